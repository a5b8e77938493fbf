"""occlusion.py's per-pixel walks compiled for the CPU (numba): where a view turns opaque, and how much of
each Gaussian's footprint lies in front of that.

Both take the projected Gaussians as one tuple (means2d, conics, opacities, depths, extents: float64
arrays, occlusion.py ``_arrays``) and walk each Gaussian's alpha >= 1/255 box pixel by pixel with the
renderer's alpha (spec 10.12: alpha = min(ALPHA_MAX, o exp(-q / 2)), q = d^T conic d at pixel centres,
contributions under ALPHA_MIN skipped).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from gspc.render.kernels import JIT
from gspc.render.rules import ALPHA_MAX, ALPHA_MIN


@numba.njit(inline="always", **JIT)
def _gaussian(g, means2d, conics, opacities, extents, width, height):
    """Gaussian ``g``'s mean, conic and opacity, and its box's pixel range clipped to the image."""
    mx, my, ex, ey = means2d[g, 0], means2d[g, 1], extents[g, 0], extents[g, 1]
    x0, x1 = max(0, int(math.floor(mx - ex))), min(width - 1, int(math.ceil(mx + ex)))
    y0, y1 = max(0, int(math.floor(my - ey))), min(height - 1, int(math.ceil(my + ey)))
    return mx, my, conics[g, 0], conics[g, 1], conics[g, 2], opacities[g], x0, x1, y0, y1


@numba.njit(inline="always", **JIT)
def _alpha(x, y, mx, my, a, b, c, o):
    dx, dy = x + 0.5 - mx, y + 0.5 - my
    return min(ALPHA_MAX, o * math.exp(-0.5 * (a * dx * dx + 2.0 * b * dx * dy + c * dy * dy)))


@numba.njit(**JIT)
def opaque_depths(gaussians: tuple, width: int, height: int, transmittance: float) -> np.ndarray:
    """(height, width) float32: per pixel, the depth of the Gaussian that takes the pixel's transmittance to
    ``transmittance`` or under, walking them nearest first; +inf where it never falls that far."""
    means2d, conics, opacities, depths, extents = gaussians
    far = np.full((height, width), np.inf, dtype=np.float32)
    trans = np.ones((height, width))
    for g in np.argsort(depths):
        if extents[g, 0] < 0:
            continue
        mx, my, a, b, c, o, x0, x1, y0, y1 = _gaussian(g, means2d, conics, opacities, extents, width, height)
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                if far[y, x] < np.inf:
                    continue
                alpha = _alpha(x, y, mx, my, a, b, c, o)
                if alpha < ALPHA_MIN:
                    continue
                trans[y, x] *= 1.0 - alpha
                if trans[y, x] <= transmittance:
                    far[y, x] = depths[g]
    return far


@numba.njit(**JIT)
def shares_in_front(gaussians: tuple, width: int, height: int, far: np.ndarray, cell: float) -> np.ndarray:
    """(M,) float64: per Gaussian, the alpha-weighted share of its footprint whose pixel lies in front of
    ``far`` (a map whose cell covers ``cell`` x ``cell`` of these pixels); 1 for one never drawn."""
    means2d, conics, opacities, depths, extents = gaussians
    out = np.ones(len(depths))
    rows, cols = far.shape
    for g in range(len(depths)):
        if extents[g, 0] < 0:
            continue
        mx, my, a, b, c, o, x0, x1, y0, y1 = _gaussian(g, means2d, conics, opacities, extents, width, height)
        front = total = 0.0
        for y in range(y0, y1 + 1):
            r = min(rows - 1, int(y / cell))
            for x in range(x0, x1 + 1):
                alpha = _alpha(x, y, mx, my, a, b, c, o)
                if alpha < ALPHA_MIN:
                    continue
                total += alpha
                if depths[g] <= far[r, min(cols - 1, int(x / cell))]:
                    front += alpha
        if total > 0.0:
            out[g] = front / total
    return out


@numba.njit(**JIT)
def fold_depths(
    far: np.ndarray, owner: np.ndarray, second: np.ndarray, tile: int, depths: np.ndarray
) -> None:
    """Fold one tile's ``depths`` into the nearest (``far``, its ``owner``) and the second nearest of any
    other tile (``second``), in place."""
    rows, cols = depths.shape
    for y in range(rows):
        for x in range(cols):
            d = depths[y, x]
            if d < far[y, x]:
                if owner[y, x] != tile:
                    second[y, x] = far[y, x]
                far[y, x], owner[y, x] = d, tile
            elif d < second[y, x] and owner[y, x] != tile:
                second[y, x] = d
