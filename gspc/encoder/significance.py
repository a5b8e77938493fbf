"""What each Gaussian does to the views: the encoder's measures for spending precision where it shows.

All accumulated over the encoder's cameras, from ONE forward and backward render per view and zoom
(gspc/encoder/precision_plan.py's :class:`Significance` holds them):

- ``weight``: the blending weight a Gaussian takes over a view, sum_pixels alpha_i T_i (its footprint times
  opacity times the transmittance in front of it), as a fraction of the view's pixels. It is the gradient of
  the summed image with respect to the Gaussian's projected colour, so the backward gives it exactly,
  occlusion included.
- ``gradient``: per attribute group, sum_views |d sum(image) / d attribute| summed over the group's
  components: how far a change of that group moves the picture (C3DGS's sensitivity).
- ``sh_band_change``: per SH band, sum_views |sum over the band's coefficients of gradient x coefficient|:
  the first-order change of the view if the band were dropped.

At several zooms (the cameras' own resolution and twice it, say), each measure is taken per zoom, per pixel
of the zoom's views, and the largest kept: a Gaussian finer than a pixel of the cameras shows its scale and
rotation only when the picture is shown larger (bench/precision.md).

The encoder (:func:`encoder_significance`) measures every one of its cameras (up to WIDE_VIEWS, fewer for
scenes past WIDE_WORK) at their own size and a sample of them at the larger zooms: a sample at 1x can see a
sky Gaussian behind the object where another camera sees it beside it, and removal then takes it
(bench/precision.md, "Every camera measured at its own size"). A Gaussian the cameras measured show much
less of than all of them do (where not every camera is measured) is measured again, alone, at every camera:
removal and coarse classes chosen from such glimpses cost a sky of large Gaussians most of its quality
(bench/precision.md, "Choosing the presets' parameters").

None is ever written to a file: the precision classes chosen from them are what a decoder reads, so a
decoder never recomputes these. tools/bench_significance.py measures which of them predicts where the
attribute codec's error shows (bench/significance.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.encoder.occlusion import Occlusion
from gspc.encoder.precision_plan import Significance
from gspc.progress import Progress
from gspc.render.project import project
from gspc.render.rasterize import composite
from gspc.scene import ATTRIBUTE_NAMES, GaussianScene
from gspc.visibility import footprints

__all__ = [
    "Significance",
    "ViewMeasures",
    "encoder_significance",
    "evenly_spaced",
    "evenly_spaced_indices",
    "measure_view",
    "significance",
    "wide_cameras",
]

# The encoder's sample: 20 views rank Gaussians as well as all 161 of the bird capture
# (bench/significance.md); they are rendered forward and backward at twice the cameras' size too: precision
# measured at 1x alone leaves the statues worse at 2x for the same bytes (bench/precision.md, "After version
# 4's first run").
SIGNIFICANCE_VIEWS = 20
SIGNIFICANCE_ZOOMS = (1.0, 2.0)
# At 1x every camera is measured, up to this many (evenly spaced): 20 rank Gaussians as well as all, but
# removal takes what only unsampled cameras see whole; measured at every camera, each scene codes the same
# PSNR in as many bytes or fewer and the shells come far closer (bench/precision.md, "Every camera measured
# at its own size"). 64 holds the 60 views the encoder synthesises.
WIDE_VIEWS = 64
# ... and at most this many Gaussian-views in that pass (64 views of 250k Gaussians), never fewer views than
# the sample: a view's measure costs in proportion to the Gaussians it holds, and every camera of a
# million-Gaussian scene would add minutes to its encode (bench/precision.md, "Every camera measured at its
# own size"; bench/speed.md, "The significance measure's per-view sums compiled").
WIDE_WORK = 64 * 250_000
# Where not every camera is measured at 1x, a Gaussian the measured ones show less than 1 / UNDER_SAMPLED of
# what every camera shows on average (by gspc/visibility.py's footprints) is measured again at every camera.
UNDER_SAMPLED = 1.5
# ... at most this many Gaussian-views (the sample's own cost at 1x is views x N) and this many cameras (each
# render has a cost of its own, whatever it holds): beyond either, at evenly spaced cameras.
SURVEY_WORK_PER_GAUSSIAN = SIGNIFICANCE_VIEWS
SURVEY_MAX_VIEWS = 256


@dataclass(frozen=True)
class ViewMeasures:
    """One view's share of a :class:`Significance`, each per Gaussian."""

    weight: torch.Tensor  # (N,) sum_pixels alpha T over the view's pixels, as a fraction of them
    gradient: dict[
        str, torch.Tensor
    ]  # attribute -> (N,) |d sum(image) / d attribute|, summed over components
    sh_band_change: torch.Tensor  # (N, D)


