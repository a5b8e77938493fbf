"""Spatial tiles (format 1.5, spec 10.14; their side information, 1.6, 10.15, drawn with neighbouring tiles,
1.7, shared by a span of tiles, 1.9, 10.17): the tile index and the rules that tie each tile to its chunks.

A tiled file codes its scene as tiles, each an attribute section (spec 10.0) a decoder can decode alone: the
``TIDX`` chunk lists every tile's box and section, and tile ``k``'s attribute chunks carry index ``k``, all
of them after tile ``k - 1``'s. A reader finds any tile from the header's chunk table and the index, without
reading the others.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import msgpack

from gspc.errors import CodecError
from gspc.format.attribute_section import AttributeSection, check_attribute_chunks
from gspc.format.chunks import ATTRIBUTE_TYPES, TIDX, TSID
from gspc.limits import MAX_DRAWN_TILES, MAX_SPAN_TILES, MAX_TILES, RenderAllowance, max_coded_gaussians

# The format versions a file with a tile index is written as (spec section 3): 1.9 where a tile's side
# information serves a span of tiles (10.17), 1.7 where it shows other tiles drawn with it (the index's
# ``drawn``, 10.15), 1.6 where a tile carries side information of its own (a TSID chunk), 1.5 otherwise.
TILED_VERSION = (1, 5)
TILE_SIDE_VERSION = (1, 6)
TILE_DRAWN_VERSION = (1, 7)
TILE_SPAN_VERSION = (1, 9)
Box = tuple[float, float, float, float, float, float]  # lo x, y, z, hi x, y, z


@dataclass(frozen=True)
class Tile:
    """One tile: the box of its decoded positions and its attribute section."""

    box: Box
    section: AttributeSection
    # The tiles whose decoded Gaussians its side information's views show with its own (spec 10.15); ():
    # the tile alone.
    drawn: tuple[int, ...] = ()
    # The tiles k .. k + span - 1 its side information serves together (spec 10.17; 1: the tile alone).
    span: int = 1

    @property
    def n(self) -> int:
        return self.section.n

    def meets(self, region: Box) -> bool:
        """Whether the tile's box meets the closed box ``region``."""
        return all(self.box[a] <= region[a + 3] and region[a] <= self.box[a + 3] for a in range(3))


@dataclass(frozen=True)
class TileIndex:
    tiles: tuple[Tile, ...]

    @property
    def num_gaussians(self) -> int:
        return sum(t.n for t in self.tiles)

    @property
    def sh_degree(self) -> int:
        return self.tiles[0].section.sh_degree

    def meeting(self, region: Box | None) -> list[int]:
        """The tiles whose boxes meet ``region`` (every tile for None), in file order."""
        return [k for k, t in enumerate(self.tiles) if region is None or t.meets(region)]

    def span_of(self) -> list[int]:
        """Each tile's span's first tile (spec 10.17): its own number, or its span's lead's."""
        lead = list(range(len(self.tiles)))
        for k, t in enumerate(self.tiles):
            lead[k + 1 : k + t.span] = [k] * (t.span - 1)
        return lead


def pack_tile_index(tiles: Sequence[Tile]) -> bytes:
    """The TIDX payload (spec 10.14): a msgpack array of one map per tile."""
    entries = []
    for t in tiles:
        entry = {"box": [float(x) for x in t.box], "attributes": t.section.to_dict()}
        if t.drawn:
            entry["drawn"] = [int(j) for j in t.drawn]
        if t.span > 1:
            entry["span"] = int(t.span)
        entries.append(entry)
    return msgpack.packb(entries, use_bin_type=True)


def _refuse_ext(code: int, data: bytes) -> None:
    raise CodecError(f"chunk {TIDX} holds a msgpack extension type ({code})")


def read_tile_index(payload: bytes) -> TileIndex:
    """The tile index of a TIDX payload, every field checked (CodecError naming the first bad one)."""
    n = len(payload)
    try:
        raw = msgpack.unpackb(
            payload,
            raw=False,
            ext_hook=_refuse_ext,
            max_str_len=n,
            max_bin_len=n,
            max_array_len=n,
            max_map_len=n,
            max_ext_len=n,
        )
    except CodecError:
        raise
    except Exception:
        raise CodecError(f"chunk {TIDX} is not one msgpack value") from None
    if not isinstance(raw, list) or not 2 <= len(raw) <= MAX_TILES:
        raise CodecError(f"chunk {TIDX} is not an array of 2..{MAX_TILES} tiles")
    tiles = []
    for k, entry in enumerate(raw):
        if not isinstance(entry, dict) or "box" not in entry or "attributes" not in entry:
            raise CodecError(f"tile {k} of chunk {TIDX} is not a map with a box and attributes")
        drawn = _drawn(entry.get("drawn", []), k, len(raw))
        span = _span(entry.get("span", 1), k, len(raw))
        tiles.append(
            Tile(_box(entry["box"], k), AttributeSection.from_dict(entry["attributes"]), drawn, span)
        )
    degrees = {t.section.sh_degree for t in tiles}
    if len(degrees) != 1:
        raise CodecError(f"the tiles of chunk {TIDX} have SH degrees {sorted(degrees)}; a scene has one")
    return TileIndex(tuple(tiles))


