"""Positions: voxelise, order along the Morton curve, code the sorted curve indices losslessly.

Voxelisation uses the scene's measured bounds: per axis ``lo = min``, ``step = (max - min) / (2^bits - 1)``
(``step = 1`` for a flat axis), voxel ``v = round((x - lo) / step)``. The decoded position is
``float32(lo + v * step)`` computed in float64. Gaussians are sorted by Morton code (x bit lowest
within each triple), ties by input index; the decoded order IS this curve order.

Unbounded scenes (a capture's background tens of radii away, floaters beyond) would stretch that grid and
coarsen every voxel of the foreground. There the grid lies in a contracted space instead (attribute codec
version 2, spec 10.1): around a region of interest (centre c, radius R) space is kept as it is, and beyond it
each octave of distance (R 2^e .. R 2^(e+1)) maps to one unit of radius, so a voxel's size grows with its
distance and its angular size, seen from the region, stays about constant. The grid keeps the preset's
voxel size inside the region and adds the bits it needs to span the rest: along the Morton curve the
foreground's deltas are what they were, so the background costs only its own bits. The inverse uses only
+, -, *, /, sqrt, floor and powers of two, which IEEE 754 rounds the same on every machine.

The sorted codes are coded as deltas: the bit length of each delta goes through the context
coder of :mod:`gspc.codec.entropy` (spatial context along the curve), the bits below each delta's
leading one are stored raw.
"""

from __future__ import annotations

import msgpack
import numpy as np

from gspc.codec.entropy import bit_length, decode_matrix, encode_matrix, pack_bits, unpack_bits
from gspc.errors import CodecError

MAX_BITS = 17  # plain grid (version 1): 3 * 17 = 51 bits per code
# Contracted grid (version 2): 3 * 21 = 63 bits per code, the most an int64 holds; the far octaves need the
# extra bits to keep the foreground's voxel size.
CONTRACTED_MAX_BITS = 21
# Region of interest: R = ROI_MARGIN times the median distance of the Gaussians from their median. The
# mapping is the identity up to 2 R (the first octave keeps its scale), so only Gaussians beyond 6 median
# distances are contracted. Bounded objects lie inside (the statues here reach 3.1-4.2 median distances,
# lego 2.9, donut 1.3) and keep the plain grid (version 1, unchanged bytes); a background shell or far
# floaters do not, even when they hold up to half the Gaussians.
ROI_QUANTILE = 0.5
ROI_MARGIN = 3.0
IDENTITY_RADIUS = 2.0  # in units of R: where contraction starts


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


