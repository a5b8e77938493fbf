"""Tile-based front-to-back alpha compositing: tile lists, and the walk in pure PyTorch.

``composite`` is the only entry point. On the CPU it runs the compiled kernels of composite_cpu.py over
the same tile lists (several times faster: bench/render.md); the torch walk below serves every other
device and is the tests' second implementation. Rules (3DGS):
alpha = min(0.99, o * exp(-q / 2)) with q = d^T conic d, d = pixel centre - mean; alphas below
1/255 are skipped; Gaussians are composited in increasing depth; a pixel stops before the Gaussian
that would take its transmittance below 1e-4. There is deliberately no "skip if q < 0" rule: q
rounds slightly negative at a Gaussian's centre and that rule would drop the Gaussian there.

How it is vectorised: each Gaussian is listed in every 8x8 tile whose pixel centres its alpha >= 1/255
ellipse reaches (``bin_tiles``; lists in depth order). Tiles are processed in chunks, and each chunk walks
its lists in blocks of ``BLOCK`` Gaussians, so one step works on a (tiles, BLOCK, 64 pixels) array; a tile
leaves the walk when its list ends or all its pixels have stopped. In tile-centred pixel coordinates the
exponent is a quadratic, log o - q/2 = k . [1, x, y, x^2, xy, y^2], so one matmul evaluates a whole block
(in base 2: exp2 is several times faster than exp on CPU). Elementwise work is in place and avoids
boolean masks, which are slow on CPU. The backward pass repeats the walk (nothing per pixel and
Gaussian is stored; the per-pair arrays are kept from the forward) and uses the closed-form gradient of
compositing: with weights w_i = alpha_i T_i and g_i = dL/dw_i,
dL/dalpha_i = g_i T_i - (sum_{j>i} w_j g_j) / (1 - alpha_i). Pairs index the caller's (unsorted) rows,
so gradients scatter straight back to them (bench/render.md lists these choices beside its timings).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from gspc.errors import InputError
from gspc.limits import MAX_VIEW_PAIRS
from gspc.render.kernels import pick_kernel
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

BLOCK = 32  # Gaussians per tile per step
DEAD_POWER = -1e4  # exponent of padding entries: exp2() is exactly 0
LOG2_E = 1.4426950408889634


@dataclass(frozen=True)
class WalkSizes:
    """How the walk cuts its work, by device (``walk_sizes``); the composited result is the same up to
    round-off whatever the sizes (tests/test_render.py)."""

    step_budget: int  # elements of one (tiles, BLOCK, pixels) array: tiles per chunk, and memory
    scan_loop_from: int  # steps of at least this many elements scan with a loop over the BLOCK slices


# CPU: steps sized for its caches. A Python loop over the BLOCK slices (one in-place op each) is cheaper per
# element than torch's CPU cumprod/cumsum along the middle axis of a (tiles, BLOCK, 64) array but pays a
# fixed cost per op, so it wins only on large steps (bench/render.md, "Moved from code comments").
CPU_WALK = WalkSizes(step_budget=1 << 19, scan_loop_from=1 << 19)
# GPU: scans are one kernel each (the loop's 32 launches per scan cost more than a scan there), and
# chunks of 1024 tiles (2^21 elements): faster than CPU_WALK, and larger chunks are slower
# (bench/gpu_walk.md, "Reading").
GPU_WALK = WalkSizes(step_budget=1 << 21, scan_loop_from=1 << 62)


def walk_sizes(device: torch.device) -> WalkSizes:
    """The walk's sizes on ``device``: CPU_WALK on the CPU, GPU_WALK elsewhere."""
    return CPU_WALK if device.type == "cpu" else GPU_WALK


@dataclass
class TileBins:
    """Which Gaussians (indices into depth-sorted arrays) touch which tile, tile lists contiguous."""

    gauss: torch.Tensor  # (P,) Gaussian of each (tile, Gaussian) pair, grouped by tile, depth order within
    start: torch.Tensor  # (tiles,) first pair of each tile
    count: torch.Tensor  # (tiles,) pairs of each tile
    tiles_x: int
    tiles_y: int

    @property
    def tile(self) -> torch.Tensor:
        """(P,) the tile of each pair (the torch walk's; the compiled kernels need none)."""
        return torch.repeat_interleave(torch.arange(len(self.count), device=self.count.device), self.count)


