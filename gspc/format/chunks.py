"""Every chunk type a .gspc file may hold, in one registry (spec section 6; layouts in section 10).

The container (gspc/format/container.py) stores any 4-character type; the names below are the ones gspc
writes or reads, and every module that names a chunk takes it from here.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ChunkType:
    name: str  # the 4 ASCII characters in the chunk table
    holds: str  # what its payload is
    spec: str  # the spec section of its layout


POSN = "POSN"
OPAC = "OPAC"
SCAL = "SCAL"
ROTN = "ROTN"
SHDC = "SHDC"
SHRS = "SHRS"
PREC = "PREC"
SIDE = "SIDE"
RESI = "RESI"
TIDX = "TIDX"
TSID = "TSID"

REGISTRY: dict[str, ChunkType] = {
    c.name: c
    for c in (
        ChunkType(POSN, "Morton-ordered voxel positions", "10.1"),
        ChunkType(OPAC, "quantised activated opacity", "10.2"),
        ChunkType(SCAL, "quantised log scales", "10.3"),
        ChunkType(ROTN, "smallest-three quaternions", "10.4"),
        ChunkType(SHDC, "quantised SH DC", "10.5"),
        ChunkType(SHRS, "flags and quantised SH rest (absent at SH degree 0)", "10.6"),
        ChunkType(PREC, "each Gaussian's precision class and SH degree (attribute codec version 4)", "10.13"),
        ChunkType(RESI, "one residual image per view (format 1.0; read only)", "10.7"),
        ChunkType(SIDE, "every side-information view and residual image (format 1.1 on)", "10.9"),
        ChunkType(TIDX, "the tile index: each tile's box and attribute section (format 1.5)", "10.14"),
        ChunkType(TSID, "one tile's side information, in the SIDE layout (format 1.6; optional)", "10.15"),
    )
}

# The attribute codec's chunks, in the order the encoder writes them.
ATTRIBUTE_TYPES: tuple[str, ...] = (POSN, PREC, OPAC, SCAL, ROTN, SHDC, SHRS)
KNOWN_TYPES: frozenset[str] = frozenset(REGISTRY)
