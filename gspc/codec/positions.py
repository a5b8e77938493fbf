"""Positions: voxelise, order along the Morton curve, code the sorted curve indices losslessly.

Voxelisation uses the scene's measured bounds: per axis ``lo = min``, and cubic voxels as many as a grid of
``p`` bits per axis over those bounds has (the side: the geometric mean of the extents over ``2^p - 1``;
``step = 1`` for a flat axis), ``p`` fractional between whole bits (the file holds ``step`` and the grid's
whole ``bits``, what the longest axis needs), voxel ``v = round((x - lo) / step)``. The decoded position is
``float32(lo + v * step)`` computed in float64. Gaussians are sorted by Morton code (x bit lowest
within each triple), ties by input index; the decoded order IS this curve order.

Unbounded scenes (a capture's background tens of radii away, floaters beyond) would stretch that grid and
coarsen every voxel of the foreground. There the grid lies in a contracted space instead (attribute codec
version 2, spec 10.1): around a region of interest (centre c, radius R) space is kept as it is, and beyond it
each octave of distance (R 2^e .. R 2^(e+1)) maps to one unit of radius, so a voxel's size grows with its
distance and its angular size, seen from the region, stays about constant. The grid keeps the preset's
voxel size inside the region and adds the bits it needs to span the rest: along the Morton curve the
foreground's deltas are those of the plain grid, so the background costs only its own bits. The inverse uses
only +, -, *, /, sqrt, floor and powers of two, which IEEE 754 rounds the same on every machine.

The background of a real capture is large Gaussians, and the contracted grid still places them far more
finely than their size needs (bench/far_set.md, "Reading"). So the Gaussians beyond it whose size allows
may form a far set
(attribute codec version 3, spec 10.1): coded after the others as a curve of their own on the same grid
coarsened by ``far_shift`` bits per axis, each far voxel standing for the fine voxel ``v << far_shift``. The
encoder puts there each Gaussian that keeps, at the coarse voxel, at least twice the relative precision (size
over voxel) of the median Gaussian inside the region, picks the shift that saves the most bits, and keeps the
far set where it makes the payload smaller.

The sorted codes are coded as deltas: the bit length of each delta goes through the context
coder of :mod:`gspc.codec.entropy` (spatial context along the curve), the bits below each delta's
leading one are stored raw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import msgpack
import numpy as np

from gspc.codec.entropy import bit_length, decode_matrix, encode_matrix, pack_bits, unpack_bits
from gspc.errors import CodecError
from gspc.format.attribute_section import (
    CONTRACTED_MAX_BITS,
    MAX_BITS,
    MAX_CONTRACTED,
    RESOLUTION,
    Contraction,
    FarSet,
    PositionGrid,
)
from gspc.limits import DecodeBudget

# Region of interest: R = ROI_MARGIN times the median distance of the Gaussians from their median. The
# mapping is the identity up to 2 R (the first octave keeps its scale), so only Gaussians beyond 6 median
# distances are contracted. Bounded objects lie inside (bench/unbounded.md) and keep the plain grid (version
# 1); a background shell or far floaters do not, even when they hold up to half the Gaussians.
ROI_QUANTILE = 0.5
ROI_MARGIN = 3.0
IDENTITY_RADIUS = 2.0  # in units of R: where contraction starts
# The core a contracted grid keeps at the world's scale, in median distances from the median (6): the region
# synthesised cameras frame (gspc/views.py).
CORE_DISTANCES = IDENTITY_RADIUS * ROI_MARGIN
FAR_MAX_SHIFT = 8  # the far set's coarsening is chosen among 1..8 bits per axis (spec 10.1 allows 1..bits-1)
# Bits of relative precision a far Gaussian keeps above the median inside the region: of margins 0, 1 and 2,
# 1 gains the bird fit most at equal bytes (bench/far_set.md, "Reading").
FAR_MARGIN_BITS = 1


def grid_bits(precision: float) -> int:
    """Integer bits per axis of a grid of ``precision`` bits (spec 10.1 codes whole bits; a fractional
    precision is a step between two of them, encoder-only)."""
    return int(math.ceil(precision - 1e-9))


def voxel_grid(means: np.ndarray, precision: float) -> tuple[int, list[float], list[float]]:
    """Measured (bits, per-axis origin, step) of a grid of ``precision`` bits per axis over the points'
    bounds: cubic voxels (:func:`cubic_step`) as many as ``2^precision - 1`` steps per axis would make, and
    the bits the longest axis needs at that size (at most MAX_BITS; beyond, the voxels grow)."""
    if not 1 <= grid_bits(precision) <= MAX_BITS or not precision >= 1:
        raise CodecError(f"position bits must be 1-{MAX_BITS}, got {precision}")
    means = np.asarray(means, dtype=np.float64)
    lo = means.min(0)
    extent = means.max(0) - lo
    step = cubic_step(extent, precision)
    bits = span_bits(extent, step)
    if bits > MAX_BITS:
        step, bits = step * 2.0 ** (bits - MAX_BITS), MAX_BITS
    step = resolvable_step(lo, step, bits)
    return bits, [float(x) for x in lo], [float(x) for x in step]


def resolvable_step(
    lo: np.ndarray, step: np.ndarray, bits: int, floor: np.ndarray | None = None
) -> np.ndarray:
    """``step`` per axis, coarsened where the grid's span (2^bits - 1) step is under RESOLUTION of the
    larger of |lo| and the far corner's magnitude, or under ``floor`` (spec 10.1): only a flat axis far from
    the origin (its step 1 whatever its coordinate), or a grid of less than one binary32 step, needs it."""
    out = np.array(step, np.float64)
    least = np.zeros(3) if floor is None else np.asarray(floor, np.float64)
    top = float((1 << bits) - 1)
    for a in range(3):
        for _ in range(4):  # the corner moves with the step: settles at once
            corner = max(abs(float(lo[a])), abs(float(lo[a]) + top * out[a]))
            need = max(RESOLUTION * corner, float(least[a])) / top
            if top * out[a] >= max(RESOLUTION * corner, float(least[a])):
                break
            out[a] = need * (1.0 + 2.0**-20)
    return out


def cubic_step(extent: np.ndarray, precision: float) -> np.ndarray:
    """Per axis, the side of a cubic voxel: the geometric mean of the axes' extents over ``2^precision - 1``
    (over the axes the points spread along; 1 for a flat axis). Steps in proportion to each axis's extent
    would make a tall statue's voxels much longer than wide: cubic ones, the same count, err less in squared
    distance, and the statues code fewer bytes at equal PSNR (bench/precision.md, "Cubic voxels")."""
    spread = extent > 0
    if not spread.any():
        return np.ones(3)
    side = float(np.exp(np.log(extent[spread]).mean())) / (2.0**precision - 1.0)
    return np.where(spread, side, 1.0)


def span_bits(extent: np.ndarray, step: np.ndarray) -> int:
    """The bits per axis a grid of ``step`` needs to hold points ``extent`` apart on every axis."""
    return max(1, int(np.ceil(np.log2((extent / step).max() + 1.0) - 1e-9)))


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
    order spec 10.1 gives (so every decoder computes the same float32 bits). The grid's bounds (spec 10.1,
    gspc/format/attribute_section.py) keep rho below 56: the octave ``e`` is a small exact integer."""
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