def measure_view(
    scene: GaussianScene,
    camera: Camera,
    background: Sequence[float],
    occlusion: Occlusion | None = None,
    zoom: float = 1.0,
) -> ViewMeasures:
    """Every measure of one view (``camera`` at ``zoom`` times its size), from one render and its backward;
    with ``occlusion`` (a tile's), each Gaussian's measures scaled by the share of it in front of the other
    tiles (gspc/encoder/occlusion.py)."""
    if zoom != 1.0:
        camera, base = camera.scaled(zoom), camera
    else:
        base = camera
    # Leaves sharing the scene's storage (autograd.grad below writes no .grad, and nothing writes them).
    leaves = {k: v.detach().requires_grad_(True) for k, v in scene.tensors().items()}
    p = project(
        leaves["means"],
        leaves["quats"],
        leaves["log_scales"],
        leaves["opacities"],
        leaves["sh_dc"],
        leaves["sh_rest"],
        camera,
        scene.sh_degree,
    )
    # Colour and depth composited together, as render() does: the compiled compositor takes that layout.
    features = torch.cat([p.colors, p.depths[:, None]], 1)
    acc, alpha = composite(
        p.means2d, p.conics, p.opacities, features, p.depths, p.extents, camera.width, camera.height
    )
    bg = torch.tensor(background, dtype=acc.dtype)
    image = acc[..., :3] + (1 - alpha)[..., None] * bg
    grads = torch.autograd.grad(image.sum(), [*leaves.values(), p.colors], allow_unused=True)
    from gspc.encoder import significance_cpu as kern  # numba: imported where a measure runs

    n = scene.num_gaussians
    # The sums read only the drawn Gaussians' rows: the rest are zero, and a close-up view of a large scene
    # draws few of them (bench/speed.md, "Only the drawn Gaussians' rows").
    drawn = p.index[p.drawn].numpy()
    zero = torch.zeros(n, dtype=torch.float64)
    gradient = {
        k: zero
        if g is None
        else torch.from_numpy(kern.abs_row_sums(g.reshape(n, -1).contiguous().numpy(), drawn))
        for k, g in zip(leaves, grads[:-1])
    }
    # d sum(image) / d colour_i is sum_pixels alpha_i T_i in each channel; the projection may keep only the
    # Gaussians in front of the camera (p.index): the rest weigh 0.
    weight = torch.zeros(n, dtype=torch.float64)
    weight.index_copy_(0, p.index, grads[-1][:, 0].double())
    weight /= camera.width * camera.height
    d = scene.sh_degree
    change = torch.zeros(n, d, dtype=torch.float64)
    g_rest = grads[ATTRIBUTE_NAMES.index("sh_rest")]
    if d > 0 and g_rest is not None:
        coef = scene.sh_rest.detach().contiguous().numpy()
        change = torch.from_numpy(kern.band_changes(g_rest.contiguous().numpy(), coef, d, drawn))
    shares = None if occlusion is None else occlusion.shares(p, base, zoom)
    if shares is not None:
        front = torch.ones(n, dtype=torch.float64)
        front[p.index] = torch.from_numpy(shares)
        weight *= front
        gradient = {k: g * front for k, g in gradient.items()}
        change = change * front[:, None]
    return ViewMeasures(weight, gradient, change)


def evenly_spaced(cameras: Sequence[Camera], count: int) -> list[Camera]:
    """``count`` cameras spread evenly over the list (all of them when there are fewer): 20 rank Gaussians as
    well as 161 on the bird capture (bench/significance.md)."""
    return [cameras[i] for i in evenly_spaced_indices(len(cameras), count)]


def evenly_spaced_indices(n: int, count: int) -> list[int]:
    """The indices :func:`evenly_spaced` picks of ``n`` cameras."""
    if n <= count:
        return list(range(n))
    return [int(i) for i in np.linspace(0, n - 1, count).round().astype(int)]


