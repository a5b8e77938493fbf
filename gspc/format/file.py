"""A whole .gspc file as gspc writes and reads it: the typed header, the attribute payloads (one section, or
one per spatial tile), the side information and the bytes each part takes.

A file is parsed and checked once, here: the container (every CRC), the header's records, the tile index
and each tile's chunks, the side views' pixels against the file's budget (gspc/limits.py) and each residual
image's declared size, before any camera is built or view rendered. The decoder and ``gspc info`` read the
same :class:`GspcFile`; :class:`FileReader` reads a file on disk in parts (a region of a tiled one).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

from gspc.errors import CodecError
from gspc.format import container
from gspc.format.attribute_section import (
    CODEBOOK_VERSION,
    AttributeSection,
    attribute_chunks,
    check_attribute_chunks,
)
from gspc.format.chunks import ATTRIBUTE_TYPES, SIDE, TIDX, TSID
from gspc.format.header import FileHeader
from gspc.format.side_chunk import SideViews, read_side_views, read_tile_side
from gspc.format.tiles import (
    TILE_DRAWN_VERSION,
    TILE_SIDE_VERSION,
    TILE_SPAN_VERSION,
    TILED_VERSION,
    Tile,
    TileIndex,
    pack_tile_index,
    read_tile_index,
    refuse_untiled_sides,
    tile_chunks,
    tile_side_allowances,
)
from gspc.limits import RenderAllowance

# The lowest format version that holds an attribute section of codec version 5 (spec section 3).
CODEBOOK_FILE_VERSION = (1, 8)


@dataclass(frozen=True)
class GspcFile:
    version: tuple[int, int]
    header: FileHeader
    attribute_chunks: dict[str, bytes]  # by type, each checked present and within the count's bound
    side: SideViews
    chunks: tuple[container.Chunk, ...]  # every chunk in file order, unknown optional ones too
    file_size: int
    header_length: int
    tiles: TileIndex | None = None  # a tiled file's index (spec 10.14); its tiles' payloads below
    tile_chunks: tuple[dict[str, bytes], ...] = ()
    # Each tile's own side information (spec 10.15; None: the tile has none) and its share of the budget.
    tile_sides: tuple[SideViews | None, ...] = ()
    tile_allowances: tuple[RenderAllowance, ...] = ()

    @property
    def budget(self) -> dict[str, int]:
        """Bytes per part: the file, each chunk type (payloads with their padding) and the rest (preamble,
        msgpack header, padding, trailer)."""
        return byte_budget(self.file_size, self.chunks)

    @property
    def num_gaussians(self) -> int:
        return self.tiles.num_gaussians if self.tiles is not None else self.header.attributes.n

    @property
    def sh_degree(self) -> int:
        return self.tiles.sh_degree if self.tiles is not None else self.header.attributes.sh_degree


def byte_budget(file_size: int, chunks: Sequence) -> dict[str, int]:
    """Bytes per part of a file of ``file_size`` bytes holding ``chunks`` (payloads, or table entries with a
    ``length``; see GspcFile.budget)."""
    budget = {"file": file_size}
    for c in chunks:
        length = len(c.payload) if hasattr(c, "payload") else c.length
        budget[c.type] = budget.get(c.type, 0) + container.align(length)
    budget["header+framing"] = file_size - sum(v for k, v in budget.items() if k != "file")
    return budget


def read_file(data: bytes) -> GspcFile:
    """Unpack and check everything a decode uses (FormatError or CodecError, one line, otherwise)."""
    c = container.unpack(data)
    index_chunk = c.find(TIDX, 0)
    header = FileHeader.from_dict(c.header, tiled=index_chunk is not None)
    side = read_side_views(header.side_info.legacy_views, c.chunks, len(data))
    chunks = (*c.chunks, *c.skipped)
    if index_chunk is None:
        refuse_untiled_sides(c.chunks)
        attributes = attribute_chunks(c.chunks)
        check_attribute_chunks(attributes, header.attributes)
        return GspcFile(c.version, header, attributes, side, chunks, c.file_size, c.header_length)
    tiles = _tile_index(c.chunks)
    per_tile = tuple(tile_chunks(c.chunks, tiles))
    allowances = tuple(tile_side_allowances(c.chunks, tiles))
    payloads = {ch.index: ch.payload for ch in c.chunks if ch.type == TSID}
    sides = tuple(_tile_side(payloads.get(k), k, allowances[k]) for k in range(len(tiles.tiles)))
    return GspcFile(
        c.version, header, {}, side, chunks, c.file_size, c.header_length, tiles, per_tile, sides, allowances
    )


def _tile_side(payload: bytes | None, k: int, budget: RenderAllowance) -> SideViews | None:
    """Tile ``k``'s side information from its TSID payload (None: it has none), errors naming the tile."""
    if payload is None:
        return None
    try:
        return read_tile_side(payload, budget)
    except CodecError as e:
        raise CodecError(f"tile {k}'s {TSID}: {e}") from None