def _box(value: object, k: int) -> Box:
    ok = isinstance(value, list) and len(value) == 6 and all(isinstance(x, float) for x in value)
    if not ok or not all(math.isfinite(x) for x in value):
        raise CodecError(f"tile {k}'s box is not an array of 6 finite floats")
    if any(value[a] > value[a + 3] for a in range(3)):
        raise CodecError(f"tile {k}'s box has a lower corner above its upper one")
    return tuple(value)  # type: ignore[return-value]


def _drawn(value: object, k: int, tiles: int) -> tuple[int, ...]:
    ok = isinstance(value, list) and len(value) <= MAX_DRAWN_TILES
    ok = ok and all(isinstance(j, int) and not isinstance(j, bool) and 0 <= j < tiles for j in value)
    if not ok or k in value or len(set(value)) != len(value):
        raise CodecError(
            f"tile {k}'s drawn tiles are not an array of at most {MAX_DRAWN_TILES} distinct other tiles' "
            "numbers"
        )
    return tuple(value)


def _span(value: object, k: int, tiles: int) -> int:
    top = min(MAX_SPAN_TILES, tiles - k)
    if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= top:
        raise CodecError(f"tile {k}'s span is not an integer 1..{top}")
    return value


def check_spans(index: TileIndex, sides: set[int]) -> None:
    """The rules of spec 10.17, given the tiles that carry a TSID chunk: a span above 1 only on such a tile,
    its members with no TSID, drawn list or span of their own, and none of them drawn by it."""
    for k, t in enumerate(index.tiles):
        if t.span == 1:
            continue
        if k not in sides:
            raise CodecError(f"tile {k} has a span of {t.span} tiles but no {TSID} chunk")
        members = range(k + 1, k + t.span)
        for j in members:
            m = index.tiles[j]
            if j in sides or m.drawn or m.span > 1:
                raise CodecError(f"tile {j}, in tile {k}'s span, has side information, drawn tiles or a span")
        if any(j in t.drawn for j in members):
            raise CodecError(f"tile {k}'s drawn tiles name a tile of its own span")


def tile_chunks(chunks: Sequence, index: TileIndex) -> list[dict[str, bytes]]:
    """Each tile's attribute payloads by type, from a file's chunks (or chunk-table entries: anything with
    ``type``, ``index`` and, for the bounds, ``payload`` or ``length``), checked against spec 10.14: the
    index first, every attribute chunk (and every TSID, 10.15) naming a tile, a tile's chunks after the
    previous tile's, each tile's chunks those its section needs, the spans' rules (10.17), and the Gaussians
    within what the bytes may declare, per tile and in all (gspc/limits.py)."""
    out: list[dict[str, bytes]] = [{} for _ in index.tiles]
    sizes = [0] * len(index.tiles)
    last, seen_index, sides = -1, False, set()
    for c in chunks:
        if c.type == TIDX:
            seen_index = True
            continue
        if c.type not in ATTRIBUTE_TYPES and c.type != TSID:
            continue
        if not seen_index:
            raise CodecError(f"chunk {c.type}#{c.index} comes before the tile index ({TIDX})")
        if not 0 <= c.index < len(index.tiles):
            raise CodecError(f"chunk {c.type}#{c.index} names no tile (the file has {len(index.tiles)})")
        if c.index < last:
            raise CodecError(f"chunk {c.type}#{c.index} comes after tile {last}'s chunks")
        last = c.index
        if c.type == TSID:
            sides.add(c.index)
            continue
        payload = getattr(c, "payload", None)
        out[c.index][c.type] = payload if payload is not None else b""
        sizes[c.index] += len(payload) if payload is not None else c.length
    check_spans(index, sides)
    for k, (tile, chunks_k) in enumerate(zip(index.tiles, out)):
        try:
            check_attribute_chunks(chunks_k, tile.section, sizes[k])
        except CodecError as e:
            raise CodecError(f"tile {k}: {e}") from None
    total = sum(sizes)
    if index.num_gaussians > max_coded_gaussians(total):
        raise CodecError(
            f"{index.num_gaussians:,} Gaussians in all from {total:,} payload bytes (at most "
            f"{max_coded_gaussians(total):,})"
        )
    return out


def tile_side_allowances(chunks: Sequence, index: TileIndex) -> list[RenderAllowance]:
    """Each tile's share of what side views may ask of a decoder (spec 10.15): by its span's attribute and
    TSID payload bytes among every tile's (10.17: a member's bytes count in its span's first tile's share),
    from a file's chunks or chunk-table entries."""
    lead = index.span_of()
    sizes = [0] * len(index.tiles)
    for c in chunks:
        if (c.type in ATTRIBUTE_TYPES or c.type == TSID) and 0 <= c.index < len(sizes):
            payload = getattr(c, "payload", None)
            sizes[lead[c.index]] += len(payload) if payload is not None else c.length
    total = sum(sizes)
    return [RenderAllowance.of_tile(k, q, total, t.span) for k, (q, t) in enumerate(zip(sizes, index.tiles))]


def refuse_untiled_sides(chunks: Sequence) -> None:
    """A TSID chunk belongs to a tile (spec 10.15): a file without a tile index holding one is refused."""
    for c in chunks:
        if c.type == TSID:
            raise CodecError(f"chunk {TSID}#{c.index} in a file without a tile index")
