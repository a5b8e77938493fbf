"""Decoder-side refinement: re-fit a decoded scene's attributes to restored renders (README.md, decoder).

Adam over the chosen attributes with per-attribute learning rates (INRIA 3DGS's, times the schedule's
multiplier), loss 0.8 * L1 + 0.2 * (1 - SSIM) on one view per iteration (drawn with a seeded generator, so
a run on the CPU is reproducible; on CUDA it is not bit for bit: gradients are summed with float atomics in
varying order), the Gaussian count fixed (no densification or pruning). The pieces each have their
own home: :class:`Schedule` (length, rates over time, render resolution), :class:`Deadline` (a time limit
that shortens the schedule), :func:`parameter_groups` and :func:`project_into_cells`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from gspc.adam import FusedAdam
from gspc.cameras import Camera
from gspc.codec.cells import clamp_into
from gspc.codec.quantisers import Box
from gspc.errors import InputError
from gspc.scene import ATTRIBUTE_NAMES, GaussianScene, with_drawn

# INRIA 3DGS learning rates (means are scaled by the scene extent), the base the schedule multiplies.
BASE_LR = {
    "means": 1.6e-4,
    "quats": 1e-3,
    "log_scales": 5e-3,
    "opacities": 5e-2,
    "sh_dc": 2.5e-3,
    "sh_rest": 2.5e-3 / 20,
}
SSIM_WEIGHT = 0.2
# With a deadline, PROBE_ITERATIONS iterations are timed and the schedule is shortened to what fits (the
# cosine decay then ends at the deadline instead of being cut off at full learning rate). They are the ones
# after the first: a process's first iteration also loads compiled code and takes many times as long
# (bench/refine.md, "Moved from code comments").
PROBE_ITERATIONS = 3


@dataclass(frozen=True)
class Schedule:
    """How a run steps: its length, its learning rates over time and the resolution it renders at.

    Rates are BASE_LR x ``rate`` x the attribute's own factor in ``group_rates`` (1 where not named) x a
    cosine decay to zero over the run (late steps only polish, so the result depends little on where it
    stops). ``full_rate_from``: a run shorter than this many iterations takes
    proportionally smaller steps (rates x length / full_rate_from; 0: off), its length after any cut by a
    deadline deciding. ``resolution`` < 1 renders and compares at reduced size (targets area-downsampled).
    """

    iterations: int
    rate: float = 1.0
    group_rates: tuple[tuple[str, float], ...] = ()  # (attribute, factor)
    full_rate_from: int = 0
    resolution: float = 1.0

    def group_rate(self, name: str) -> float:
        return dict(self.group_rates).get(name, 1.0)

    def learning_rate_factor(self, it: int, total: int) -> float:
        """The multiplier of BASE_LR at iteration ``it`` (from 0) of a run ``total`` long (its length after
        any cut by a deadline)."""
        decay = 0.5 * (1 + math.cos(math.pi * it / total))
        short = min(1.0, total / self.full_rate_from) if self.full_rate_from > 0 else 1.0
        return self.rate * short * decay


class Deadline:
    """A time limit (a ``time.perf_counter()`` value): after the first iteration, PROBE_ITERATIONS are timed
    and the run is shortened to what fits; whatever happens it stops once the limit has passed."""

    def __init__(self, at: float) -> None:
        self.at = at
        self._first_done = 0.0

    def passed(self) -> bool:
        return time.perf_counter() >= self.at

    def length(self, done: int, total: int, device: torch.device | None = None) -> int:
        """The run's new length after ``done`` iterations of a run ``total`` long."""
        from gspc.device import synchronize

        synchronize(device)  # the clock counts the queued GPU work
        now = time.perf_counter()
        if done == 1:
            self._first_done = now
        if done == 1 + PROBE_ITERATIONS:
            per_iteration = (now - self._first_done) / PROBE_ITERATIONS
            return min(total, done + max(0, math.floor((self.at - now) / per_iteration)))
        return done if now >= self.at else total


@dataclass
class Refined:
    scene: GaussianScene  # detached
    iterations: int  # iterations run: the requested count, or fewer where a deadline cut the schedule


