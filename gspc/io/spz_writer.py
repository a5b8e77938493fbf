"""Writer for Niantic SPZ, versions 2, 3 and 4 (the layout is described in gspc/io/spz.py, the reader).

Version 3 by default: it is the newest version every maintained viewer reads. Spark reads versions 1-3 and
refuses 4; splat-transform and Niantic's library read 2-4 (Babylon.js 2-3, newer releases 4 too); mkkellogg's
GaussianSplats3D (unmaintained; its README points to Spark) reads only 1-2 (bench/outputs.md, "Which viewers
read which SPZ version"). Version 4 (zstd streams) makes smaller files for the readers that have it; version
2 is for the readers that stop there.

Values are rounded as Niantic's packer rounds them (half away from zero, then clamped to the field), with
its default SH precision: 5 bits for band 1, 4 for bands 2-3 (the low bits zeroed, so the bytes compress).
Positions keep 12 fractional bits, as Niantic's writer does, unless the scene reaches beyond the 24-bit
range, where fewer bits (coarser positions) keep every Gaussian in range.

Coordinates: SPZ files are written in OPENCV (RDF), the convention viewers read SPZ and PLY in (Spark's
documentation turns loaded splats "from OpenCV to OpenGL", splat-transform reads SPZ in PLY space). A scene
that states its convention is converted to it, and versions 3-4 record it (the coordinate-system extension),
so readers that honour the record (Niantic's library) convert it exactly. A scene that states none is
written as it is, with no record, as every other converter writes it. Version 2 never carries records:
GaussianSplats3D refuses any bytes after the attribute blocks.
"""

from __future__ import annotations

import gzip
import math
import os

import numpy as np
import torch
import zstandard

from gspc.atomic import atomic_write_bytes
from gspc.errors import InputError
from gspc.format.coordinates import CONVENTIONS
from gspc.io.coordinates import OPENCV, oriented
from gspc.io.spz import (
    COLOUR_SCALE,
    COORDINATE_SYSTEM_EXTENSION,
    COORDINATE_SYSTEM_RECORD,
    FLAG_EXTENSIONS,
    LEGACY_HEADER,
    MAGIC,
    SUPPORTED_VERSIONS,
    TOC_ENTRY,
    V4_HEADER,
)
from gspc.scene import GaussianScene

DEFAULT_VERSION = 3
DEFAULT_SH_BITS = (5, 4)  # band 1, bands 2-3: Niantic's defaults
MAX_POSITION_FRACTION = 12  # Niantic's writer's choice
MAX_FIXED = (1 << 23) - 1  # the largest 24-bit two's complement value
MAX_COUNT = (1 << 32) - 1  # the header's uint32 count
ZSTD_LEVEL = 12  # Niantic's level for version 4 streams


def _round(x: np.ndarray) -> np.ndarray:
    """Round half away from zero (C's round(), which Niantic's packer uses), as int64."""
    return (np.sign(x) * np.floor(np.abs(x) + 0.5)).astype(np.int64)


def _bytes(x: np.ndarray) -> np.ndarray:
    """Rounded and clamped to a byte; clamped first, so values far outside never reach the integer cast."""
    return _round(np.clip(x, -1.0, 256.0)).clip(0, 255).astype(np.uint8)


def _f64(t: torch.Tensor) -> np.ndarray:
    return t.detach().to("cpu", torch.float64).numpy()


def position_bits(max_abs: float) -> int:
    """The most fractional bits (at most 12) that keep coordinates up to ``max_abs`` in 24 bits."""
    for bits in range(MAX_POSITION_FRACTION, -1, -1):
        if _round(np.array([max_abs * (1 << bits)]))[0] <= MAX_FIXED:
            return bits
    raise InputError(
        f"a coordinate of {max_abs:.4g} is beyond SPZ's 24-bit positions (at most {MAX_FIXED:,} units); "
        "write .ply or .glb"
    )


def _positions(means: np.ndarray, bits: int) -> np.ndarray:
    fixed = _round(means * (1 << bits)) & 0xFFFFFF  # two's complement in 24 bits
    out = np.empty((len(means), 3, 3), np.uint8)
    for byte in range(3):
        out[:, :, byte] = (fixed >> (8 * byte)) & 0xFF
    return out


def _unit_xyzw(quats: np.ndarray) -> np.ndarray:
    q = quats[:, [1, 2, 3, 0]]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _rotations_v2(quats: np.ndarray) -> np.ndarray:
    q = _unit_xyzw(quats)
    q = np.where(q[:, 3:] < 0, -q, q)  # w >= 0, so readers can rebuild it from x, y, z
    return _bytes(q[:, :3] * 127.5 + 127.5)