def composite(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    features: torch.Tensor,
    depths: torch.Tensor,
    extents: torch.Tensor,
    width: int,
    height: int,
    kernel: str = "auto",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Composite Gaussians front to back; returns (sum_i w_i features_i (H, W, C), alpha (H, W)).

    means2d (M, 2) pixels, conics (M, 3) as (a, b, c), opacities (M,), features (M, C), depths (M,)
    sort key (ties keep input order), extents (M, 2) half-sizes of the box outside which alpha < 1/255,
    negative for Gaussians never drawn (others need opacity >= 1/255). Differentiable w.r.t. means2d,
    conics, opacities and features. ``kernel``: "auto" (compiled on the CPU for C = 4, colour and depth, as
    render() composites; else the torch walk), "torch" or "compiled"; the same image up to round-off.
    """
    c = features.shape[1]
    compiled = pick_kernel(kernel, means2d) == "compiled"
    if compiled and kernel == "auto" and c != 4:  # the compiled kernels composite colour and depth only
        compiled = False
    order = _drawn_in_depth_order(depths, extents, compiled)
    sel = (x.detach().index_select(0, order) for x in (means2d, conics, opacities, extents))
    bins = bin_tiles(*sel, width, height, compiled)
    if compiled:  # its records are copied out in depth order (a tile's list then reads them in order)
        out = _CompositeCompiled.apply(means2d, conics, opacities, features, order, bins, width, height)
    else:
        # Pairs index the caller's rows directly: no depth-sorted copies of the inputs (nor their
        # scatter-backward) are needed, only of the two detached columns binning reads.
        bins.gauss = order.index_select(0, bins.gauss)
        out = _Composite.apply(means2d, conics, opacities, features, bins, width, height)
    return out[..., :c], out[..., c]


@dataclass(frozen=True)
class WalkCounts:
    """The work of one compiled forward composite (bench/render.md reports these per pixel)."""

    pixels: int  # width * height
    pairs: int  # (tile, Gaussian) pairs in the tile lists
    walked: int  # pairs walked before their tile's pixels had all stopped
    visits: int  # pixels those pairs evaluated (their alpha >= 1/255 ellipse's, row by row)


def walk_counts(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    features: torch.Tensor,
    depths: torch.Tensor,
    extents: torch.Tensor,
    width: int,
    height: int,
    exact: bool = True,
    whole_tiles: bool = False,
) -> WalkCounts:
    """Count what composite()'s compiled forward does for these inputs (CPU tensors, no gradients).
    ``exact=False``: with box tile lists; ``whole_tiles``: edge tiles walk their pixels beyond the image too
    (the variants bench/render.md's work columns compare)."""
    from gspc.render import composite_cpu as kern

    with torch.no_grad():
        order = _drawn_in_depth_order(depths, extents, True)
        sel = (x.index_select(0, order) for x in (means2d, conics, opacities, extents))
        bins = bin_tiles(*sel, width, height, True, exact)
        records = _records(means2d, conics, opacities, features, order)
    size = (bins.tiles_x * TILE, bins.tiles_y * TILE) if whole_tiles else (width, height)
    image = np.zeros((size[1], size[0], kern.FEATURES))
    stats = kern.composite_forward(records, _lists(bins), bins.tiles_x, size, image, 1, counting=True)
    walked, visits = (int(x) for x in stats.sum(0))
    return WalkCounts(width * height, len(bins.gauss), walked, visits)


def _drawn_in_depth_order(depths: torch.Tensor, extents: torch.Tensor, compiled: bool) -> torch.Tensor:
    """Rows of the Gaussians drawn (extents >= 0), by increasing depth, ties in row order."""
    drawn = torch.nonzero(extents.detach()[:, 0] >= 0).squeeze(1)
    key = depths.detach().index_select(0, drawn)
    if compiled:
        from gspc.render.composite_cpu import depth_order

        return drawn.index_select(0, torch.from_numpy(depth_order(key.numpy(), torch.get_num_threads())))
    return drawn.index_select(0, torch.sort(key, stable=True).indices)


def _records(means2d, conics, opacities, features, order: torch.Tensor) -> np.ndarray:
    """The compiled kernels' records (composite_cpu.py pack) of rows ``order``, in that order."""
    from gspc.render.composite_cpu import FEATURES, pack

    if features.shape[1] != FEATURES - 1:
        raise ValueError(f"the compiled compositor takes {FEATURES - 1} features (colour, depth)")
    arrays = (x.detach().contiguous().numpy() for x in (means2d, conics, opacities, features))
    return pack(order.numpy(), *arrays, torch.get_num_threads())


def bin_tiles(
    means2d: torch.Tensor,
    conics: torch.Tensor,
    opacities: torch.Tensor,
    extents: torch.Tensor,
    width: int,
    height: int,
    compiled: bool = False,
    exact: bool = True,
) -> TileBins:
    """List every Gaussian in each tile whose pixel centres its alpha >= 1/255 ellipse, q <= 2 ln(255 o),
    reaches (``exact``; else every tile its box of half-sizes ``extents`` reaches), keeping input order.

    ``compiled``: by gspc/render/composite_cpu.py's counting sort, CPU only; the same lists (the per-row
    numbers are computed in the same float64 operations, in the same order). The exact test matters for
    thin rotated Gaussians, whose box holds many tiles their ellipse never reaches (bench/render.md).
    """
    tiles_x, tiles_y = -(-width // TILE), -(-height // TILE)
    dev = means2d.device
    # Tile i holds pixel centres i*TILE + 0.5 ... i*TILE + TILE - 0.5.
    lo = torch.ceil((means2d - extents - (TILE - 0.5)) / TILE)
    hi = torch.floor((means2d + extents - 0.5) / TILE)
    lo = torch.maximum(lo, torch.zeros_like(lo)).long()
    hi = torch.minimum(hi, torch.tensor([tiles_x - 1, tiles_y - 1], device=dev, dtype=hi.dtype)).long()
    # The lists hold at most the boxes' tiles: refused before anything of that size is allocated.
    boxes = int((hi - lo + 1).clamp_min(0).prod(1).sum())
    if boxes > MAX_VIEW_PAIRS:
        raise InputError(
            f"rendering a {width}x{height} view asks for up to {boxes:,} Gaussian-tile pairs; no render may "
            f"ask for more than {MAX_VIEW_PAIRS:,} (gspc/limits.py): lower the view's size"
        )
    # thr = 2 ln(255 o) with the compositor's relative margin (composite_cpu.py walks that ellipse).
    thr = (2.0 * torch.log(opacities.to(torch.float64) / ALPHA_MIN)).clamp_min(0.0)
    thr = thr * (1.0 + THRESHOLD_REL_MARGIN) + THRESHOLD_REL_MARGIN
    means2d, conics = means2d.to(torch.float64), conics.to(torch.float64)
    if compiled:
        from gspc.render.composite_cpu import bin_ellipses

        args = (x.contiguous().numpy() for x in (lo, hi, means2d, conics, thr))
        lists = bin_ellipses(*args, exact, tiles_x, tiles_x * tiles_y, torch.get_num_threads())
        return TileBins(*(torch.from_numpy(x) for x in lists), tiles_x, tiles_y)
    # One entry per (Gaussian, tile row of its box), then per tile of that row the ellipse reaches.
    rows_n = (hi[:, 1] - lo[:, 1] + 1).clamp_min(0) * (hi[:, 0] >= lo[:, 0])
    gauss_row = torch.repeat_interleave(torch.arange(len(rows_n), device=dev), rows_n)
    first = (torch.cumsum(rows_n, 0) - rows_n).index_select(0, gauss_row)
    ty = lo[:, 1].index_select(0, gauss_row) + torch.arange(len(gauss_row), device=dev) - first
    c0, c1 = lo[:, 0].index_select(0, gauss_row), hi[:, 0].index_select(0, gauss_row)
    if exact:
        per_row = torch.cat([means2d, conics, thr[:, None]], 1).index_select(0, gauss_row)
        c0, c1 = _tile_columns(ty, per_row, c0, c1)
    n = (c1 - c0 + 1).clamp_min(0)
    pair_row = torch.repeat_interleave(torch.arange(len(n), device=dev), n)
    k = torch.arange(len(pair_row), device=dev) - (torch.cumsum(n, 0) - n).index_select(0, pair_row)
    tile = ty.index_select(0, pair_row) * tiles_x + c0.index_select(0, pair_row) + k
    gauss = gauss_row.index_select(0, pair_row)
    # A stable sort groups pairs by tile and keeps the depth order inside each tile.
    tile, perm = torch.sort(tile.int(), stable=True)
    count = torch.bincount(tile.long(), minlength=tiles_x * tiles_y)
    return TileBins(gauss.index_select(0, perm), torch.cumsum(count, 0) - count, count, tiles_x, tiles_y)


def _tile_columns(ty: torch.Tensor, g: torch.Tensor, lo_x: torch.Tensor, hi_x: torch.Tensor):
    """composite_cpu.py's ellipse_terms and tile_columns for many (tile row, Gaussian) entries at once, in
    the same float64 operations and order (the lists must be equal); g: mean x, y, conic a, b, c, thr."""
    mx, my, a, b, c, thr = g.unbind(1)
    det = a * c - b * b
    hx = torch.sqrt(thr * c / det) * (1.0 + EXTENT_REL_MARGIN) + EXTENT_ABS_MARGIN
    hy = torch.sqrt(thr * a / det) * (1.0 + EXTENT_REL_MARGIN) + EXTENT_ABS_MARGIN
    ath, dyr = a * thr, -b * torch.sqrt(thr / (c * det))
    ya = torch.maximum(ty * TILE + 0.5 - my, -hy)
    yb = torch.minimum(ty * TILE + (TILE - 0.5) - my, hy)
    d = torch.minimum(torch.maximum(dyr, ya), yb)
    chord = (torch.sqrt((ath - det * d * d).clamp_min(0.0)) - b * d) / a + EXTENT_ABS_MARGIN
    right = torch.where(d == dyr, hx, chord)
    d = torch.minimum(torch.maximum(-dyr, ya), yb)
    chord = (-torch.sqrt((ath - det * d * d).clamp_min(0.0)) - b * d) / a - EXTENT_ABS_MARGIN
    left = torch.where(d == -dyr, -hx, chord)
    lo = torch.ceil((mx + left - (TILE - 0.5)) / TILE).long()
    hi = torch.floor((mx + right - 0.5) / TILE).long()
    return torch.maximum(lo, lo_x), torch.where(ya > yb, lo_x - 1, torch.minimum(hi, hi_x))


def _pixel_basis(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(6, 64) monomials [1, x, y, x^2, xy, y^2] of pixel centres relative to the tile centre."""
    r = torch.arange(TILE, dtype=dtype, device=device) + 0.5 - TILE / 2
    y, x = torch.meshgrid(r, r, indexing="ij")
    x, y = x.reshape(-1), y.reshape(-1)
    return torch.stack([torch.ones_like(x), x, y, x * x, x * y, y * y])


def _pair_params(means2d, conics, opacities, bins: TileBins) -> torch.Tensor:
    """(6, P): u, v (centre relative to the pair's tile centre), conic a, b, c and log opacity."""
    packed = torch.cat([means2d, conics, torch.log(opacities)[:, None]], 1).T.contiguous()
    # Gathering columns of the (6, M) transpose is several times faster than rows of (M, 6) + a transpose.
    packed = packed.index_select(1, bins.gauss)
    # Tile column and row by float division: exact while tiles_x * tiles_y < 2^24 (the quotient of two
    # integers cannot round across an integer), and far cheaper than integer % and //.
    tile = bins.tile.to(packed.dtype)
    ty = torch.floor(tile / bins.tiles_x)
    packed[0] -= (tile - ty * bins.tiles_x) * TILE + TILE / 2
    packed[1] -= ty * TILE + TILE / 2
    return packed


def _pair_coefficients(params: torch.Tensor) -> torch.Tensor:
    """(P + 1, 6) base-2 exponent coefficients per pair; the extra last row is padding (alpha 0)."""
    u, v, a, b, c, log_o = params
    coef = torch.empty(params.shape[1] + 1, 6, dtype=params.dtype, device=params.device)
    au_bv, bu_cv = a * u + b * v, b * u + c * v
    body = coef[:-1]
    torch.mul(log_o - 0.5 * (u * au_bv + v * bu_cv), LOG2_E, out=body[:, 0])
    torch.mul(au_bv, LOG2_E, out=body[:, 1])
    torch.mul(bu_cv, LOG2_E, out=body[:, 2])
    torch.mul(a, -0.5 * LOG2_E, out=body[:, 3])
    torch.mul(b, -LOG2_E, out=body[:, 4])
    torch.mul(c, -0.5 * LOG2_E, out=body[:, 5])
    coef[-1] = 0.0
    coef[-1, 0] = DEAD_POWER
    return coef


class _Composite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, bins: TileBins, width: int, height: int):
        params = _pair_params(means2d, conics, opacities, bins)
        coef, cap = _pair_coefficients(params), _may_cap(params)
        feat = _pair_features(features, bins)
        out = _walk(coef, feat, cap, bins, None)  # (tiles, C + 1, 64)
        if any(ctx.needs_input_grad[:4]):
            # Kept for the backward walk rather than recomputed: the backward needs them at the same
            # time as its own walk arrays, so the peak memory hardly moves, and recomputing them costs time
            # (bench/render.md, "Moved from code comments").
            ctx.save_for_backward(opacities, features, out)
            ctx.pairs = (params, coef, feat, cap)
            ctx.bins = bins
        return _tiles_to_image(out, bins, width, height)

    @staticmethod
    def backward(ctx, grad_out):
        opacities, features, out = ctx.saved_tensors
        params, coef, feat, cap = ctx.pairs
        bins = ctx.bins
        grad_pix = _image_to_tiles(grad_out.contiguous(), bins)
        d_coef, d_feat = _walk(coef, feat, cap, bins, (grad_pix, out))
        grads = _chain_to_gaussians(d_coef, d_feat, params, opacities, features, bins)
        return (*grads, None, None, None)


class _CompositeCompiled(torch.autograd.Function):
    """The compiled CPU kernels (gspc/render/composite_cpu.py) on the same tile lists, whose entries here
    index the depth-sorted rows ``order``."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, order, bins: TileBins, width: int, height: int):
        from gspc.render import composite_cpu as kern

        records = _records(means2d, conics, opacities, features, order)
        image = np.zeros((height, width, kern.FEATURES))
        size = (width, height)
        kern.composite_forward(records, _lists(bins), bins.tiles_x, size, image, torch.get_num_threads())
        if any(ctx.needs_input_grad[:4]):
            ctx.saved = (records, image, order, bins, len(opacities), size)
        return torch.from_numpy(image).to(means2d.dtype)

    @staticmethod
    def backward(ctx, grad_out):
        from gspc.render import composite_cpu as kern

        records, image, order, bins, num, size = ctx.saved
        grad_image = grad_out.detach().to(torch.float64).contiguous().numpy()
        lists, threads = _lists(bins), torch.get_num_threads()
        grads = kern.composite_backward(
            records, lists, order.numpy(), num, bins.tiles_x, size, grad_image, image, threads
        )
        g = torch.from_numpy(grads).to(grad_out.dtype)
        nf = grads.shape[1] - kern.GRADS - 1  # the last column is the alpha channel's
        return g[:, :2], g[:, 2:5], g[:, 5], g[:, kern.GRADS : kern.GRADS + nf], None, None, None, None


def _lists(bins: TileBins) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tile lists as the compiled kernels read them (gauss, start, count; views, no copies)."""
    return bins.gauss.numpy(), bins.start.numpy(), bins.count.numpy()


def _pair_features(features: torch.Tensor, bins: TileBins) -> torch.Tensor:
    """(P + 1, C + 1) features per pair plus a ones channel (its composite is the alpha image);
    the extra last row (padding) is zero."""
    f = torch.cat([features, torch.ones_like(features[:, :1])], 1)
    out = f.new_zeros(len(bins.gauss) + 1, f.shape[1])
    torch.index_select(f, 0, bins.gauss, out=out[:-1])
    return out


class _Rules:
    """Per-dtype constants of the compositing rules, as used by the in-place elementwise ops."""

    def __init__(self, dtype: torch.dtype, device: torch.device):
        def below(x: float) -> float:  # largest value < x in dtype: threshold() keeps v > t, we need v >= x
            t = torch.tensor(x, dtype=dtype)
            return float(torch.nextafter(t, torch.zeros_like(t)))

        self.alpha_min = below(ALPHA_MIN)
        self.t_min = below(T_MIN)
        self.one = torch.ones((), dtype=dtype, device=device)
        self.pix = _pixel_basis(dtype, device)


def _alphas(kc: torch.Tensor, r: _Rules, cap: bool) -> torch.Tensor:
    """(b, L, 64) alpha of each listed Gaussian at each tile pixel: capped at 0.99 (only needed when
    ``cap``: some Gaussian listed is nearly opaque), 0 below 1/255."""
    b, n = kc.shape[:2]
    alpha = torch.mm(kc.reshape(b * n, 6), r.pix).reshape(b, n, PIXELS).exp2_()
    if cap:
        alpha.clamp_(max=ALPHA_MAX)
    return F.threshold_(alpha, r.alpha_min, 0.0)


def _may_cap(params: torch.Tensor) -> torch.Tensor:
    """(P + 1,) True for pairs whose alpha may reach the 0.99 cap; the padding row is False.

    alpha = o exp(-q / 2) with q >= 0 up to round-off at the centre, so below o = 0.989 it never does;
    steps whose Gaussians are all below skip the cap and its gradient gate (most steps of real scenes).
    """
    out = torch.zeros(params.shape[1] + 1, dtype=torch.bool, device=params.device)
    torch.gt(params[5], math.log(ALPHA_MAX * 0.999), out=out[:-1])
    return out


def _transmittance(alpha: torch.Tensor, t_in: torch.Tensor, r: _Rules, loop_from: int) -> torch.Tensor:
    """(b, L + 1, 64) transmittance before each Gaussian and after the last (serial product order)."""
    b, n, _ = alpha.shape
    trans = torch.empty(b, n + 1, PIXELS, dtype=alpha.dtype, device=alpha.device)
    trans[:, 0] = t_in
    torch.sub(r.one, alpha, out=trans[:, 1:])
    if trans.numel() < loop_from:
        return trans.cumprod_(1)
    for i in range(1, n + 1):  # the serial products of cumprod_, faster on large CPU steps (CPU_WALK)
        trans[:, i].mul_(trans[:, i - 1])
    return trans


def _minus_remaining(wg: torch.Tensor, before: torch.Tensor, loop_from: int) -> torch.Tensor:
    """(b, L, 64) -R_i = sum_{j <= i} wg_j - before, R_i being what the Gaussians after i still add."""
    out = wg.clone()
    out[:, 0].sub_(before)
    if wg.numel() < loop_from:
        return out.cumsum_(1)
    for i in range(1, wg.shape[1]):  # the serial sums of cumsum_, faster on large CPU steps (CPU_WALK)
        out[:, i].add_(out[:, i - 1])
    return out


def _included(t_after: torch.Tensor, r: _Rules) -> torch.Tensor | None:
    """1 where the pixel has not stopped (3DGS: stop before T would drop below 1e-4), else 0;
    None when no pixel stops in this block. t_after only decreases, so this is the stop rule."""
    if float(t_after[:, -1].min()) >= T_MIN:
        return None
    return F.threshold(t_after, r.t_min, 0.0).sign_()


def _walk(coef: torch.Tensor, feat: torch.Tensor, may_cap: torch.Tensor, bins: TileBins, grad):
    """Forward (grad None): composited (tiles, C + 1, 64). Backward: per-pair d coef, d feat.

    Pixel-side arrays are channel-major (tiles, C + 1, 64): bmm is several times faster that way.
    """
    n_pairs = len(coef) - 1
    dev, dt = coef.device, coef.dtype
    r = _Rules(dt, dev)
    order = torch.sort(bins.count, descending=True).indices
    order = order[: int((bins.count > 0).sum())]
    sizes = walk_sizes(dev)
    chunk = max(1, sizes.step_budget // (PIXELS * BLOCK))
    if grad is None:
        out = torch.zeros(len(bins.count), feat.shape[1], PIXELS, dtype=dt, device=dev)
    else:
        grad_pix, out_saved = grad
        # R = sum over Gaussians not yet walked of w_j g_j; before the walk it is grad . output.
        remaining_all = (grad_pix * out_saved).sum(1)
        d_coef, d_feat = torch.zeros_like(coef), torch.zeros_like(feat)
    offs = torch.arange(BLOCK, device=dev)
    for lo in range(0, len(order), chunk):
        tiles = order[lo : lo + chunk]
        start, count = bins.start.index_select(0, tiles), bins.count.index_select(0, tiles)
        trans_run = torch.ones(len(tiles), PIXELS, dtype=dt, device=dev)
        if grad is None:
            acc = torch.zeros(len(tiles), feat.shape[1], PIXELS, dtype=dt, device=dev)
        else:
            gpix, remaining = grad_pix.index_select(0, tiles), remaining_all.index_select(0, tiles)
        live = torch.arange(len(tiles), device=dev)
        k = 0
        while len(live):
            b = len(live)
            cnt = count.index_select(0, live)
            pos = torch.where(
                offs < (cnt - k)[:, None], (start.index_select(0, live) + k)[:, None] + offs, n_pairs
            )
            pos = pos.reshape(-1)  # (b * L,) pair rows, padding -> the zero-alpha row
            cap = bool(may_cap.index_select(0, pos).any())
            alpha = _alphas(coef.index_select(0, pos).reshape(b, -1, 6), r, cap)  # (b, L, 64)
            trans = _transmittance(alpha, trans_run.index_select(0, live), r, sizes.scan_loop_from)
            t_before, t_end = trans[:, :-1], trans[:, -1].clone()  # (the backward reuses trans)
            keep = _included(trans[:, 1:], r)
            w = alpha * t_before
            if keep is not None:
                w.mul_(keep)
            fc = feat.index_select(0, pos).reshape(b, -1, feat.shape[1])  # (b, L, C + 1)
            if grad is None:
                acc.index_add_(0, live, torch.bmm(fc.transpose(1, 2), w))
            else:
                gp = gpix.index_select(0, live)  # (b, C + 1, 64)
                d_feat.index_copy_(
                    0, pos, torch.bmm(gp, w.transpose(1, 2)).transpose(1, 2).reshape(len(pos), -1)
                )
                # d power_i = alpha_i d_alpha_i where alpha_i is below the 0.99 cap (0 above it and at
                # stopped pixels), with d_alpha_i = g_i T_i - R_i / (1 - alpha_i), R_i = sum_{j > i} w_j g_j
                # and g = dL/dw. Written as w_i g_i - R_i alpha_i / (1 - alpha_i), it reuses w g (the
                # terms of R) and needs no separate gate where nothing reaches the cap.
                wg = torch.bmm(fc, gp).mul_(w)
                before = remaining.index_select(0, live)
                neg_after = _minus_remaining(wg, before, sizes.scan_loop_from)  # -R_i
                remaining.index_copy_(0, live, neg_after[:, -1].neg())
                ratio = torch.sub(r.one, alpha, out=trans[:, 1:])
                ratio = torch.div(alpha, ratio, out=ratio)
                if keep is not None:  # (w g is already 0 at stopped pixels)
                    ratio.mul_(keep)
                d_power = wg.addcmul_(ratio, neg_after)
                if cap:  # 1 where 0 < alpha < 0.99, else 0 (alpha is not needed after this)
                    d_power.mul_(F.threshold_(alpha.neg_(), -ALPHA_MAX, 0.0).sign_().neg_())
                d_coef.index_copy_(0, pos, torch.mm(d_power.reshape(-1, PIXELS), r.pix.T))
            trans_run.index_copy_(0, live, t_end)
            k += BLOCK
            live = live[(cnt > k) & (t_end >= T_MIN).any(1)]
        if grad is None:
            out.index_copy_(0, tiles, acc)
    if grad is None:
        return out
    return d_coef[:n_pairs], d_feat[:n_pairs]


def _chain_to_gaussians(d_coef, d_feat, params, opacities, features, bins: TileBins):
    """Gradients of means2d, conics, opacities, features from per-pair exponent/feature gradients."""
    u, v, a, b, c, _ = params
    g0, g1, g2, g3, g4, g5 = d_coef.T
    nf = features.shape[1]
    au_bv, bu_cv = a * u + b * v, b * u + c * v
    # Written row by row into one (6 + C, P) buffer (fused multiply-adds, no stacked temporaries).
    per_pair = params.new_empty(6 + nf, len(g0))
    torch.mul(a, g1, out=per_pair[0]).addcmul_(b, g2).addcmul_(au_bv, g0, value=-1)  # d u
    torch.mul(b, g1, out=per_pair[1]).addcmul_(c, g2).addcmul_(bu_cv, g0, value=-1)  # d v
    uu_g0, uv_g0, vv_g0 = u * g0, v * g0, v * g0
    uu_g0.mul_(u)
    uv_g0.mul_(u)
    vv_g0.mul_(v)
    torch.mul(u, g1, out=per_pair[2]).sub_(uu_g0.add_(g3), alpha=0.5)  # d a
    torch.mul(v, g1, out=per_pair[3]).addcmul_(u, g2).sub_(uv_g0).sub_(g4)  # d b
    torch.mul(v, g2, out=per_pair[4]).sub_(vv_g0.add_(g5), alpha=0.5)  # d c
    per_pair[5] = g0  # d log o
    per_pair[6:] = d_feat[:, :nf].T
    # One scatter of rows of the (6 + C, P) layout: index_add_ along dim 1 is several times faster on
    # CPU than along dim 0 of (P, 6 + C) when the index is in tile order (random for Gaussians).
    per_gauss = per_pair.new_zeros(len(per_pair), len(opacities)).index_add_(1, bins.gauss, per_pair)
    return per_gauss[:2].T, per_gauss[2:5].T, per_gauss[5] / opacities, per_gauss[6:].T


def _tiles_to_image(t: torch.Tensor, bins: TileBins, width: int, height: int) -> torch.Tensor:
    """(tiles, C, 64) -> (H, W, C)."""
    c = t.shape[1]
    img = t.reshape(bins.tiles_y, bins.tiles_x, c, TILE, TILE).permute(0, 3, 1, 4, 2)
    return img.reshape(bins.tiles_y * TILE, bins.tiles_x * TILE, c)[:height, :width]


def _image_to_tiles(img: torch.Tensor, bins: TileBins) -> torch.Tensor:
    """(H, W, C) -> (tiles, C, 64), zero beyond the image."""
    h, w, c = img.shape
    pad = img.new_zeros(bins.tiles_y * TILE, bins.tiles_x * TILE, c)
    pad[:h, :w] = img
    t = pad.reshape(bins.tiles_y, TILE, bins.tiles_x, TILE, c).permute(0, 2, 4, 1, 3)
    return t.reshape(bins.tiles_y * bins.tiles_x, c, PIXELS)
