"""The compositor compiled for the CPU (numba): the same rules and tile lists as rasterize.py's torch walk.

Why a second implementation: the torch walk evaluates every listed Gaussian at all 64 pixels of its tile
in many full-size passes (one per elementwise op), while most pairs reach few of them (bench/render.md's
work columns, visits per pair; "Moved from code comments"). Here each
(tile, Gaussian) pair walks only the tile rows its alpha >= 1/255 ellipse reaches, a row's TILE pixels as
one vector operation (exp(-q / 2) by one multiplication per pixel from the row above; the rules' alpha test
skips the pixels outside the ellipse), and every pixel's state (transmittance, what the Gaussians after it
still add) stays in cache (on the stack) instead of full-size arrays. The torch walk remains for other
devices (and as the tests' second opinion).

Rules (rasterize.py's docstring, reference.py): alpha = min(0.99, o exp(-q / 2)), q = d^T conic d,
d = pixel centre - mean; alpha < 1/255 skipped; a pixel stops before the Gaussian that would take its
transmittance below 1e-4. Arithmetic is float64 whatever the input dtype; results are cast back.

Backward: the closed form of compositing (rasterize.py), walked front to back as the forward walked:
dL/dalpha_i = g_i T_i - R_i / (1 - alpha_i), g_i = dL/dw_i, R_i = sum_{j > i} w_j g_j, which starts as
the pixel's grad . output. On one thread each pair adds its gradient straight into its Gaussian's, in list
order (tile by tile). On several, tiles run in parallel: a Gaussian's first pair in list order adds into
its Gaussian's row (no other pair touches it meanwhile), each later pair writes a row of its own, and those
are added to their Gaussians' rows afterwards, in list order. Either way each Gaussian's gradient is the
same sum in the same order, whatever the threads and their schedule.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from gspc.render.intrinsics import prefetch, stack_array
from gspc.render.kernels import JIT, ROWS_PER_TASK, block_bounds, parallel
from gspc.render.rules import (
    ALPHA_MAX,
    ALPHA_MIN,
    EXTENT_ABS_MARGIN,
    EXTENT_REL_MARGIN,
    PIXELS,
    T_MIN,
    THRESHOLD_REL_MARGIN,
    TILE,
)

# The ellipse q <= 2 ln(255 o) bounds the pixels a pair visits; widened so that round-off never leaves out
# a pixel whose computed alpha reaches 1/255 (alpha itself is then tested exactly as the rules say).
SPAN_MARGIN = 1e-3  # pixels
FIELDS = 7  # pack(): mean x, mean y, conic a, b, c, opacity, threshold; then the features
# Features composited: r, g, b, depth and a 1 (its composite is the alpha image). A fixed count keeps each
# pair's features in registers and the per-pixel sums unrolled (bench/render.md, "Moved from code comments").
FEATURES = 5
GRADS = 6  # gradient columns before the features: d mean x, d mean y, d a, d b, d c, d opacity
AHEAD = 4  # pairs: each pair's record is prefetched while the pair AHEAD before it is walked
STATS = 2  # composite_forward's counts per tile: pairs walked, pixel visits
if TILE != 8:  # _lane_total adds up exactly 8 columns
    raise ImportError("the compiled compositor is written for 8x8 tiles")
# Divisors (kernels.JIT has no zero checks): conic a and its determinant are bounded away from 0 by the
# low-pass filter, 1 - alpha >= 0.01 by the cap, opacity >= 1/255 for a listed Gaussian.


@numba.njit(inline="always", error_model="numpy")
def _ellipse(rec):
    """A pair's constants: (mean x, y, conic a, b, c, opacity, and of the ellipse q <= thr: a thr,
    det = ac - b^2, 1 / a, -b / a), computed once per pair rather than once per row."""
    a, b, c, thr = rec[2], rec[3], rec[4], rec[6]
    inv_a = 1.0 / a
    return rec[0], rec[1], a, b, c, rec[5], a * thr, a * c - b * b, inv_a, -b * inv_a


@numba.njit(inline="always", error_model="numpy")
def _row_span(ell, dy, x0):
    """First and last pixel column (0..TILE-1) of the tile starting at x0 whose centre can lie inside the
    ellipse a dx^2 + 2 b dx dy + c dy^2 <= thr on this row; (1, 0) when none does. On the row, that is
    dx + b dy / a within +-sqrt(a thr - det dy^2) / a; ``ell`` from _ellipse()."""
    mx, ath, det, inv_a, nba = ell[0], ell[6], ell[7], ell[8], ell[9]
    disc = ath - det * dy * dy
    if disc < 0.0:
        return 1, 0
    half = math.sqrt(disc) * inv_a
    centre = mx + nba * dy
    lo = math.ceil(centre - half - SPAN_MARGIN - 0.5 - x0)
    hi = math.floor(centre + half + SPAN_MARGIN - 0.5 - x0)
    return max(int(lo), 0), min(int(hi), TILE - 1)


@numba.njit(inline="always", error_model="numpy")
def _row_range(ell, y0):
    """First and last pixel row (0..TILE-1) of the tile starting at y0 that the ellipse can reach:
    |dy| <= sqrt(a thr / det); ``ell`` from _ellipse()."""
    my, ath, det = ell[1], ell[6], ell[7]
    half = math.sqrt(max(ath, 0.0) / det)
    lo = math.ceil(my - half - SPAN_MARGIN - 0.5 - y0)
    hi = math.floor(my + half + SPAN_MARGIN - 0.5 - y0)
    return max(int(lo), 0), min(int(hi), TILE - 1)


# A tile's per-pixel state, one block of PIXELS each: the forward's transmittance and its FEATURES sums;
# the backward's transmittance, R and dL/d image (FEATURES).
_forward_state = stack_array(PIXELS * (1 + FEATURES))
_backward_state = stack_array(PIXELS * (2 + FEATURES))
# A pair's walk, one value per tile column: e = o exp(-q / 2) on the current row, its factor to the next row,
# and (backward) dx = pixel centre x - mean x.
_row_values = stack_array(TILE)
_row_factors = stack_array(TILE)
_row_dx = stack_array(TILE)
# The backward's per-column partial sums of a pair (LANE_SUMS of them), added up when the pair is done:
# w g_k for each feature k, and gp, gp dy, gp dy^2 (gp = dL/d power; dx is a column's constant).
LANE_SUMS = FEATURES + 3
_lane_sums = stack_array(LANE_SUMS * TILE)


@numba.njit(inline="always", error_model="numpy")
def _row_start(ell, row, x0, y0, er, vr):
    """Start a pair's walk at ``row`` of the tile at (x0, y0): er[col] = o exp(-q / 2) at its pixel centres,
    vr[col] the factor that moves er[col] one row down; returns exp(-c), the factor that moves vr[col] one row
    down (q = a dx^2 + 2 b dx dy + c dy^2 is quadratic, so both factors are exponentials of linear terms).

    Why: each row of the pair is then TILE multiplications from the last and a pair needs six exponentials,
    not one per pixel. Every pixel of the tile in the rows walked is within a tile's diagonal of the ellipse
    (the ellipse reaches a pixel centre of those rows), where exp(-q / 2) > 1e-150 (q <= ~600 by the
    low-pass filter): nothing under- or overflows in float64 and the error stays at round-off."""
    mx, my, a, b, c, o = ell[0], ell[1], ell[2], ell[3], ell[4], ell[5]
    dx, dy = x0 + 0.5 - mx, y0 + row + 0.5 - my
    e = o * math.exp(-0.5 * (a * dx * dx + 2.0 * b * dx * dy + c * dy * dy))
    s = math.exp(-(a * dx + b * dy) - 0.5 * a)  # e's factor to the next column
    v = math.exp(-(b * dx + c * dy) - 0.5 * c)  # e's factor to the next row
    ea, eb = math.exp(-a), math.exp(-b)
    for col in range(TILE):
        er[col] = e
        vr[col] = v
        e *= s
        s *= ea
        v *= eb
    return math.exp(-c)


@numba.njit(inline="always", error_model="numpy")
def _features(rec):
    return rec[FIELDS], rec[FIELDS + 1], rec[FIELDS + 2], rec[FIELDS + 3], rec[FIELDS + 4]


@numba.njit(inline="always", error_model="numpy")
def _visit(tr, raw):
    """One Gaussian at one pixel by the rules, without branches (so that a row's pixels run as one vector
    operation): (alpha, T after it, whether the pixel stops here); alpha 0 where it is not composited (pixel
    stopped earlier, T < 0, alpha < 1/255, or it would take T below 1e-4); a stopped pixel's T becomes -1."""
    alpha = min(ALPHA_MAX, raw)
    after = tr * (1.0 - alpha)
    ok = (tr >= 0.0) & (alpha >= ALPHA_MIN)
    stop = ok & (after < T_MIN)
    used = ok & (after >= T_MIN)
    return (alpha if used else 0.0), (after if used else (-1.0 if stop else tr)), stop