def contracted_grid(
    y: np.ndarray, precision: float, centre_floor: np.ndarray | None = None
) -> tuple[int, list[float], list[float]]:
    """(grid bits, lo, step) in grid space: the voxel size a grid of ``precision`` bits has over the Gaussians
    the mapping leaves as they are (|y| <= 2), with as many bits as the whole scene's extent needs at that
    size (at most MAX_BITS; beyond, the voxels grow), spanning at least ``centre_floor`` per axis (what
    binary32 resolves at the region's centre, spec 10.1)."""
    inside = np.sqrt((y * y).sum(1)) <= IDENTITY_RADIUS
    core = y[inside] if inside.any() else y
    core_bounds = np.stack([core.min(0), core.max(0)])
    return _contracted_grid(y.min(0), y.max(0), core_bounds, precision, centre_floor)


def resolution_floor(contraction: Contraction) -> np.ndarray:
    """The least span per axis of a grid in ``contraction``'s space: what binary32 resolves at the region's
    centre (spec 10.1)."""
    return RESOLUTION * np.abs(np.asarray(contraction.centre)) / contraction.radius * (1.0 + 2.0**-20)


def _contracted_grid(
    lo: np.ndarray,
    hi: np.ndarray,
    core: np.ndarray,
    precision: float,
    centre_floor: np.ndarray | None = None,
) -> tuple[int, list[float], list[float]]:
    """:func:`contracted_grid` from the bounds: all the points' (``lo``, ``hi``), the core's (2 x 3)."""
    step = cubic_step(core[1] - core[0], precision)
    need = span_bits(hi - lo, step)
    bits = min(max(grid_bits(precision), need), CONTRACTED_MAX_BITS)
    if need > CONTRACTED_MAX_BITS:
        step = step * 2.0 ** (need - CONTRACTED_MAX_BITS)
    step = resolvable_step(lo, step, bits, centre_floor)
    return bits, [float(x) for x in lo], _inside_bound(lo, hi, step, bits)


