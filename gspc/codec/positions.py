"""Positions: voxelise, order along the Morton curve, code the sorted curve indices losslessly.

Voxelisation uses the scene's measured bounds: per axis ``lo = min``, ``step = (max - min) / (2^bits - 1)``
(``step = 1`` for a flat axis), voxel ``v = round((x - lo) / step)``. The decoded position is
``float32(lo + v * step)`` computed in float64. Gaussians are sorted by Morton code (x bit lowest
within each triple), ties by input index; the decoded order IS this curve order.

The sorted codes are coded as deltas: the bit length of each delta goes through the context
coder of :mod:`gspc.codec.entropy` (spatial context along the curve), the bits below each delta's
leading one are stored raw.
"""

from __future__ import annotations

import msgpack
import numpy as np

from gspc.codec.entropy import bit_length, decode_matrix, encode_matrix, pack_bits, unpack_bits
from gspc.errors import CodecError

MAX_BITS = 17  # 3 * 17 = 51 bits per code stays below 2^53 (exact through float64 bit lengths)


def voxel_grid(means: np.ndarray, bits: int) -> tuple[list[float], list[float]]:
    """Measured per-axis origin and step of a ``bits``-per-axis grid over the points' bounds."""
    if not 1 <= bits <= MAX_BITS:
        raise CodecError(f"position bits must be 1-{MAX_BITS}, got {bits}")
    means = np.asarray(means, dtype=np.float64)
    lo = means.min(0)
    hi = means.max(0)
    step = (hi - lo) / float((1 << bits) - 1)
    step = np.where(step > 0, step, 1.0)
    return [float(x) for x in lo], [float(x) for x in step]


def voxelise(means: np.ndarray, lo: list[float], step: list[float], bits: int) -> np.ndarray:
    v = np.rint((np.asarray(means, np.float64) - np.asarray(lo)) / np.asarray(step))
    return np.clip(v, 0, (1 << bits) - 1).astype(np.int64)


def dequantise(v: np.ndarray, lo: list[float], step: list[float]) -> np.ndarray:
    """Exact float32 positions of voxels (the same numpy ops in encoder and decoder)."""
    return (np.asarray(lo, np.float64) + v.astype(np.float64) * np.asarray(step, np.float64)).astype(
        np.float32
    )


def morton_encode(v: np.ndarray, bits: int) -> np.ndarray:
    v = np.asarray(v, dtype=np.int64)
    code = np.zeros(v.shape[0], np.int64)
    for b in range(bits):
        for axis in range(3):
            code |= ((v[:, axis] >> b) & 1) << (3 * b + axis)
    return code


def morton_decode(code: np.ndarray, bits: int) -> np.ndarray:
    code = np.asarray(code, dtype=np.int64)
    v = np.zeros((code.shape[0], 3), np.int64)
    for b in range(bits):
        for axis in range(3):
            v[:, axis] |= ((code >> (3 * b + axis)) & 1) << b
    return v


def curve_order(means: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """Voxels in curve order, the permutation of the input, and the grid meta."""
    lo, step = voxel_grid(means, bits)
    v = voxelise(means, lo, step, bits)
    code = morton_encode(v, bits)
    order = np.argsort(code, kind="stable")
    return v[order], order, {"bits": bits, "lo": lo, "step": step}


def encode_positions(v_sorted: np.ndarray, bits: int) -> bytes:
    """Code voxels already in curve order."""
    code = morton_encode(v_sorted, bits)
    delta = np.diff(code, prepend=0)
    lengths = bit_length(delta)
    mantissa_len = np.maximum(lengths - 1, 0)
    classes = encode_matrix(lengths[:, None])
    raw = pack_bits(delta.astype(np.uint64), mantissa_len)
    return msgpack.packb([classes, raw], use_bin_type=True)


def decode_positions(payload: bytes, bits: int, n: int) -> np.ndarray:
    """Voxels in curve order from a POSN payload."""
    try:
        classes, raw = msgpack.unpackb(payload, raw=False)
    except Exception as err:
        raise CodecError(f"corrupt position payload ({type(err).__name__})") from None
    if not (isinstance(classes, bytes) and isinstance(raw, bytes)):
        raise CodecError("position payload is not a pair of msgpack bins")
    lengths = decode_matrix(classes, (n, 1))[:, 0]
    if (lengths > 3 * bits).any() or (lengths < 0).any():
        raise CodecError("position payload does not match the header's bit depth")
    mantissa_len = np.maximum(lengths - 1, 0)
    low = unpack_bits(raw, mantissa_len).astype(np.int64)
    lead = np.where(lengths > 0, np.left_shift(1, mantissa_len), 0)
    code = np.cumsum(lead | low)
    # Gaps are below 2^51, so a sum that would wrap int64 passes through [2^(3 bits), 2^63) first.
    if (code >= 1 << (3 * bits)).any():
        raise CodecError(f"position codes run past 3 x {bits} bits")
    return morton_decode(code, bits)