def scene_extent(cameras: Sequence[Camera], scene: GaussianScene) -> float:
    """INRIA's "cameras extent": 1.1 x the largest camera distance from the cameras' mean centre.

    Falls back to the spread of the Gaussians when there are too few cameras to measure one: the distance
    from their median within which 90% of them lie, so a capture's far background and floaters do not set
    the step size of the foreground.
    """
    centers = np.stack([c.center for c in cameras])
    radius = float(np.linalg.norm(centers - centers.mean(0), axis=1).max()) * 1.1
    if radius > 0:
        return radius
    means = scene.means.detach().double()
    if scene.num_gaussians < 2:
        return 1.0
    spread = float((means - means.median(0).values).norm(dim=1).quantile(0.9))
    return spread if spread > 0 else 1.0


def parameter_groups(scene: GaussianScene, attributes: Sequence[str], extent: float) -> list[dict]:
    """Adam's groups: each chosen, non-empty attribute of ``scene`` (made a leaf that needs gradients) at its
    base rate, ``name`` kept for the projection."""
    groups = []
    for name in attributes:
        t = getattr(scene, name)
        if t.numel() == 0:  # e.g. sh_rest at SH degree 0
            continue
        t.requires_grad_(True)
        lr = BASE_LR[name] * (extent if name == "means" else 1.0)
        groups.append({"params": [t], "lr": lr, "name": name})
    return groups


@torch.no_grad()
def project_into_cells(groups: Sequence[dict], cells: dict[str, Box]) -> None:
    """Move every refined attribute (in place) back into its quantisation cell."""
    for g in groups:
        if g["name"] in cells:
            clamp_into(g["name"], g["params"][0], cells[g["name"]])


def _resize(img: torch.Tensor, h: int, w: int) -> torch.Tensor:
    if img.shape[:2] == (h, w):
        return img
    x = img.permute(2, 0, 1)[None]
    return F.interpolate(x, size=(h, w), mode="area")[0].permute(1, 2, 0)


def _check_inputs(
    cameras: Sequence[Camera], targets: Sequence[torch.Tensor], attributes: Sequence[str]
) -> None:
    if len(cameras) != len(targets) or not cameras:
        raise InputError(f"refinement needs one target per camera, got {len(cameras)} and {len(targets)}")
    unknown = set(attributes) - set(ATTRIBUTE_NAMES)
    if unknown:
        raise InputError(f"refinement got unknown attributes: {', '.join(sorted(unknown))}")
    for cam, t in zip(cameras, targets, strict=True):
        if tuple(t.shape) != (cam.height, cam.width, 3):
            raise InputError(
                f"target for camera {cam.name!r} is {tuple(t.shape)}, expected ({cam.height}, {cam.width}, 3)"
            )