def _inside_bound(lo: np.ndarray, hi: np.ndarray, step: np.ndarray, bits: int) -> list[float]:
    """The step per axis, made finer where the grid's far corner would pass the format's bound on grid space
    (MAX_CONTRACTED, spec 10.1: a grid spans up to twice its points' extent); the points stay covered."""
    out = []
    for a, s, h in zip(lo, step, hi):
        top = float(a) + float((1 << bits) - 1) * float(s)
        if top > MAX_CONTRACTED and h <= MAX_CONTRACTED:
            s = (MAX_CONTRACTED - a) / float((1 << bits) - 1)
            while float(a) + float((1 << bits) - 1) * s > MAX_CONTRACTED:  # at most an ulp or two
                s = float(np.nextafter(s, 0.0))
        out.append(float(s))
    return out


def curve_order(
    means: np.ndarray, precision: float, sizes: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, PositionGrid]:
    """Voxels of the (fine) grid in decoded order, the permutation of the input, and the grid (contracted
    where the scene is unbounded, with a far set coded on a coarser grid where one pays) of ``precision``
    bits per axis over the positions (fractional: :func:`voxel_grid`). ``sizes``: each
    Gaussian's world size (the encoder's choice of a far set needs it; None, no far set). CodecError where
    the scene's positions lie beyond the format's bounds (spec 10.1)."""
    return grid_order(means, grid_frame(means).grid(precision), sizes)


@dataclass(frozen=True)
class GridFrame:
    """What a scene's grid at any precision is made from: its contraction (None: a bounded scene) and the
    bounds of its points in grid space, all of them and those the contraction leaves as they are. The
    spatial tiles of a scene code on their scene's grid, made from its frame (gspc/encoder/tiles.py)."""

    contraction: Contraction | None
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    core_lo: tuple[float, float, float]
    core_hi: tuple[float, float, float]

    def grid(self, precision: float) -> PositionGrid:
        """The grid of ``precision`` bits per axis (:func:`voxel_grid`, :func:`contracted_grid`)."""
        lo, hi = np.asarray(self.lo), np.asarray(self.hi)
        if self.contraction is None:
            bits, lo_, step = voxel_grid(np.stack([lo, hi]), precision)
            return PositionGrid(bits, tuple(lo_), tuple(step))
        core = np.stack([np.asarray(self.core_lo), np.asarray(self.core_hi)])
        bits, lo_, step = _contracted_grid(lo, hi, core, precision, resolution_floor(self.contraction))
        return PositionGrid(bits, tuple(lo_), tuple(step), self.contraction)


def grid_frame(means: np.ndarray) -> GridFrame:
    """The frame of ``means``'s grid: contracted where the scene is unbounded (:func:`region_of_interest`)."""
    roi = region_of_interest(means)
    if roi is None:
        m = np.asarray(means, np.float64)
        lo, hi = tuple(m.min(0).tolist()), tuple(m.max(0).tolist())
        return GridFrame(None, lo, hi, lo, hi)
    centre, radius = roi
    y = contract(means, centre, radius)
    inside = np.sqrt((y * y).sum(1)) <= IDENTITY_RADIUS
    core = y[inside] if inside.any() else y
    contraction = Contraction(tuple(float(c) for c in centre), radius)
    return GridFrame(
        contraction,
        tuple(y.min(0).tolist()),
        tuple(y.max(0).tolist()),
        tuple(core.min(0).tolist()),
        tuple(core.max(0).tolist()),
    )


