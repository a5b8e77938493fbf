"""Decoding one spatial tile of a tiled file (spec 10.14): a task of plain data, so tiles decode side by side
in worker processes (gspc/workers.py) with the same bits wherever they run."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gspc.codec.attributes import DecodedSection, decode_section
from gspc.errors import CodecError
from gspc.format.attribute_section import AttributeSection
from gspc.format.tiles import Box, Tile
from gspc.limits import DecodeBudget
from gspc.scene import GaussianScene


@dataclass(frozen=True)
class TileDecodeJob:
    number: int
    chunks: dict[str, bytes]  # the tile's attribute payloads by type
    section: AttributeSection
    box: Box
    file_bytes: int  # the attribute payload bytes of all the file's tiles (the budget's share)


def file_tile_jobs(tiles: Sequence[Tile], chunks: Sequence[dict[str, bytes]]) -> list[TileDecodeJob]:
    """Every tile's decoding job, of a tile index's tiles and each one's attribute payloads."""
    total = sum(sum(len(p) for p in c.values()) for c in chunks)
    return [TileDecodeJob(k, c, t.section, t.box, total) for k, (t, c) in enumerate(zip(tiles, chunks))]


def decode_tile(job: TileDecodeJob) -> GaussianScene:
    """The tile's Gaussians in its decoded order, each position checked inside the tile's box."""
    return decode_tile_section(job).scene


def decode_tile_section(job: TileDecodeJob) -> DecodedSection:
    """:func:`decode_tile`, with the precision map its refinement keeps each value's cell by."""
    tile_bytes = sum(len(p) for p in job.chunks.values())
    decoded = decode_section(job.chunks, job.section, DecodeBudget(tile_bytes, job.file_bytes))
    m = decoded.scene.means.numpy()
    lo, hi = np.asarray(job.box[:3], np.float32), np.asarray(job.box[3:], np.float32)
    if ((m < lo) | (m > hi)).any():
        raise CodecError(f"tile {job.number} decodes positions outside its box")
    return decoded