def _tile_index(chunks: Sequence) -> TileIndex:
    """The index of a file whose chunks (or table entries) hold a TIDX; only index 0 is one."""
    found = [ch for ch in chunks if ch.type == TIDX]
    if len(found) != 1 or found[0].index != 0:
        raise CodecError(f"a tiled file holds one {TIDX} chunk, of index 0")
    return read_tile_index(found[0].payload)


class FileReader:
    """A .gspc file on disk read in parts: its head, header and tile index first, then the chunks asked for,
    each checked as it is read (spec section 8, and 10.14 on reading part of a file). A reader that reads
    every chunk checks the whole file's trailer too (:meth:`check_trailer`)."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = os.fspath(path)
        self._f = open(self.path, "rb")  # noqa: SIM115 (closed by close() / the context manager)
        try:
            self.head = container.read_head(self._f)
            entries = self.head.entries
            has_index = any(e.type == TIDX for e in entries)
            # An untiled file is read whole (read_file), its header parsed after the whole-file checksum
            # (spec section 8); a tiled one is read in parts, from here (10.14).
            self.header: FileHeader | None = None
            self.tiles: TileIndex | None = None
            self.side = SideViews()
            self.tile_allowances: list[RenderAllowance] = []
            if has_index:
                self.header = FileHeader.from_dict(self.head.meta, tiled=True)
                k = next(i for i, e in enumerate(entries) if e.type == TIDX)
                index_chunk = container.read_chunk(self._f, self.head, k)
                self.tiles = _tile_index([*entries[:k], index_chunk, *entries[k + 1 :]])
                tile_chunks(entries, self.tiles)  # the table's layout, before any tile is read
                self.tile_allowances = tile_side_allowances(entries, self.tiles)
                side_entries = [i for i, e in enumerate(entries) if e.type in (SIDE, "RESI")]
                side_chunks = [container.read_chunk(self._f, self.head, i) for i in side_entries]
                self.side = read_side_views(
                    self.header.side_info.legacy_views, side_chunks, self.head.file_size
                )
        except BaseException:
            self._f.close()
            raise

    def __enter__(self) -> FileReader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._f.close()

    @property
    def budget(self) -> dict[str, int]:
        return byte_budget(self.head.file_size, self.head.entries)

    def tile_bytes(self) -> list[int]:
        """Each tile's attribute payload bytes, from the chunk table."""
        sizes = [0] * len(self.tiles.tiles)
        for e in self.head.entries:
            if e.type in ATTRIBUTE_TYPES:
                sizes[e.index] += e.length
        return sizes

    def tile(self, k: int) -> dict[str, bytes]:
        """Tile ``k``'s attribute payloads by type, each chunk's CRC checked as it is read."""
        out = {}
        for i, e in enumerate(self.head.entries):
            if e.type in ATTRIBUTE_TYPES and e.index == k:
                out[e.type] = container.read_chunk(self._f, self.head, i).payload
        return out

    def tile_side(self, k: int) -> SideViews | None:
        """Tile ``k``'s own side information (spec 10.15; None: it has none), read and checked (its
        CRC, layout and pixels against the tile's share of the budget)."""
        for i, e in enumerate(self.head.entries):
            if e.type == TSID and e.index == k:
                payload = container.read_chunk(self._f, self.head, i).payload
                return _tile_side(payload, k, self.tile_allowances[k])
        return None

    @property
    def has_tile_sides(self) -> bool:
        return any(e.type == TSID for e in self.head.entries)

    def check_trailer(self) -> None:
        """Spec section 8's checks 9 and 10 over the whole file, read in blocks (a decode that read every
        tile runs it before its output is in place)."""
        container.check_stream(self._f, self.head)