def grid_coordinates(means: np.ndarray, grid: PositionGrid) -> np.ndarray:
    """Positions in the grid's space (contracted where the grid is), float64."""
    if grid.contraction is None:
        return np.asarray(means, np.float64)
    return contract(means, grid.contraction.centre, grid.contraction.radius)


def grid_order(
    means: np.ndarray,
    grid: PositionGrid,
    sizes: np.ndarray | None = None,
    reference: float | None = None,
) -> tuple[np.ndarray, np.ndarray, PositionGrid]:
    """:func:`curve_order` on a given ``grid`` (its far set, if any, ignored: one is chosen here from
    ``sizes``, against the median precision ``reference`` where given, else the points' own)."""
    grid = replace(grid, far=None)
    y = grid_coordinates(means, grid)
    lo, step, bits = list(grid.lo), list(grid.step), grid.bits
    v = voxelise(y, lo, step, bits)
    order = np.argsort(morton_encode(v, bits), kind="stable")
    if grid.contraction is None or sizes is None:
        return v[order], order, grid
    shift, far = far_set(means, y, sizes, grid, reference)
    if far is None:
        return v[order], order, grid
    near_idx, far_idx = np.flatnonzero(~far), np.flatnonzero(far)
    coarse = voxelise(y[far_idx], lo, [s * 2.0**shift for s in step], bits - shift)
    near_idx = near_idx[np.argsort(morton_encode(v[near_idx], bits), kind="stable")]
    far_order = np.argsort(morton_encode(coarse, bits - shift), kind="stable")
    far_grid = replace(grid, far=FarSet(int(far.sum()), int(shift)))
    far_voxels = np.concatenate([v[near_idx], np.left_shift(coarse[far_order], shift)])
    # A second curve has its own models and restarts its gaps: a small far set can cost more than it saves,
    # so it is kept only where the payload is smaller.
    if len(encode_positions(far_voxels, far_grid)) >= len(encode_positions(v[order], grid)):
        return v[order], order, grid
    return far_voxels, np.concatenate([near_idx, far_idx[far_order]]), far_grid


def far_set(
    means: np.ndarray, y: np.ndarray, sizes: np.ndarray, grid: PositionGrid, reference: float | None = None
) -> tuple[int, np.ndarray | None]:
    """(shift, mask) of the far set for a contracted grid, or (0, None) where none pays (see the module).

    Relative precision is size over the voxel's world size across the line of sight from the region's
    centre (the contraction's tangential stretch |u| / |y|). A Gaussian beyond the identity radius may join
    the far set at shift k if its relative precision is at least 2^(k + FAR_MARGIN_BITS) times the median
    inside; the k that saves the most bits (k bits per axis for each member) wins. Encoder-only: the file
    states the set. ``reference``: the median inside, where the points are a part of the scene (a tile)."""
    outside, precision = _relative_precision(means, y, sizes, grid)
    if not outside.any() or outside.all():
        return 0, None
    if reference is None:
        reference = float(np.median(precision[~outside]))
    if not reference > 0:
        return 0, None
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.floor(np.log2(precision / reference) - FAR_MARGIN_BITS)  # the shift each Gaussian allows
    room = np.where(outside & np.isfinite(room), room, 0).astype(np.int64)
    shifts = np.arange(1, min(FAR_MAX_SHIFT, grid.bits - 1) + 1)
    saved = [k * int((room >= k).sum()) for k in shifts]
    if not saved or max(saved) == 0:
        return 0, None
    k = int(shifts[int(np.argmax(saved))])
    far = room >= k
    if far.all():  # the near curve is never empty (spec 10.1)
        return 0, None
    return k, far


def _relative_precision(
    means: np.ndarray, y: np.ndarray, sizes: np.ndarray, grid: PositionGrid
) -> tuple[np.ndarray, np.ndarray]:
    """(beyond the identity radius, each Gaussian's size over its voxel's world size across the line of
    sight): the far set's measure (:func:`far_set`)."""
    roi = grid.contraction
    u = np.sqrt(((np.asarray(means, np.float64) - np.asarray(roi.centre)) ** 2).sum(1)) / roi.radius
    rho = np.sqrt((y * y).sum(1))
    outside = u > IDENTITY_RADIUS
    voxel = max(grid.step) * roi.radius * np.where(outside, u / np.maximum(rho, 1e-300), 1.0)
    return outside, np.asarray(sizes, np.float64) / voxel