class Refinement:
    """One refinement run that can be paused: :meth:`run` steps it up to an iteration, :meth:`scene` shows
    where it is, and running on continues the same trajectory (the encoder's check scores a run part-way and
    goes on only where the score leaves its decision open; gspc/encoder/policy.py).

    The input is left unchanged unless ``in_place`` (which saves a copy of the scene: 59 float32 values per
    Gaussian at SH degree 3), where it is the result. ``drawn``: Gaussians rendered with the scene but never
    refined (a tile's neighbours, spec 10.15). See :func:`refine` for the arguments."""

    def __init__(
        self,
        scene: GaussianScene,
        cameras: list[Camera],
        targets: list[torch.Tensor],
        schedule: Schedule,
        background: torch.Tensor | None = None,
        cells: dict[str, Box] | None = None,
        seed: int = 0,
        attributes: Sequence[str] = ATTRIBUTE_NAMES,
        in_place: bool = False,
        drawn: GaussianScene | None = None,
    ) -> None:
        _check_inputs(cameras, targets, attributes)
        self._scene = scene.map(lambda t: t.detach()) if in_place else scene.detach()
        self._drawn = None
        if drawn is not None and drawn.num_gaussians:
            self._drawn = drawn.to(self._scene.means.device, self._scene.means.dtype).detach()
        if schedule.resolution != 1.0:
            cameras = [c.scaled(schedule.resolution) for c in cameras]
        dtype, device = self._scene.means.dtype, self._scene.means.device
        self._cameras = cameras
        self._targets = [
            _resize(t.detach().to(device=device, dtype=dtype), c.height, c.width)
            for c, t in zip(cameras, targets, strict=True)
        ]
        self._schedule, self._background, self._cells = schedule, background, cells
        self._groups = parameter_groups(self._scene, attributes, scene_extent(cameras, self._scene))
        self._opt = None
        if self._groups:
            # fused: one pass over each tensor per step, several times faster than torch.optim.Adam's default
            # at a million Gaussians, where the step is a large share of an iteration (bench/speed.md, "Moved
            # from code comments"). The same kernel without torch.optim, whose import costs seconds
            # (gspc/adam.py).
            self._opt = FusedAdam(self._groups, eps=1e-15)
        self._base = [g["lr"] * schedule.group_rate(g["name"]) for g in self._groups]
        # A CPU generator whatever the scene's device: the views are drawn in the same order on every device.
        self._gen = torch.Generator().manual_seed(seed)
        self.done = 0
        self.skipped = 0  # iterations whose loss was not finite: no step taken
        self.total = schedule.iterations if self._groups else 0

    def run(
        self,
        until: int | None = None,
        deadline: Deadline | None = None,
        progress: Callable[[int, int, float], None] | None = None,
    ) -> None:
        """Step on to iteration ``until`` (default: the end), or until ``deadline`` shortens the run."""
        from gspc.device import float32_math
        from gspc.metrics import ssim  # imported here: refinement is the only user on the decode path
        from gspc.render import render

        stop = self.total if until is None else min(until, self.total)
        if deadline is not None and self.done == 0 and deadline.passed():
            self.total = 0
        while self.done < min(stop, self.total):
            factor = self._schedule.learning_rate_factor(self.done, self.total)
            for g, lr0 in zip(self._groups, self._base):
                g["lr"] = lr0 * factor
            v = int(torch.randint(len(self._cameras), (1,), generator=self._gen))
            image = render(with_drawn(self._scene, self._drawn), self._cameras[v], self._background).image
            target = self._targets[v]
            loss = (1 - SSIM_WEIGHT) * (image - target).abs().mean() + SSIM_WEIGHT * (1 - ssim(image, target))
            self._opt.zero_grad()
            # A scene's values may be finite but so large that the loss is not (a file may code colours of
            # 10^30): such a step would make every attribute NaN, so it is not taken.
            if bool(torch.isfinite(loss)):
                with float32_math():  # SSIM's convolutions' gradients too (gspc/device.py)
                    loss.backward()
                self._opt.step()
                if self._cells is not None:
                    project_into_cells(self._groups, self._cells)
            else:
                self.skipped += 1
            self.done += 1
            if deadline is not None:
                self.total = deadline.length(self.done, self.total, self._scene.means.device)
            if progress is not None:
                progress(self.done, self.total, float(loss.detach()))

    def scene(self) -> GaussianScene:
        """The scene as refined so far, detached (it shares memory with the run: copy it to keep it)."""
        return self._scene.map(lambda t: t.detach())

    def result(self) -> Refined:
        return Refined(self.scene(), self.done)


def refine(
    scene: GaussianScene,
    cameras: list[Camera],
    targets: list[torch.Tensor],
    schedule: Schedule,
    background: torch.Tensor | None = None,
    cells: dict[str, Box] | None = None,
    deadline: float | None = None,
    seed: int = 0,
    progress: Callable[[int, int, float], None] | None = None,
    attributes: Sequence[str] = ATTRIBUTE_NAMES,
    in_place: bool = False,
    drawn: GaussianScene | None = None,
) -> Refined:
    """Optimise ``attributes`` of ``scene`` so its renders at ``cameras`` match ``targets`` (H, W, 3).

    ``cells`` (from :func:`gspc.codec.cells.quantisation_cells`) keeps every attribute inside its
    quantisation cell after each step. ``deadline`` (a ``time.perf_counter()`` value, see
    :class:`Deadline`); without it the run depends on its inputs alone. ``progress(done, total, loss)`` is
    called after every step (``total`` shrinks if a deadline cuts the schedule). Returns the new, detached
    scene and the iterations run; the input is left unchanged unless ``in_place``, where it is the result.
    ``drawn``: Gaussians rendered with ``scene`` at every step, never refined.
    """
    run = Refinement(scene, cameras, targets, schedule, background, cells, seed, attributes, in_place, drawn)
    run.run(deadline=Deadline(deadline) if deadline is not None else None, progress=progress)
    return run.result()
