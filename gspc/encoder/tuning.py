"""Tuning the coded values: each quantised attribute may take a neighbour of its nearest grid point where the
decoded scene renders closer (an encoder choice: the bitstream and the decoder are unchanged).

Quantisation codes every attribute as the grid point nearest the original, one value at a time. What the
views show is the sum of many Gaussians' rounding errors through the renderer, and the encoder holds the
original's renders: moving a value to the grid point beside its nearest one may cancel a neighbour's error
(as a video encoder picks its quantised coefficients by what they cost the picture, not one by one).
Tuning moves the values the codec quantises, each within ``reach`` cells of the original, so that the
decoded scene renders closer at the encoder's cameras:

- each iteration codes the moved values at the rate under the original's plan (the same parameters,
  visibility and measure, and the original's opacities and sizes: the same classes, removal and far set),
  renders the decoded scene at a share of the cameras, and moves the values by Adam along the gradient at
  the decoded ones (straight through the rounding), in units of each Gaussian's own cell, so that a step
  means the same to every class;
- the shares rotate, so the iterations together see every camera; a quarter of them per iteration gains
  about what all of them do, in much less time (bench/tuning.md, "A quarter of the views per iteration");
- the tuning stops at the first coding over the byte limit; the last coding within it is kept where it
  renders closer than the untuned one at the first share of cameras, else the untuned one.

Positions are left as coded: moving them would move the grid's bounds and the contraction's centre
(gspc/codec/positions.py), and with them every voxel. The encoder tunes the files the decoder takes as they
are, without side information (gspc/pipeline.py): where it refines against side information, refinement
moves the same values inside the same cells.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from gspc.adam import FusedAdam
from gspc.cameras import Camera
from gspc.codec.cells import quantisation_cells
from gspc.encoder.coding import EncodedAttributes, SharedGrid, encode_attributes
from gspc.encoder.occlusion import Occlusion
from gspc.encoder.params import CodecParams
from gspc.encoder.precision_plan import Significance
from gspc.encoder.significance import wide_cameras
from gspc.errors import ValueRangeError
from gspc.progress import Progress
from gspc.reconstruct import render_images
from gspc.render import render
from gspc.scene import GaussianScene

TUNED_ATTRIBUTES = ("log_scales", "quats", "opacities", "sh_dc", "sh_rest")
# Gaussian-views one iteration may render (forward and backward): the bird capture's 16 views of 100,000
# Gaussians. Larger scenes render fewer views per iteration; under MIN_VIEWS the tuning is skipped (past
# 400,000 Gaussians): each iteration also codes and decodes the whole scene, seconds at a million Gaussians
# (bench/precision.md, "Removal chosen per scene"), and a view or two per iteration is not what
# bench/tuning.md measures.
TUNE_WORK = 16 * 100_000
MIN_VIEWS = 4


@dataclass(frozen=True)
class TuningParams:
    """How the encoder tunes its coded values (nothing of it is in the file)."""

    iterations: int = 4  # the presets' (gspc/presets.py)
    # Adam's learning rate in cells: 0.02 and 0.03 tie on the statue massa, the bird gains most at 0.03, and
    # a larger step reaches the byte limit early (bench/tuning.md, "The step").
    step: float = 0.03
    reach: float = 1.0  # cells a value may move from the original
    share: int = 4  # each iteration renders every share-th of the cameras
    # The tuned coding may grow by this share of the untuned one's bytes (tuned values sit off the contexts'
    # predictions: bench/tuning.md, "Gain and cost by scene"); a byte target
    # (--target-size) bounds it instead.
    growth: float = 0.02
    # Every twice_every-th camera rendered at twice its width and height (0: none), so that the values are
    # tuned for a viewer that draws the scene larger than the cameras were (bench/precision.md, "Tuning at
    # twice the size").
    twice_every: int = 0


@dataclass(frozen=True)
class TuningReport:
    """What a tuning did, measured at the first share of its cameras (PSNR of the float renders)."""

    iterations: int  # run (a deadline may cut them)
    views: int  # cameras rendered per iteration
    before_db: float
    after_db: float
    before_bytes: int
    after_bytes: int
    kept: bool  # whether the tuned coding replaced the untuned one
    seconds: float

    def summary(self) -> str:
        if self.iterations == 0:
            return "none (no time left, or a scene past the tuning's work bound)"
        verdict = "kept" if self.kept else "not kept (no closer within the byte limit)"
        return (
            f"{self.iterations} iterations at {self.views} views each: {self.before_db:.2f} -> "
            f"{self.after_db:.2f} dB, {self.before_bytes:,} -> {self.after_bytes:,} B, {verdict}, "
            f"{self.seconds:.1f} s"
        )


@dataclass
class Tuned:
    encoded: EncodedAttributes  # the coding to send (the untuned one where tuning did not pay)
    report: TuningReport


def tune_coding(
    scene: GaussianScene,
    enc: EncodedAttributes,
    params: CodecParams,
    cameras: Sequence[Camera],
    background: Sequence[float],
    visible: np.ndarray | None = None,
    significance: Significance | None = None,
    tuning: TuningParams = TuningParams(),
    byte_limit: int | None = None,
    deadline: float | None = None,
    progress: Progress | None = None,
    grid: SharedGrid | None = None,
    occlusion: Occlusion | None = None,
) -> Tuned:
    """``enc`` (``scene`` coded with ``params.with_lambda(enc.lam)``, ``visible`` and ``significance``) with
    its values tuned at ``cameras`` (see the module). ``byte_limit``: the most bytes the tuned coding may
    take (default: the untuned one's plus ``tuning.growth``); no iteration starts after ``deadline`` (a
    ``time.perf_counter()`` value). The scene is read on the CPU, as the codec runs. A tile's ``occlusion``:
    only the pixels where some of it is in front of the other tiles count (gspc/encoder/occlusion.py)."""
    t0 = time.perf_counter()
    views = wide_cameras(cameras, scene.num_gaussians)
    affordable = TUNE_WORK // max(1, scene.num_gaussians)
    if affordable < MIN_VIEWS:
        return Tuned(enc, _report(0, 0, 0.0, 0.0, enc, enc, False, t0))
    per = max(1, min(len(views) // max(1, tuning.share), affordable))
    scene = scene.to("cpu")
    params = params.with_lambda(enc.lam)
    limit = byte_limit if byte_limit is not None else int(enc.num_bytes * (1.0 + tuning.growth))
    stride = max(1, len(views) // per)
    views = _zoomed(views, stride, tuning.twice_every)
    bg = tuple(float(x) for x in background)
    refs = render_images(scene, views, bg)
    if occlusion is not None:  # the pixels the other tiles hide are the same in both: no error there
        masks = occlusion.masks(scene, views)
        refs = [r if m is None else r * m for r, m in zip(refs, masks)]
    else:
        masks = [None] * len(views)
    first_share = _share(len(views), stride, 0)

    origin, width = _origin_and_width(scene, enc)
    z = {k: torch.zeros_like(origin[k], requires_grad=True) for k in TUNED_ATTRIBUTES}
    opt = FusedAdam([{"params": list(z.values()), "lr": tuning.step}])
    current, best, before = enc, enc, None
    done = 0
    if progress:
        progress("tune", 0, tuning.iterations)
    for it in range(tuning.iterations):
        if deadline is not None and time.perf_counter() >= deadline:
            break
        share = _share(len(views), stride, it)
        loss, grads = _loss_and_gradients(current, views, refs, masks, share, bg)
        if it == 0:
            before = loss
        opt.zero_grad()
        for k in TUNED_ATTRIBUTES:
            z[k].grad = _to_input_rows(grads[k], current, origin[k], k) * width[k]
        opt.step()
        with torch.no_grad():
            for v in z.values():
                v.clamp_(-tuning.reach, tuning.reach)
        try:
            moved = _moved(scene, origin, width, z)
            current = encode_attributes(moved, params, visible, significance, scene, grid)
        except ValueRangeError:  # a value at the edge of what the rate codes moved past it: stop there
            break
        done = it + 1
        if progress:
            progress("tune", done, tuning.iterations)
        if current.num_bytes > limit:
            # The bytes grow as the values leave their nearest grid points, and go on growing with more
            # iterations (bench/tuning.md, "Gain and cost by scene"): a later coding would not fit either.
            break
        best = current
    if before is None:
        return Tuned(enc, _report(done, len(first_share), 0.0, 0.0, enc, enc, False, t0))
    if best is enc:  # the first coding already passed the byte limit (or the rate's range)
        at = _db(before, views, first_share)
        return Tuned(enc, _report(done, len(first_share), at, at, enc, enc, False, t0))
    after = _loss(best, views, refs, masks, first_share, bg)
    before_db, after_db = _db(before, views, first_share), _db(after, views, first_share)
    kept = after < before
    chosen = best if kept else enc
    return Tuned(chosen, _report(done, len(first_share), before_db, after_db, enc, best, kept, t0))


def _zoomed(views: list[Camera], stride: int, every: int) -> list[Camera]:
    """``views`` with every ``every``-th of each share (the views ``stride`` apart, :func:`_share`) at twice
    its size, so that every iteration renders both sizes; all as given where ``every`` is 0."""
    return [v.scaled(2.0) if every and (i // stride) % every == 0 else v for i, v in enumerate(views)]


def _share(count: int, stride: int, it: int) -> list[int]:
    """The cameras iteration ``it`` renders: every ``stride``-th, starting at ``it`` modulo ``stride``."""
    return list(range(it % stride, count, stride)) if stride > 1 else list(range(count))


def _origin_and_width(
    scene: GaussianScene, enc: EncodedAttributes
) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """Per attribute, the original values (unit quaternions signed like the codec's: the largest component
    positive) and each value's cell width at ``enc``'s classes, for every input row (0 where not coded, or
    where the cell is open: a dropped SH band, an opacity at its end)."""
    origin = {k: getattr(scene, k).detach().float().clone() for k in TUNED_ATTRIBUTES}
    q = origin["quats"] / origin["quats"].norm(dim=1, keepdim=True).clamp_min(1e-12)
    big = q.abs().argmax(dim=1, keepdim=True)
    origin["quats"] = q * torch.where(q.gather(1, big) < 0, -1.0, 1.0)
    cells = quantisation_cells(enc.decoded, enc.section, enc.precision)
    rows = torch.from_numpy(enc.kept)
    width = {}
    for k in TUNED_ATTRIBUTES:
        lo, hi = cells[k]
        w = (hi - lo).float()
        w = torch.where(torch.isfinite(w), w, torch.zeros_like(w))
        if k == "quats":
            # The codec codes the three smaller components (a step each) and derives the largest, whose cell
            # is wider: one step for all four.
            w = w.min(dim=1, keepdim=True).values.expand(-1, 4)
        full = torch.zeros_like(origin[k])
        full[rows] = w
        width[k] = full
    return origin, width


def _moved(
    scene: GaussianScene,
    origin: dict[str, torch.Tensor],
    width: dict[str, torch.Tensor],
    z: dict[str, torch.Tensor],
) -> GaussianScene:
    """The scene with every tuned attribute at ``origin + width z``, its positions unchanged."""
    with torch.no_grad():
        values = {k: origin[k] + width[k] * z[k] for k in TUNED_ATTRIBUTES}
    return GaussianScene(means=scene.means, sh_degree=scene.sh_degree, extra=scene.extra, **values)


def _loss_and_gradients(
    enc: EncodedAttributes,
    views: Sequence[Camera],
    refs: list[torch.Tensor],
    masks: list[torch.Tensor | None],
    share: list[int],
    bg,
) -> tuple[float, dict[str, torch.Tensor]]:
    """The squared error of ``enc``'s decoded scene at the ``share`` of ``views`` (where ``masks`` count),
    and its gradient with respect to each tuned attribute of the decoded scene (decoded order)."""
    dec = enc.decoded
    leaves = {k: v.detach().clone().requires_grad_(k in TUNED_ATTRIBUTES) for k, v in dec.tensors().items()}
    s = GaussianScene(**leaves, sh_degree=dec.sh_degree)
    bgt = torch.tensor(bg, dtype=dec.means.dtype)
    total = 0.0
    for i in share:
        loss = ((_masked(render(s, views[i], background=bgt).image, masks[i]) - refs[i]) ** 2).sum()
        loss.backward()
        total += float(loss.detach())
    grads = {}
    for k in TUNED_ATTRIBUTES:
        g = leaves[k].grad
        grads[k] = torch.zeros_like(leaves[k]) if g is None else g
    # Decoded quaternions are unit: only the gradient along the sphere moves them.
    u = leaves["quats"].detach()
    g = grads["quats"]
    grads["quats"] = g - (g * u).sum(1, keepdim=True) * u
    return total, grads


def _to_input_rows(g: torch.Tensor, enc: EncodedAttributes, origin: torch.Tensor, name: str) -> torch.Tensor:
    """A gradient in ``enc``'s decoded order moved to the input's rows (0 for rows ``enc`` does not code);
    a quaternion's turned to the sign of the original it moves."""
    out = torch.zeros_like(origin)
    rows = torch.from_numpy(enc.kept)
    if name == "quats":
        dec = enc.decoded.quats.detach().float()
        sign = torch.where((dec * origin[rows]).sum(1, keepdim=True) < 0, -1.0, 1.0)
        g = g * sign
    out[rows] = g.to(out.dtype)
    return out


def _loss(enc: EncodedAttributes, views: Sequence[Camera], refs: list[torch.Tensor], masks, share, bg):
    bgt = torch.tensor(bg, dtype=enc.decoded.means.dtype)
    total = 0.0
    with torch.no_grad():
        for i in share:
            image = _masked(render(enc.decoded, views[i], background=bgt).image, masks[i])
            total += float(((image - refs[i]) ** 2).sum())
    return total


def _masked(image: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    return image if mask is None else image * mask


def _db(loss: float, views: Sequence[Camera], share: list[int]) -> float:
    """PSNR of a summed squared error over the share's pixels (three channels)."""
    pixels = sum(3 * views[i].width * views[i].height for i in share)
    return float(10.0 * np.log10(pixels / max(loss, 1e-30)))


def _report(done, views, before_db, after_db, enc, best, kept, t0) -> TuningReport:
    return TuningReport(
        done, views, before_db, after_db, enc.num_bytes, best.num_bytes, kept, time.perf_counter() - t0
    )