def far_reference(means: np.ndarray, sizes: np.ndarray, grid: PositionGrid) -> float | None:
    """The median relative precision of the Gaussians inside the identity radius (:func:`far_set`'s
    reference) on ``grid``; None on a plain grid or with none inside."""
    if grid.contraction is None:
        return None
    outside, precision = _relative_precision(means, grid_coordinates(means, grid), sizes, grid)
    return float(np.median(precision[~outside])) if (~outside).any() else None


def positions(v: np.ndarray, grid: PositionGrid) -> np.ndarray:
    """Decoded float32 positions of voxels under a grid (plain or contracted)."""
    if grid.contraction is not None:
        y = np.asarray(grid.lo, np.float64) + v.astype(np.float64) * np.asarray(grid.step, np.float64)
        return expand(y, grid.contraction.centre, grid.contraction.radius)
    return dequantise(v, grid.lo, grid.step)


def cell_half_widths(means: np.ndarray, grid: PositionGrid) -> np.ndarray:
    """Half-widths of a box holding each decoded position's voxel cell in world space: (N, 3), or (1, 3)
    for the plain grid, where every cell is the same."""
    half = np.asarray(grid.step, np.float64)[None, :] / 2
    roi = grid.contraction
    if roi is None:
        return half
    r = np.sqrt(((np.asarray(means, np.float64) - np.asarray(roi.centre)) ** 2).sum(1)) / roi.radius
    # The mapping stretches grid space by 2^e <= r in octave e >= 1 (none below 2 R); a cell may reach into
    # the next octave: 2 r bounds it there, and from 1.5 R on to cover cells that cross 2 R.
    stretch = np.where(r < 1.5, 1.0, np.maximum(1.0, 2.0 * r))
    near, shift = grid.split(len(r))
    stretch[near:] *= 2.0**shift  # the far set's voxels are 2^shift fine voxels wide
    return half * roi.radius * stretch[:, None]


def encode_positions(voxels: np.ndarray, grid: PositionGrid) -> bytes:
    """The POSN payload of voxels in decoded order (curve_order's): one curve, or the near curve and the far
    set's on the coarser grid."""
    bits = grid.bits
    near, shift = grid.split(len(voxels))
    parts = _encode_curve(voxels[:near], bits)
    if near < len(voxels):
        parts += _encode_curve(np.right_shift(voxels[near:], shift), bits - shift)
    return msgpack.packb(parts, use_bin_type=True)


def decode_positions(
    payload: bytes, grid: PositionGrid, n: int, budget: DecodeBudget | None = None
) -> np.ndarray:
    """Voxels of the fine grid in decoded order from a POSN payload."""
    bits = grid.bits
    near, shift = grid.split(n)
    try:
        parts = msgpack.unpackb(payload, raw=False)
    except Exception as err:
        raise CodecError(f"corrupt position payload ({type(err).__name__})") from None
    expected = 2 if near == n else 4
    if not (isinstance(parts, list) and len(parts) == expected and all(isinstance(p, bytes) for p in parts)):
        raise CodecError(f"position payload is not an array of {expected} msgpack bins")
    v = _decode_curve(parts[0], parts[1], bits, near, budget)
    if near == n:
        return v
    far = np.left_shift(_decode_curve(parts[2], parts[3], bits - shift, n - near, budget), shift)
    return np.concatenate([v, far])


def _encode_curve(v_sorted: np.ndarray, bits: int) -> list[bytes]:
    """[classes, raw] of voxels already in curve order."""
    code = morton_encode(v_sorted, bits)
    delta = np.diff(code, prepend=0)
    lengths = bit_length(delta)
    mantissa_len = np.maximum(lengths - 1, 0)
    return [encode_matrix(lengths[:, None]), pack_bits(delta.astype(np.uint64), mantissa_len)]


def _decode_curve(classes: bytes, raw: bytes, bits: int, n: int, budget: DecodeBudget | None) -> np.ndarray:
    lengths = decode_matrix(classes, (n, 1), budget)[:, 0]
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