def file_chunks(attributes: dict[str, bytes], side: bytes | None) -> list[container.Chunk]:
    """A file's chunks: the attribute chunks in the order the format lists them, then the side information
    in one SIDE chunk (spec 10.9), all required."""
    chunks = [container.Chunk(t, attributes[t]) for t in ATTRIBUTE_TYPES if t in attributes]
    if side is not None:
        chunks.append(container.Chunk(SIDE, side))
    return chunks


def tiled_file_chunks(
    tiles: Sequence[tuple[Tile, dict[str, bytes]]],
    side: bytes | None,
    tile_sides: Sequence[bytes | None] = (),
) -> list[container.Chunk]:
    """A tiled file's chunks (spec 10.14): the tile index, then each tile's attribute chunks (index: the
    tile's number) in the order the format lists them and its own side information (a TSID, optional:
    10.15), then the whole scene's side information."""
    chunks = [container.Chunk(TIDX, pack_tile_index([t for t, _ in tiles]))]
    for k, (_, payloads) in enumerate(tiles):
        chunks += [container.Chunk(t, payloads[t], index=k) for t in ATTRIBUTE_TYPES if t in payloads]
        if k < len(tile_sides) and tile_sides[k] is not None:
            chunks.append(container.Chunk(TSID, tile_sides[k], index=k, required=False))
    if side is not None:
        chunks.append(container.Chunk(SIDE, side))
    return chunks


def _marked(version: tuple[int, int], sections: Sequence[AttributeSection | None]) -> tuple[int, int]:
    """``version``, or 1.8 where a section codes its SH rest by codebook (spec section 3)."""
    codebook = any(s is not None and s.version == CODEBOOK_VERSION for s in sections)
    return max(version, CODEBOOK_FILE_VERSION) if codebook else version


def pack_file(header: FileHeader, attributes: dict[str, bytes], side: bytes | None) -> bytes:
    """The file of these parts (:func:`file_chunks`), marked 1.8 with the SH rest by codebook, else 1.4."""
    version = _marked(container.VERSION, [header.attributes])
    return container.pack(header.to_dict(), file_chunks(attributes, side), version)


def pack_tiled_file(
    header: FileHeader,
    tiles: Sequence[tuple[Tile, dict[str, bytes]]],
    side: bytes | None,
    tile_sides: Sequence[bytes | None] = (),
) -> bytes:
    """The tiled file of these parts (:func:`tiled_file_chunks`), marked format 1.9 where a tile's side
    information serves a span of tiles, 1.8 where a tile codes its SH rest by codebook, 1.7 where a tile's
    side information draws other tiles, 1.6 where a tile carries side information of its own, else 1.5 (spec
    section 3)."""
    version = TILE_SIDE_VERSION if any(s is not None for s in tile_sides) else TILED_VERSION
    if any(t.drawn for t, _ in tiles):
        version = TILE_DRAWN_VERSION
    version = _marked(version, [t.section for t, _ in tiles])
    if any(t.span > 1 for t, _ in tiles):
        version = max(version, TILE_SPAN_VERSION)
    return container.pack(header.to_dict(), tiled_file_chunks(tiles, side, tile_sides), version)