def _rotations_v3(quats: np.ndarray) -> np.ndarray:
    """Smallest three: the index of the largest |component| (x, y, z, w order) in bits 31-30, then the
    other three in order, 10 bits each (sign, 9-bit magnitude of |q| / sqrt(1/2)), with the largest made
    positive (q and -q are one rotation)."""
    q = _unit_xyzw(quats)
    rows = np.arange(len(q))
    largest = np.abs(q).argmax(axis=1)
    q = np.where(q[rows, largest][:, None] < 0, -q, q)
    word = largest.astype(np.uint64)
    for slot in range(4):
        kept = largest != slot
        magnitude = np.minimum(_round(np.abs(q[:, slot]) / math.sqrt(0.5) * 511.0), 511).astype(np.uint64)
        field = (q[:, slot] < 0).astype(np.uint64) << np.uint64(9) | magnitude
        word = np.where(kept, word << np.uint64(10) | field, word)
    word = word.astype(np.uint32)
    return np.stack([(word >> (8 * i)) & 0xFF for i in range(4)], axis=1).astype(np.uint8)


def _sh(sh_rest: torch.Tensor, bits: tuple[int, int], rows: int = 1 << 16) -> np.ndarray:
    """(N, K, 3) coefficients as bytes (byte - 128) / 128, rounded to the middle of buckets of
    2^(8 - bits) bytes (so 0 stays exact), band 1 with ``bits[0]``, the others with ``bits[1]``. In blocks
    of ``rows``: the SH rest is most of a scene, and whole-array temporaries would be several times it."""
    k = sh_rest.shape[1]
    bucket = np.full(k, 1 << (8 - bits[1]), np.int64)
    bucket[:3] = 1 << (8 - bits[0])
    bucket = bucket[None, :, None]
    out = np.empty(tuple(sh_rest.shape), np.uint8)
    for i in range(0, len(out), rows):
        block = sh_rest[i : i + rows].to(torch.float32).numpy()
        q = _round(np.clip(block, -2.0, 2.0) * np.float32(128.0)) + 128  # past +-2 every byte clamps alike
        out[i : i + rows] = np.clip((q + bucket // 2) // bucket * bucket, 0, 255)
    return out


def attribute_blocks(scene: GaussianScene, version: int, sh_bits: tuple[int, int]) -> tuple[int, list[bytes]]:
    """(fractional bits, the six attribute blocks in file order) of a scene already in its output axes."""
    means = _f64(scene.means)
    bits = position_bits(float(np.abs(means).max()))
    quats = _f64(scene.quats)
    alphas = 1.0 / (1.0 + np.exp(-_f64(scene.opacities)))
    blocks = [
        _positions(means, bits),
        _bytes(alphas * 255.0),
        _bytes(_f64(scene.sh_dc) * (COLOUR_SCALE * 255.0) + 127.5),
        _bytes((_f64(scene.log_scales) + 10.0) * 16.0),
        _rotations_v2(quats) if version == 2 else _rotations_v3(quats),
        _sh(scene.sh_rest.detach().cpu(), sh_bits),
    ]
    return bits, [b.tobytes() for b in blocks]


def _legacy(head: tuple, blocks: list[bytes], records: bytes) -> bytes:
    body = LEGACY_HEADER.pack(*head, 0) + b"".join(blocks) + records  # records follow the blocks
    return gzip.compress(body, compresslevel=6, mtime=0)


def _v4(head: tuple, blocks: list[bytes], records: bytes) -> bytes:
    streams = [b for b in blocks if b]  # degree 0: five streams (splat-transform refuses an empty sixth)
    toc = V4_HEADER.size + len(records)
    header = V4_HEADER.pack(*head, len(streams), toc, bytes(12))
    zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
    frames = [zstd.compress(s) for s in streams]
    table = b"".join(TOC_ENTRY.pack(len(f), len(s)) for f, s in zip(frames, streams))
    return header + records + table + b"".join(frames)


def spz_bytes(
    scene: GaussianScene, version: int = DEFAULT_VERSION, sh_bits: tuple[int, int] = DEFAULT_SH_BITS
) -> bytes:
    """The SPZ file of ``scene`` (see the module's docstring); InputError for a scene SPZ cannot hold."""
    if version not in SUPPORTED_VERSIONS:
        raise InputError(f"SPZ version {version} cannot be written (versions 2, 3 and 4 can)")
    if not all(1 <= b <= 8 for b in sh_bits):
        raise InputError(f"SPZ SH precision {sh_bits} is outside 1-8 bits")
    scene.validate()
    if scene.num_gaussians > MAX_COUNT:
        raise InputError(f"{scene.num_gaussians:,} Gaussians: SPZ counts at most {MAX_COUNT:,} (32 bits)")
    stated = scene.coordinates is not None
    scene = oriented(scene, OPENCV)
    records = b""
    if stated and version >= 3:
        code = CONVENTIONS.index(OPENCV) + 1
        records = COORDINATE_SYSTEM_RECORD.pack(COORDINATE_SYSTEM_EXTENSION, 4, code)
    bits, blocks = attribute_blocks(scene, version, sh_bits)
    head = (MAGIC, version, scene.num_gaussians, scene.sh_degree, bits, FLAG_EXTENSIONS if records else 0)
    return _v4(head, blocks, records) if version == 4 else _legacy(head, blocks, records)


def write_spz(
    scene: GaussianScene,
    path: str | os.PathLike,
    version: int = DEFAULT_VERSION,
    sh_bits: tuple[int, int] = DEFAULT_SH_BITS,
) -> None:
    """Write ``scene`` as an SPZ file, atomically (temp file + rename)."""
    atomic_write_bytes(path, spz_bytes(scene.to("cpu"), version, sh_bits))