@numba.njit(inline="always", error_model="numpy")
def _tile_pixels(t, tiles_x, size, trans):
    """Tile t's origin (x0, y0) and its pixels inside the image; trans = 1 there, and -1 (stopped from the
    start) beyond the image's right and bottom edges, so that edge tiles end when their image pixels do."""
    x0, y0 = (t % tiles_x) * TILE, (t // tiles_x) * TILE
    live = 0
    for pix in range(PIXELS):
        inside = _inside(x0, y0, pix, size)
        trans[pix] = 1.0 if inside else -1.0
        live += inside
    return x0, y0, live


@numba.njit(inline="always", error_model="numpy")
def _inside(x0, y0, pix, size):
    """Whether pixel pix of the tile at (x0, y0) lies inside the image of ``size`` (width, height)."""
    return x0 + pix % TILE < size[0] and y0 + pix // TILE < size[1]


@numba.njit(inline="always", error_model="numpy")
def _row_visits(ell, y0, x0, row_lo, row_hi):
    """The pixels of rows row_lo..row_hi whose centre can lie inside the pair's ellipse (the work that
    walk_counts reports; the walk itself evaluates whole rows)."""
    visits = 0
    for row in range(row_lo, row_hi + 1):
        lo, hi = _row_span(ell, y0 + row + 0.5 - ell[1], x0)
        visits += max(hi - lo + 1, 0)
    return visits


@numba.njit(**JIT)
def _tile_forward(t, gaussians, gauss, start, count, tiles_x, size, image, stats, counting):
    """Tile t of composite_forward. Each pair walks the rows its ellipse reaches, every pixel of a row (a
    pixel outside the ellipse has alpha < 1/255, which the rules skip), as one vector operation; indices are
    unsigned so that no negative-index wraparound stands in the way."""
    n = count[t]
    if n == 0:
        return
    state = numba.carray(_forward_state(), (PIXELS * (1 + FEATURES),))  # T, then the sums
    x0, y0, live = _tile_pixels(t, tiles_x, size, state)
    state[PIXELS:] = 0.0
    er = numba.carray(_row_values(), (TILE,))
    vr = numba.carray(_row_factors(), (TILE,))
    visits = 0
    p = start[t]
    while p < start[t] + n and live > 0:
        if p + AHEAD < start[t] + n:
            prefetch(gaussians, np.int64(gauss[p + AHEAD]))
        rec = gaussians[gauss[p]]
        p += 1
        ell = _ellipse(rec)
        f0, f1, f2, f3, f4 = _features(rec)
        row_lo, row_hi = _row_range(ell, y0)
        if counting:
            visits += _row_visits(ell, y0, x0, row_lo, row_hi)
        ec = _row_start(ell, row_lo, x0, y0, er, vr)
        for row in range(row_lo, row_hi + 1):
            base = np.uint64(row * TILE)
            stops = 0
            for col in range(TILE):
                c = np.uint64(col)
                pix = base + c
                raw = er[c]
                er[c] = raw * vr[c]
                vr[c] *= ec
                alpha, after, stop = _visit(state[pix], raw)
                w = alpha * state[pix]
                state[pix] = after
                stops += stop
                state[pix + np.uint64(PIXELS)] += w * f0
                state[pix + np.uint64(2 * PIXELS)] += w * f1
                state[pix + np.uint64(3 * PIXELS)] += w * f2
                state[pix + np.uint64(4 * PIXELS)] += w * f3
                state[pix + np.uint64(5 * PIXELS)] += w * f4
            live -= stops
    stats[t, 0], stats[t, 1] = p - start[t], visits
    for pix in range(PIXELS):
        if _inside(x0, y0, pix, size):
            for k in range(FEATURES):
                image[y0 + pix // TILE, x0 + pix % TILE, k] = state[(k + 1) * PIXELS + pix]


@numba.njit(**JIT)
def _forward_serial(gaussians, gauss, start, count, tiles_x, size, image, stats, counting):
    for t in range(len(start)):
        _tile_forward(t, gaussians, gauss, start, count, tiles_x, size, image, stats, counting)


@numba.njit(parallel=True, **JIT)
def _forward_parallel(gaussians, gauss, start, count, tiles_x, size, image, stats, counting):
    for t in numba.prange(len(start)):
        _tile_forward(t, gaussians, gauss, start, count, tiles_x, size, image, stats, counting)


@numba.njit(**JIT)
def _tile_backward(
    t, gaussians, gauss, start, count, tiles_x, size, grad_image, image, rows, slot, grads, own, used
):
    """Tile t of composite_backward, walked as _tile_forward walks it. A pair's sums over its pixels are
    kept per tile column (vector lanes) and added up when the pair is done: into its Gaussian's row of
    ``grads`` (rows[gauss[p]]), or, where slot[p] >= 0 (``slot`` may be empty: none), into row slot[p] of
    ``own``; the pairs not walked get slot -1."""
    n = count[t]
    if n == 0:
        return
    state = numba.carray(_backward_state(), (PIXELS * (2 + FEATURES),))  # T, R, then dL/d image
    x0, y0, live = _tile_pixels(t, tiles_x, size, state)
    state[PIXELS:] = 0.0  # dL/d image is 0 beyond the image
    for pix in range(PIXELS):
        if _inside(x0, y0, pix, size):
            y, x = y0 + pix // TILE, x0 + pix % TILE
            for k in range(FEATURES):
                state[(2 + k) * PIXELS + pix] = grad_image[y, x, k]
                state[PIXELS + pix] += grad_image[y, x, k] * image[y, x, k]  # R: grad . output
    er = numba.carray(_row_values(), (TILE,))
    vr = numba.carray(_row_factors(), (TILE,))
    dxs = numba.carray(_row_dx(), (TILE,))
    lanes = numba.carray(_lane_sums(), (LANE_SUMS * TILE,))
    rem_at, g_at = np.uint64(PIXELS), np.uint64(2 * PIXELS)
    depth_used, alpha_used = used[3], used[4]
    for p in range(start[t], start[t] + n):
        if p + AHEAD < start[t] + n:
            prefetch(gaussians, np.int64(gauss[p + AHEAD]))
        rec = gaussians[gauss[p]]
        ell = _ellipse(rec)
        a, b, c, o = ell[2], ell[3], ell[4], ell[5]
        f0, f1, f2, f3, f4 = _features(rec)
        row_lo, row_hi = _row_range(ell, y0)
        ec = _row_start(ell, row_lo, x0, y0, er, vr)
        for col in range(TILE):
            dxs[col] = x0 + col + 0.5 - ell[0]
        lanes[:] = 0.0
        for row in range(row_lo, row_hi + 1):
            dy = y0 + row + 0.5 - ell[1]
            dy2 = dy * dy
            base = np.uint64(row * TILE)
            stops = 0
            for col in range(TILE):
                cu = np.uint64(col)
                pix = base + cu
                raw = er[cu]
                er[cu] = raw * vr[cu]
                vr[cu] *= ec
                tr = state[pix]
                alpha, after, stop = _visit(tr, raw)
                state[pix] = after
                stops += stop
                w = alpha * tr
                g0, g1 = state[g_at + pix], state[g_at + np.uint64(PIXELS) + pix]
                g2, g3 = state[g_at + np.uint64(2 * PIXELS) + pix], state[g_at + np.uint64(3 * PIXELS) + pix]
                g4 = state[g_at + np.uint64(4 * PIXELS) + pix]
                gw = g0 * f0 + g1 * f1 + g2 * f2
                if depth_used:
                    gw += g3 * f3
                    lanes[np.uint64(3 * TILE) + cu] += w * g3
                if alpha_used:
                    gw += g4 * f4
                    lanes[np.uint64(4 * TILE) + cu] += w * g4
                lanes[cu] += w * g0
                lanes[np.uint64(TILE) + cu] += w * g1
                lanes[np.uint64(2 * TILE) + cu] += w * g2
                rem = state[rem_at + pix] - w * gw
                state[rem_at + pix] = rem
                # dL/d power (power = ln o - q / 2); above the cap alpha does not move.
                gp = (gw * tr - rem / (1.0 - alpha)) * alpha if raw < ALPHA_MAX else 0.0
                lanes[np.uint64(5 * TILE) + cu] += gp
                lanes[np.uint64(6 * TILE) + cu] += gp * dy
                lanes[np.uint64(7 * TILE) + cu] += gp * dy2
            live -= stops
        # d power / d (mean, conic): q = a dx^2 + 2 b dx dy + c dy^2, dx = px - mean x, dy = py - mean y.
        g_pow, g_dx, g_dx2 = _lane_moments(lanes, 5, dxs)
        g_dy, g_dxdy, _ = _lane_moments(lanes, 6, dxs)
        g_dy2 = _lane_total(lanes, 7)
        k_own = slot[p] if len(slot) else -1  # (composite_backward says which)
        add = k_own < 0
        out_row = grads[rows[gauss[p]]] if add else own[k_own]
        _put(out_row, 0, a * g_dx + b * g_dy, add)
        _put(out_row, 1, b * g_dx + c * g_dy, add)
        _put(out_row, 2, -0.5 * g_dx2, add)
        _put(out_row, 3, -g_dxdy, add)
        _put(out_row, 4, -0.5 * g_dy2, add)
        _put(out_row, 5, g_pow / o, add)
        for k in range(FEATURES):
            _put(out_row, GRADS + k, _lane_total(lanes, k), add)
        if live == 0:  # the pairs after this one touch no pixel: their gradients are zero
            if len(slot):  # their own rows are never written: nothing to add
                slot[p + 1 : start[t] + n] = -1
            break


@numba.njit(inline="always", error_model="numpy")
def _put(row, j, v, add):
    """row[j] += v (``add``) or row[j] = v."""
    if add:
        row[j] += v
    else:
        row[j] = v


@numba.njit(inline="always", error_model="numpy")
def _lane_total(lanes, k):
    """The sum of partial sum k over the tile columns (pairwise: a short dependency chain)."""
    b = k * TILE
    left = (lanes[b] + lanes[b + 1]) + (lanes[b + 2] + lanes[b + 3])
    return left + ((lanes[b + 4] + lanes[b + 5]) + (lanes[b + 6] + lanes[b + 7]))


@numba.njit(inline="always", error_model="numpy")
def _lane_moments(lanes, k, dxs):
    """sum_col v, sum_col v dx, sum_col v dx^2 of partial sum k (v) over the tile columns, column col's
    pixels lying dxs[col] right of the mean."""
    s0 = s1 = s2 = 0.0
    for col in range(TILE):
        v = lanes[k * TILE + col]
        vd = v * dxs[col]
        s0 += v
        s1 += vd
        s2 += vd * dxs[col]
    return s0, s1, s2


@numba.njit(**JIT)
def _backward_serial(gaussians, gauss, start, count, tiles_x, size, grad_image, image, rows, grads, used):
    none, own = np.empty(0, np.int64), np.empty((0, GRADS + FEATURES))
    for t in range(len(start)):
        _tile_backward(
            t, gaussians, gauss, start, count, tiles_x, size, grad_image, image, rows, none, grads, own, used
        )


@numba.njit(parallel=True, **JIT)
def _backward_parallel(
    gaussians, gauss, start, count, tiles_x, size, grad_image, image, rows, slot, grads, own, used
):
    for t in numba.prange(len(start)):
        _tile_backward(
            t, gaussians, gauss, start, count, tiles_x, size, grad_image, image, rows, slot, grads, own, used
        )


@numba.njit(inline="always", error_model="numpy")
def ellipse_terms(mx, my, a, b, c, thr):
    """What the exact tile test reads of one Gaussian: (a thr, det = ac - b^2, the half-extents
    hx = sqrt(thr Sigma_xx), hy = sqrt(thr Sigma_yy) of the ellipse q <= thr widened as the box is, and
    dy_r = -b sqrt(thr / (c det)), the y offset of its rightmost point). rasterize.py's torch binning
    computes the same numbers in the same float64 operations, in the same order (its lists must equal these
    lists), from the same thr."""
    det = a * c - b * b
    hx = math.sqrt(thr * c / det) * (1.0 + EXTENT_REL_MARGIN) + EXTENT_ABS_MARGIN
    hy = math.sqrt(thr * a / det) * (1.0 + EXTENT_REL_MARGIN) + EXTENT_ABS_MARGIN
    return a * thr, det, hx, hy, -b * math.sqrt(thr / (c * det))


@numba.njit(inline="always", error_model="numpy")
def tile_columns(ty, mx, my, a, b, terms, lo_x, hi_x):
    """First and last tile column of tile row ty whose pixel centres one Gaussian's ellipse reaches, within
    its box's columns lo_x..hi_x (lo > hi: none); ``terms`` from ellipse_terms().

    The ellipse meets the tile row's band of pixel centres in a convex set: its x range runs from the
    chord's left end at the band's y nearest -dy_r (the leftmost point's) to the right end at the y nearest
    dy_r, each end widened by EXTENT_ABS_MARGIN. rasterize.py computes the same (see ellipse_terms)."""
    ath, det, hx, hy, dyr = terms
    ya = max(ty * TILE + 0.5 - my, -hy)
    yb = min(ty * TILE + (TILE - 0.5) - my, hy)
    if ya > yb:
        return 1, 0
    d = min(max(dyr, ya), yb)
    right = hx if d == dyr else (math.sqrt(max(ath - det * d * d, 0.0)) - b * d) / a + EXTENT_ABS_MARGIN
    d = min(max(-dyr, ya), yb)
    left = -hx if d == -dyr else (-math.sqrt(max(ath - det * d * d, 0.0)) - b * d) / a - EXTENT_ABS_MARGIN
    lo = math.ceil((mx + left - (TILE - 0.5)) / TILE)
    hi = math.floor((mx + right - 0.5) / TILE)
    return max(int(lo), lo_x), min(int(hi), hi_x)


def bin_ellipses(
    lo: np.ndarray,
    hi: np.ndarray,
    means2d: np.ndarray,
    conics: np.ndarray,
    thr: np.ndarray,
    exact: bool,
    tiles_x: int,
    num_tiles: int,
    threads: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tile lists by a counting sort: (gauss, start, count), pairs grouped by tile, Gaussians in input order
    inside each tile, for Gaussian i in the tiles lo[i]..hi[i] (x, y; none when hi < lo) of its box that its
    ellipse q <= thr[i] reaches (``exact``; else every tile of the box).

    On several threads each takes blocks of consecutive Gaussians, counting their pairs per tile, and
    places them after the earlier blocks' pairs of that tile: the same lists."""
    if threads <= 1:
        return _bin_serial(lo, hi, means2d, conics, thr, exact, tiles_x, num_tiles)
    bounds = block_bounds(len(lo), threads)
    with parallel(threads):
        return _bin_parallel(lo, hi, means2d, conics, thr, exact, tiles_x, num_tiles, bounds)


@numba.njit(**JIT)
def _bin_rows(lo, hi, i0, i1):
    """(Gaussian, tile row) entries of Gaussians i0..i1 - 1."""
    rows = 0
    for i in range(i0, i1):
        if hi[i, 0] >= lo[i, 0]:
            rows += max(hi[i, 1] - lo[i, 1] + 1, 0)
    return rows


@numba.njit(**JIT)
def _bin_count(lo, hi, means2d, conics, thr, exact, tiles_x, i0, i1, r, cols, count):
    """Gaussians i0..i1 - 1: each (Gaussian, tile row)'s first and last tile column into cols from row r,
    and their pairs per tile into count (made zero first)."""
    count[:] = 0
    for i in range(i0, i1):
        if hi[i, 0] < lo[i, 0]:
            continue
        mx, my, a, b, c = means2d[i, 0], means2d[i, 1], conics[i, 0], conics[i, 1], conics[i, 2]
        terms = ellipse_terms(mx, my, a, b, c, thr[i]) if exact else (0.0, 1.0, 0.0, 0.0, 0.0)
        for ty in range(lo[i, 1], hi[i, 1] + 1):
            c0, c1 = lo[i, 0], hi[i, 0]
            if exact:
                c0, c1 = tile_columns(ty, mx, my, a, b, terms, c0, c1)
            cols[r, 0], cols[r, 1] = c0, c1
            r += 1
            for tx in range(c0, c1 + 1):
                count[ty * tiles_x + tx] += 1


@numba.njit(**JIT)
def _bin_fill(lo, hi, tiles_x, i0, i1, r, cols, start, fill, gauss):
    """Gaussians i0..i1 - 1 (their columns from row r of cols) into their tiles' lists: tile t's next at
    start[t] + fill[t]."""
    for i in range(i0, i1):
        if hi[i, 0] < lo[i, 0]:
            continue
        for ty in range(lo[i, 1], hi[i, 1] + 1):
            for tx in range(cols[r, 0], cols[r, 1] + 1):
                t = ty * tiles_x + tx
                gauss[start[t] + fill[t]] = i
                fill[t] += 1
            r += 1


@numba.njit(**JIT)
def _starts(count):
    """Where each tile's list starts (exclusive prefix sums), and the pairs in all."""
    start = np.empty(len(count), np.int64)
    total = 0
    for t in range(len(count)):
        start[t] = total
        total += count[t]
    return start, total


@numba.njit(**JIT)
def _bin_serial(lo, hi, means2d, conics, thr, exact, tiles_x, num_tiles):
    n = len(lo)
    cols = np.empty((_bin_rows(lo, hi, 0, n), 2), np.int64)
    count = np.empty(num_tiles, np.int64)
    _bin_count(lo, hi, means2d, conics, thr, exact, tiles_x, 0, n, 0, cols, count)
    start, total = _starts(count)
    gauss = np.empty(total, np.int32)  # (half the bytes of int64 to scatter)
    _bin_fill(lo, hi, tiles_x, 0, n, 0, cols, start, np.zeros(num_tiles, np.int64), gauss)
    return gauss, start, count


@numba.njit(parallel=True, **JIT)
def _bin_parallel(lo, hi, means2d, conics, thr, exact, tiles_x, num_tiles, bounds):
    """bin_ellipses for the blocks of Gaussians bounds[b]..bounds[b + 1] - 1."""
    # Loops only, no whole-array expressions: in a parallel function numba makes each a parallel loop.
    blocks = len(bounds) - 1
    first_row = np.empty(blocks + 1, np.int64)  # each block's first (Gaussian, tile row) entry
    first_row[0] = 0
    for b in numba.prange(blocks):
        first_row[b + 1] = _bin_rows(lo, hi, bounds[b], bounds[b + 1])
    for b in range(blocks):
        first_row[b + 1] += first_row[b]
    cols = np.empty((first_row[blocks], 2), np.int64)
    place = np.empty((blocks, num_tiles), np.int64)  # each block's pairs per tile, then where they go
    for b in numba.prange(blocks):
        i0, i1 = bounds[b], bounds[b + 1]
        _bin_count(lo, hi, means2d, conics, thr, exact, tiles_x, i0, i1, first_row[b], cols, place[b])
    count = np.empty(num_tiles, np.int64)
    for g in numba.prange((num_tiles + 255) // 256):
        for t in range(g * 256, min(num_tiles, g * 256 + 256)):
            total = 0
            for b in range(blocks):
                n = place[b, t]
                place[b, t] = total
                total += n
            count[t] = total
    start, total = _starts(count)
    gauss = np.empty(total, np.int32)
    for b in numba.prange(blocks):
        _bin_fill(lo, hi, tiles_x, bounds[b], bounds[b + 1], first_row[b], cols, start, place[b], gauss)
    return gauss, start, count


def pack(
    order: np.ndarray,
    means2d: np.ndarray,
    conics: np.ndarray,
    opacities: np.ndarray,
    features: np.ndarray,
    threads: int = 1,
) -> np.ndarray:
    """(len(order), FIELDS + FEATURES) float64 records of the Gaussians ``order``, in that order: mean x,
    mean y, conic a, b, c, opacity, threshold, the FEATURES - 1 features (colour, depth) and a 1 (its
    composite is the alpha image): one Gaussian's data in one or two cache lines (the kernels read Gaussians
    scattered). Reads the projection's arrays in their own dtype."""
    out = np.empty((len(order), FIELDS + FEATURES))
    if threads > 1:
        with parallel(threads):
            _pack_parallel(order, means2d, conics, opacities, features, out)
    else:
        _pack_rows(0, len(order), order, means2d, conics, opacities, features, out)
    return out


@numba.njit(**JIT)
def _pack_rows(lo, hi, order, means2d, conics, opacities, features, out):
    """Records lo..hi - 1 of pack(). The gather (latency-bound at 1M Gaussians) and the logarithms run in
    separate passes."""
    for r in range(lo, hi):
        i = order[r]
        rec = out[r]
        rec[0], rec[1] = means2d[i, 0], means2d[i, 1]
        rec[2], rec[3], rec[4] = conics[i, 0], conics[i, 1], conics[i, 2]
        rec[5] = opacities[i]
        for k in range(FEATURES - 1):
            rec[FIELDS + k] = features[i, k]
        rec[FIELDS + FEATURES - 1] = 1.0
    for r in range(lo, hi):
        o = out[r, 5]
        thr = 2.0 * math.log(o / ALPHA_MIN) if o > 0.0 else -np.inf
        out[r, 6] = thr * (1.0 + THRESHOLD_REL_MARGIN) + THRESHOLD_REL_MARGIN


@numba.njit(parallel=True, **JIT)
def _pack_parallel(order, means2d, conics, opacities, features, out):
    n = len(order)
    for c in numba.prange((n + ROWS_PER_TASK - 1) // ROWS_PER_TASK):
        lo, hi = c * ROWS_PER_TASK, min(n, (c + 1) * ROWS_PER_TASK)
        _pack_rows(lo, hi, order, means2d, conics, opacities, features, out)


def depth_order(depths: np.ndarray, threads: int = 1) -> np.ndarray:
    """Indices sorting ``depths`` (finite floats) ascending, ties in input order: torch.sort(stable=True)'s
    result, by a radix sort on the float64 bit patterns made order-preserving (negative: all bits flipped;
    otherwise the sign bit set). Several times faster than the comparison sort at 100k depths."""
    bits = depths.astype(np.float64).view(np.uint64)
    keys = np.where(bits >> np.uint64(63), ~bits, bits | np.uint64(1 << 63))
    if threads <= 1:
        return _radix_serial(keys)
    with parallel(threads):
        return _radix_parallel(keys, block_bounds(len(keys), threads))


# A least-significant-byte radix sort: stable ascending order of unsigned 64-bit keys in 8 passes (a pass
# whose byte is the same for every key is skipped). On several threads each pass counts blocks of positions
# apart and moves each block's keys after the earlier blocks' of the same byte: stable, so the order is
# unique, whatever the blocks.


@numba.njit(**JIT)
def _radix_count(keys, idx, i0, i1, shift, count):
    count[:] = 0
    for i in range(i0, i1):
        count[(keys[idx[i]] >> shift) & 255] += 1


@numba.njit(**JIT)
def _radix_place(place, n):
    """place (blocks, 256) from counts to where each block's keys of each byte go; False where one byte
    holds all n keys (nothing moves)."""
    for v in range(256):
        m = 0
        for b in range(place.shape[0]):
            m += place[b, v]
        if m == n:
            return False
    total = 0
    for v in range(256):
        for b in range(place.shape[0]):
            m = place[b, v]
            place[b, v] = total
            total += m
    return True


@numba.njit(**JIT)
def _radix_move(keys, idx, tmp, i0, i1, shift, fill):
    for i in range(i0, i1):
        j = idx[i]
        v = (keys[j] >> shift) & 255
        tmp[fill[v]] = j
        fill[v] += 1


@numba.njit(**JIT)
def _radix_serial(keys):
    n = len(keys)
    idx, tmp = np.arange(n), np.empty(n, np.int64)
    place = np.empty((1, 256), np.int64)
    for shift in range(0, 64, 8):
        _radix_count(keys, idx, 0, n, shift, place[0])
        if _radix_place(place, n):
            _radix_move(keys, idx, tmp, 0, n, shift, place[0])
            idx, tmp = tmp, idx
    return idx


@numba.njit(parallel=True, **JIT)
def _radix_parallel(keys, bounds):
    # (loops only: see _bin_parallel)
    n, blocks = len(keys), len(bounds) - 1
    idx, tmp = np.empty(n, np.int64), np.empty(n, np.int64)
    for i in range(n):
        idx[i] = i
    place = np.empty((blocks, 256), np.int64)
    for shift in range(0, 64, 8):
        for b in numba.prange(blocks):
            _radix_count(keys, idx, bounds[b], bounds[b + 1], shift, place[b])
        if _radix_place(place, n):
            for b in numba.prange(blocks):
                _radix_move(keys, idx, tmp, bounds[b], bounds[b + 1], shift, place[b])
            idx, tmp = tmp, idx
    return idx


def composite_forward(
    gaussians: np.ndarray,
    lists: tuple,
    tiles_x: int,
    size: tuple,
    image: np.ndarray,
    threads: int,
    counting: bool = False,
) -> np.ndarray:
    """image (height, width, FEATURES) float64 = sum_i w_i feat_i per pixel of the image of ``size`` (width,
    height), for records from pack() and the tile lists (gauss, start, count) of gspc/render/rasterize.py's
    TileBins (tiles without pairs are left as they are: pass zeros); returns (tiles, STATS) counts: the pairs
    each tile walked before its pixels stopped, and (``counting``; else 0) its pixel visits: the pixels of
    each walked pair's rows that its ellipse reaches."""
    stats = np.zeros((len(lists[1]), STATS), np.int64)
    size = np.asarray(size, np.int64)
    if threads > 1:
        with parallel(threads):
            _forward_parallel(gaussians, *lists, tiles_x, size, image, stats, counting)
    else:
        _forward_serial(gaussians, *lists, tiles_x, size, image, stats, counting)
    return stats


def composite_backward(
    gaussians: np.ndarray,
    lists: tuple,
    rows: np.ndarray,
    num: int,
    tiles_x: int,
    size: tuple,
    grad_image: np.ndarray,
    image: np.ndarray,
    threads: int,
) -> np.ndarray:
    """(num, GRADS + FEATURES): dL/d (mean x, mean y, conic a, b, c, opacity, features) of every Gaussian,
    record r being the caller's Gaussian rows[r] (the others get zeros), for dL/d image = grad_image
    (height, width, FEATURES) float64 and the forward's ``image``."""
    cols = GRADS + FEATURES
    # Depth's and alpha's image gradients are often all zero (a loss of the colour image alone, on a black
    # background): their terms are then left out of the walk (adding zeros changes no sum).
    used = np.ones(FEATURES, np.bool_)
    used[3:] = np.any(grad_image[..., 3:] != 0.0, axis=(0, 1))
    size = np.asarray(size, np.int64)
    grads = np.zeros((num, cols))
    if threads <= 1:  # one thread: every pair adds straight into its Gaussian's row, rows[gauss]
        _backward_serial(gaussians, *lists, tiles_x, size, grad_image, image, rows, grads, used)
        return grads
    # Threads own tiles, and a Gaussian's pairs lie in several: all but its first get a row of their own.
    slot, later = _later_pairs(lists[0], len(gaussians))
    own = np.empty((later, cols))  # every row is written before it is read
    with parallel(threads):
        _backward_parallel(gaussians, *lists, tiles_x, size, grad_image, image, rows, slot, grads, own, used)
    with parallel(threads):
        _add_later(own, slot, lists[0], rows, grads, threads)
    return grads


@numba.njit(**JIT)
def _later_pairs(gauss, records):
    """(slot, count): slot[p] = -1 for the first pair of each record in list order, else its row in a
    (count, columns) array of the later pairs' rows, in list order."""
    seen = np.zeros(records, np.bool_)
    slot = np.empty(len(gauss), np.int64)
    k = 0
    for p in range(len(gauss)):
        r = gauss[p]
        if seen[r]:
            slot[p] = k
            k += 1
        else:
            seen[r] = True
            slot[p] = -1
    return slot, k


@numba.njit(parallel=True, **JIT)
def _add_later(own, slot, gauss, rows, grads, parts):
    """grads[rows[gauss[p]]] += own[slot[p]] for the later pairs p walked, in list order per Gaussian; the
    records are split into ``parts`` (by index mod parts), each part's Gaussians summed by one task."""
    for part in numba.prange(parts):
        for p in range(len(slot)):
            k = slot[p]
            if k >= 0 and gauss[p] % parts == part:
                row = grads[rows[gauss[p]]]
                for c in range(own.shape[1]):
                    row[c] += own[k, c]