def region_of_interest(means: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(centre, radius) of the contraction, or None where every Gaussian lies inside it (a bounded scene)."""
    means = np.asarray(means, dtype=np.float64)
    centre = np.median(means, axis=0)
    dist = np.sqrt(((means - centre) ** 2).sum(1))
    radius = ROI_MARGIN * float(np.quantile(dist, ROI_QUANTILE))
    if not radius > 0 or dist.max() <= IDENTITY_RADIUS * radius:
        return None
    return centre, radius


def contract(means: np.ndarray, centre, radius: float) -> np.ndarray:
    """Grid-space coordinates (float64) of world positions: u = (x - c) / R, kept where |u| <= 1; beyond,
    rescaled to radius 1 + e + (|u| / 2^e - 1) with 2^e <= |u| < 2^(e+1) (a piecewise-linear 1 + log2)."""
    u = (np.asarray(means, np.float64) - np.asarray(centre, np.float64)) / float(radius)
    r = np.sqrt((u[:, 0] * u[:, 0] + u[:, 1] * u[:, 1]) + u[:, 2] * u[:, 2])
    _, k = np.frexp(r)  # r = m 2^k, m in [0.5, 1): 2^(k-1) <= r
    e = (k - 1).astype(np.float64)
    rho = 1.0 + e + (np.ldexp(r, 1 - k) - 1.0)
    out = r > 1.0
    scale = np.where(out, rho / np.where(out, r, 1.0), 1.0)
    return u * scale[:, None]


def expand(y: np.ndarray, centre, radius: float) -> np.ndarray:
    """World positions (float32) of grid-space points: the inverse of :func:`contract`, in the operation
    order spec 10.1 gives (so every decoder computes the same float32 bits)."""
    y = np.asarray(y, np.float64)
    rho = np.sqrt((y[:, 0] * y[:, 0] + y[:, 1] * y[:, 1]) + y[:, 2] * y[:, 2])
    out = rho > 1.0
    e = np.floor(rho - 1.0)
    r = np.ldexp(1.0 + ((rho - 1.0) - e), np.where(out, e, 0).astype(np.int64))
    scale = np.where(out, r / np.where(out, rho, 1.0), 1.0)
    u = y * scale[:, None]
    return (np.asarray(centre, np.float64) + float(radius) * u).astype(np.float32)


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


def contracted_grid(y: np.ndarray, bits: int) -> tuple[int, list[float], list[float]]:
    """(grid bits, lo, step) in grid space: the voxel size a ``bits`` grid has over the Gaussians the mapping
    leaves as they are (|y| <= 2), with as many bits as the whole scene's extent needs at that size (at most
    MAX_BITS; beyond, the voxels grow)."""
    inside = np.sqrt((y * y).sum(1)) <= IDENTITY_RADIUS
    core = y[inside] if inside.any() else y
    step = (core.max(0) - core.min(0)) / float((1 << bits) - 1)
    step = np.where(step > 0, step, 1.0)
    lo, hi = y.min(0), y.max(0)
    need = int(np.ceil(np.log2(((hi - lo) / step).max() + 1.0)))
    grid_bits = min(max(bits, need), CONTRACTED_MAX_BITS)
    if need > CONTRACTED_MAX_BITS:
        step = step * 2.0 ** (need - CONTRACTED_MAX_BITS)
    return grid_bits, [float(x) for x in lo], [float(x) for x in step]


def curve_order(means: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """Voxels in curve order, the permutation of the input, and the grid meta (with ``centre`` and
    ``radius`` where the grid lies in contracted space)."""
    roi = region_of_interest(means)
    if roi is None:
        lo, step = voxel_grid(means, bits)
        v = voxelise(means, lo, step, bits)
        grid = {"bits": bits, "lo": lo, "step": step}
    else:
        centre, radius = roi
        y = contract(means, centre, radius)
        bits, lo, step = contracted_grid(y, bits)
        v = voxelise(y, lo, step, bits)
        grid = {"bits": bits, "lo": lo, "step": step, "centre": [float(c) for c in centre], "radius": radius}
    code = morton_encode(v, bits)
    order = np.argsort(code, kind="stable")
    return v[order], order, grid


def is_contracted(grid: dict) -> bool:
    return "radius" in grid


def positions(v: np.ndarray, grid: dict) -> np.ndarray:
    """Decoded float32 positions of voxels under a grid meta (plain or contracted)."""
    if is_contracted(grid):
        y = np.asarray(grid["lo"], np.float64) + v.astype(np.float64) * np.asarray(grid["step"], np.float64)
        return expand(y, grid["centre"], grid["radius"])
    return dequantise(v, grid["lo"], grid["step"])


def cell_half_widths(means: np.ndarray, grid: dict) -> np.ndarray:
    """Half-widths of a box holding each decoded position's voxel cell in world space: (N, 3), or (1, 3)
    for the plain grid, where every cell is the same."""
    half = np.asarray(grid["step"], np.float64)[None, :] / 2
    if not is_contracted(grid):
        return half
    r = np.sqrt(((np.asarray(means, np.float64) - np.asarray(grid["centre"])) ** 2).sum(1)) / grid["radius"]
    # The mapping stretches grid space by 2^e <= r in octave e >= 1 (none below 2 R); a cell may reach into
    # the next octave: 2 r bounds it there, and from 1.5 R on to cover cells that cross 2 R.
    return half * grid["radius"] * np.where(r < 1.5, 1.0, np.maximum(1.0, 2.0 * r))[:, None]


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
    # Gaps are non-negative, so a sum that wrapped int64 shows as a decrease.
    if n and (code[0] < 0 or (np.diff(code) < 0).any() or code[-1] > (1 << (3 * bits)) - 1):
        raise CodecError(f"position codes run past 3 x {bits} bits")
    return morton_decode(code, bits)