def significance(
    scene: GaussianScene,
    cameras: Sequence[Camera],
    background: Sequence[float] = (0.0, 0.0, 0.0),
    progress: Progress | None = None,
    zooms: Sequence[float] = (1.0,),
    occlusion: Occlusion | None = None,
) -> Significance:
    """Every measure, accumulated over ``cameras`` at each of ``zooms`` (a camera's size multiplier); of
    several zooms, per Gaussian the largest, the sums over a zoom's pixels divided by zoom^2. ``occlusion``:
    a tile's, what the other tiles hide (gspc/encoder/occlusion.py)."""
    n, d = scene.num_gaussians, scene.sh_degree
    weight = torch.zeros(n, dtype=torch.float64)
    gradient = {k: torch.zeros(n, dtype=torch.float64) for k in ATTRIBUTE_NAMES}
    change = torch.zeros(n, d, dtype=torch.float64)
    total = len(cameras) * len(zooms)
    for z, zoom in enumerate(zooms):
        w = torch.zeros(n, dtype=torch.float64)
        g = {k: torch.zeros(n, dtype=torch.float64) for k in ATTRIBUTE_NAMES}
        c = torch.zeros(n, d, dtype=torch.float64)
        for i, cam in enumerate(cameras):
            if progress:
                progress("significance", z * len(cameras) + i, total)
            m = measure_view(scene, cam, background, occlusion, zoom)
            w += m.weight
            c += m.sh_band_change
            for k, v in m.gradient.items():
                g[k] += v
        per_pixel = 1.0 / zoom**2  # weight is already a fraction of the view's pixels
        weight = torch.maximum(weight, w)
        change = torch.maximum(change, c * per_pixel)
        for k in gradient:
            gradient[k] = torch.maximum(gradient[k], g[k] * per_pixel)
    if progress:
        progress("significance", total, total)
    return Significance(
        weight.numpy(), {k: v.numpy() for k, v in gradient.items()}, change.numpy(), len(cameras)
    )


def encoder_significance(
    scene: GaussianScene,
    cameras: Sequence[Camera],
    background: Sequence[float] = (0.0, 0.0, 0.0),
    progress: Progress | None = None,
    occlusion: Occlusion | None = None,
) -> Significance:
    """The encoder's measure: :func:`significance` at up to WIDE_VIEWS evenly spaced cameras at 1x (fewer
    past WIDE_WORK Gaussian-views, never fewer than SIGNIFICANCE_VIEWS) and at SIGNIFICANCE_VIEWS of them at
    the larger SIGNIFICANCE_ZOOMS (per Gaussian the largest, per view of the wider set), and the Gaussians
    those cameras under-show measured alone at every camera (in front of nothing of the scene's: what the
    rest hides of them is counted too, which errs towards precision). With a tile's ``occlusion``, of what
    the other tiles leave in view."""
    wide = wide_cameras(cameras, scene.num_gaussians)
    sample = evenly_spaced(wide, SIGNIFICANCE_VIEWS)
    zooms = [z for z in SIGNIFICANCE_ZOOMS if z != 1.0]
    total = len(wide) + len(sample) * len(zooms)
    sig = significance(scene, wide, background, _within(progress, 0, total), occlusion=occlusion)
    if zooms:
        within = _within(progress, len(wide), total)
        zoomed = significance(scene, sample, background, within, zooms, occlusion)
        sig = _raised(sig, np.arange(scene.num_gaussians), zoomed, len(wide) / len(sample))
    if len(wide) == len(cameras):
        return sig
    means, log_scales = scene.means.detach().cpu().numpy(), scene.log_scales.detach().cpu().numpy()
    shown = footprints(means, log_scales, wide)
    rows = np.flatnonzero(footprints(means, log_scales, list(cameras)) > UNDER_SAMPLED * shown)
    if rows.size == 0:
        return sig
    budget = max(1, SURVEY_WORK_PER_GAUSSIAN * scene.num_gaussians // rows.size)
    survey = evenly_spaced(cameras, min(budget, SURVEY_MAX_VIEWS))
    alone = significance(scene.subset(rows), survey, background, occlusion=occlusion)
    return _raised(sig, rows, alone, len(wide) / len(survey))


def wide_cameras(cameras: Sequence[Camera], num_gaussians: int) -> list[Camera]:
    """The cameras :func:`encoder_significance` measures at 1x for a scene of ``num_gaussians``: up to
    WIDE_VIEWS evenly spaced, fewer past WIDE_WORK Gaussian-views, never fewer than SIGNIFICANCE_VIEWS."""
    count = max(SIGNIFICANCE_VIEWS, min(WIDE_VIEWS, WIDE_WORK // max(1, int(num_gaussians))))
    return evenly_spaced(cameras, count)


def _within(progress: Progress | None, before: int, total: int) -> Progress | None:
    """``progress`` for a part of a stage: its steps counted after ``before`` of ``total``."""
    if progress is None:
        return None
    return lambda stage, done, _: progress(stage, before + done, total)


def _raised(sig: Significance, rows: np.ndarray, alone: Significance, per_view: float) -> Significance:
    """``sig`` with each measure of ``rows`` raised to ``alone``'s (summed over other views or at another
    zoom, scaled by ``per_view`` to ``sig``'s count of views) where that is larger."""

    def up(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        out = a.copy()
        out[rows] = np.maximum(a[rows], b * per_view)
        return out

    return Significance(
        up(sig.weight, alone.weight),
        {k: up(v, alone.gradient[k]) for k, v in sig.gradient.items()},
        up(sig.sh_band_change, alone.sh_band_change),
        sig.views,
    )
