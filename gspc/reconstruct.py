"""The decoder's reconstruction from side information: render G~ at the stored views, restore the renders,
refine G~ against them inside its quantisation cells.

The encoder predicts what the decoder will render and refine by running the decoder's own code, so these
steps live here, used by gspc/pipeline.py's decoder and gspc/encoder/policy.py alike.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass

import torch

from gspc.cameras import Camera
from gspc.codec import residuals
from gspc.codec.cells import quantisation_cells
from gspc.codec.precision import PrecisionMap
from gspc.codec.quantisers import Box
from gspc.errors import CodecError
from gspc.format.attribute_section import AttributeSection
from gspc.format.view_records import ViewRecord
from gspc.limits import (
    PAIR_FLOOR,
    PAIRS_PER_FILE_BYTE,
    RESTORE_PIXEL_WORK,
    WORK_FLOOR,
    WORK_PER_FILE_BYTE,
    RenderAllowance,
    allowance,
    default_refine_iterations,
    refine_work_iterations,
    view_work,
)
from gspc.progress import Progress
from gspc.refine import Deadline, Refined, Refinement, Schedule
from gspc.render import render
from gspc.render.work import view_pairs
from gspc.scene import GaussianScene, with_drawn
from gspc.stages import Stages
from gspc.visibility import sampling_coverage


@dataclass(frozen=True)
class DecodeWork:
    """What a decode that renders asks for, counted from the projections before anything is rendered
    (gspc/limits.py, spec 10.8 "The decoder's work"): each view's Gaussian-tile pairs and pixels, and the
    pixels it restores."""

    num_gaussians: int
    pairs: tuple[int, ...]  # per view
    pixels: tuple[int, ...]  # per view
    restored_pixels: int  # of the views whose residual the decoder restores

    @property
    def views(self) -> tuple[int, ...]:
        """Each view's work: rendering it once."""
        return tuple(view_work(self.num_gaussians, p, a) for p, a in zip(self.pairs, self.pixels))

    @property
    def first(self) -> int:
        """The first renders of every view and the restoration."""
        return sum(self.views) + RESTORE_PIXEL_WORK * self.restored_pixels

    @property
    def heaviest(self) -> int:
        """One refinement iteration's work: the heaviest view's."""
        return max(self.views, default=0)


def decode_work(
    scene: GaussianScene,
    cameras: Sequence[Camera],
    restored: Collection[int],
    file_size: int | RenderAllowance | None,
) -> DecodeWork:
    """The work of rendering ``scene`` at every camera and restoring the views ``restored`` (view numbers),
    each view's pairs counted from its projection alone; with a ``file_size`` (or a tile's allowance),
    refused (CodecError) as soon as a view is beyond its pair budget, before anything else is projected."""
    pairs = []
    for k, cam in enumerate(cameras):
        pairs.append(view_pairs(scene, cam))
        if file_size is not None:
            _check_view_pairs(k, pairs[-1], allowance(file_size))
    pixels = tuple(c.width * c.height for c in cameras)
    return DecodeWork(scene.num_gaussians, tuple(pairs), pixels, sum(pixels[k] for k in restored))


def _check_view_pairs(k: int, pairs: int, budget: RenderAllowance) -> None:
    if pairs > budget.pairs:
        raise CodecError(
            f"side-information view {k} asks for {pairs:,} Gaussian-tile pairs in {budget.of}; the limit is "
            f"{budget.pairs:,} (max({PAIR_FLOOR:,}, {PAIRS_PER_FILE_BYTE} per file byte), {budget.rule})"
        )


def check_decode_work(work: DecodeWork, file_size: int | RenderAllowance) -> None:
    """Refuse (CodecError) a file (or a tile, by its allowance) with a view beyond its pair budget, or whose
    first renders and restoration alone pass its work budget."""
    budget = allowance(file_size)
    for k, pairs in enumerate(work.pairs):
        _check_view_pairs(k, pairs, budget)
    if work.first > budget.work:
        raise CodecError(
            f"rendering and restoring the {len(work.pixels)} views asks for {work.first:,} units of work in "
            f"{budget.of}; the limit is {budget.work:,} (max({WORK_FLOOR:,}, {WORK_PER_FILE_BYTE} per file "
            f"byte), {budget.rule})"
        )


def work_bound(
    scene: GaussianScene,
    cameras: Sequence[Camera],
    restored: Collection[int],
    file_size: int | RenderAllowance,
) -> int:
    """The refinement iterations the work budget of a file of at least ``file_size`` bytes (or a tile's
    allowance) pays for, with ``scene`` at ``cameras`` restored at the views ``restored``: the encoder's
    check runs no more."""
    work = decode_work(scene, cameras, restored, None)
    return refine_work_iterations(work.first, work.heaviest, file_size)


def refine_iterations(file_iterations: int, work: DecodeWork, file_size: int | RenderAllowance) -> int:
    """The refinement a decode runs without --iterations: the file's number, bounded by its Gaussians and by
    what its work budget (or a tile's allowance) pays for after the first renders and restoration."""
    by_work = refine_work_iterations(work.first, work.heaviest, file_size)
    return min(default_refine_iterations(file_iterations, work.num_gaussians), by_work)


@torch.no_grad()
def render_images(
    scene: GaussianScene,
    cameras: Sequence[Camera],
    background: Sequence[float],
    progress: Progress | None = None,
    stage: str = "render",
    backend: str = "auto",
) -> list[torch.Tensor]:
    """Clamped renders, one per camera (what a viewer displays), by render's ``backend``."""
    bg = torch.tensor(background, dtype=scene.means.dtype, device=scene.means.device)
    out = []
    if progress:
        progress(stage, 0, len(cameras))
    for i, cam in enumerate(cameras):
        out.append(render(scene, cam, background=bg, backend=backend).image.clamp(0, 1))
        if progress:
            progress(stage, i + 1, len(cameras))
    return out


def restored_targets(
    degraded: list[torch.Tensor],
    views: Sequence[ViewRecord],
    images: dict[int, bytes],
    restorer,
    progress: Progress | None = None,
) -> list[torch.Tensor]:
    """The decoder's refinement targets: renders restored with their decoded residual ``images`` (by view
    number) where one was sent."""
    out = []
    if progress:
        progress("restore", 0, len(degraded))
    for k, (img, v) in enumerate(zip(degraded, views)):
        if k in images and restorer is not None:
            r = torch.from_numpy(residuals.decode_residual(images[k], v.residual)).to(img)
            img = restorer.restore(img, r)
        # A view without a residual keeps its render: the restorer alone gains little there
        # (bench/restorer.md, "Restoration of held-out views", the rows without R~).
        out.append(img.clamp(0, 1))
        if progress:
            progress("restore", k + 1, len(degraded))
    return out


def refine_progress(
    progress: Progress | None, stage: str, iterations: int
) -> Callable[[int, int, float], None] | None:
    """refine()'s per-iteration callback reporting to ``progress`` under ``stage`` (opened here)."""
    if progress is None:
        return None
    progress(stage, 0, iterations)
    return lambda done, total, loss: progress(stage, done, total)


# A refinement shorter than this takes steps in proportion (learning rates x iterations / FULL_RATE_FROM):
# Adam's first steps move every attribute by about its full rate whatever the gradient, and a short
# schedule has no time to undo that (bench/scale_pipeline.md, "Moved from code comments"). A schedule that a
# time budget cuts below FULL_RATE_FROM takes the steps of its new length from then on (gspc/refine.py,
# Schedule).
FULL_RATE_FROM = 300
# The decoder's learning rates: INRIA 3DGS's (gspc/refine.py, BASE_LR), but view-dependent colour's (sh_rest)
# times 8. INRIA's sh_rest rate (a twentieth of sh_dc's) is made for training from scratch; refining a coded
# scene, it is what holds the run back, and raising the other rates too gains nothing (bench/refine.md,
# "Moved from code comments"; "Summary" measures the result).
DECODER_GROUP_RATES = (("sh_rest", 8.0),)
# Views seeing a Gaussian (view_coverage: counted by the pixels they give it) from which the rates are full;
# fewer take them in proportion to the square of their share. With few views per Gaussian the cells leave
# refinement free to fit the targets at those views in ways that hurt every other view, and Adam steps about
# its full rate whatever the gradient. The real scenes' side-information views see each Gaussian more often
# than this and keep the full rates; the scale scenes' close-up views do not. In proportion to the share
# itself, a longer run's steps would grow with its length (FULL_RATE_FROM) and cost what its extra visits gain
# (bench/scale_pipeline.md, "Reading (by hand)", "More iterations at 1M" and "After: rates by the share's
# square").
COVERAGE_FULL = 16.0
# A mean over an evenly strided sample differs from the whole's in the second decimal, in a fraction of the
# time (bench/scale_pipeline.md, "Moved from code comments").
COVERAGE_SAMPLE = 1 << 16


def view_coverage(scene: GaussianScene, cameras: Sequence[Camera]) -> float:
    """The mean number of ``cameras`` that see a Gaussian of ``scene``, each counted by the pixels it gives
    the Gaussian against the closest (gspc/visibility.py, sampling_coverage), over the Gaussians some camera
    sees (0 where none is seen), estimated on at most COVERAGE_SAMPLE of them, evenly strided."""
    step = max(1, -(-scene.num_gaussians // COVERAGE_SAMPLE))
    cover = sampling_coverage(
        scene.means.detach()[::step].cpu().numpy(),
        scene.log_scales.detach()[::step].cpu().numpy(),
        list(cameras),
    )
    seen = cover[cover > 0]
    return float(seen.mean()) if seen.size else 0.0


def decoder_schedule(iterations: int, lr_scale: float = 1.0, coverage: float = COVERAGE_FULL) -> Schedule:
    """The decoder's refinement schedule for a run of ``iterations`` (``lr_scale``: the user's multiplier)
    over views that see each Gaussian ``coverage`` times on average (:func:`view_coverage`)."""
    rate = lr_scale * min(1.0, coverage / COVERAGE_FULL) ** 2
    return Schedule(iterations, rate, DECODER_GROUP_RATES, full_rate_from=FULL_RATE_FROM)


def decoder_refinement(
    decoded: GaussianScene,
    section: AttributeSection | None,
    cameras: list[Camera],
    targets: list[torch.Tensor],
    iterations: int,
    background: Sequence[float],
    seed: int = 0,
    lr_scale: float = 1.0,
    in_place: bool = False,
    precision: PrecisionMap | None = None,
    drawn: GaussianScene | None = None,
    cells: dict[str, Box] | None = None,
) -> Refinement:
    """The decoder's refinement of G~ against ``targets`` (:func:`decoder_schedule`), inside the
    quantisation cells of the attribute ``section`` (None: free refinement; at version 4 with the file's
    ``precision``), ready to run. ``in_place``: G~ itself is refined (a caller that keeps no use for it saves
    a copy). ``drawn``: a tile's neighbours, rendered with G~ and never refined (spec 10.15). ``cells``:
    G~'s cells given whole, in place of ``section``'s (a span's tiles, each in its own: spec 10.17)."""
    bg = torch.tensor(background, dtype=decoded.means.dtype, device=decoded.means.device)
    if cells is None and section is not None:
        cells = quantisation_cells(decoded, section, precision)
    schedule = decoder_schedule(iterations, lr_scale, view_coverage(decoded, cameras))
    return Refinement(decoded, cameras, targets, schedule, bg, cells, seed, in_place=in_place, drawn=drawn)


def refine_in_cells(
    decoded: GaussianScene,
    section: AttributeSection | None,
    cameras: list[Camera],
    targets: list[torch.Tensor],
    iterations: int,
    background: Sequence[float],
    progress: Progress | None = None,
    stage: str = "refine",
    seed: int = 0,
    lr_scale: float = 1.0,
    deadline: float | None = None,
    in_place: bool = False,
    precision: PrecisionMap | None = None,
    drawn: GaussianScene | None = None,
    cells: dict[str, Box] | None = None,
) -> Refined:
    """:func:`decoder_refinement` run to its end, or to ``deadline`` when one is given."""
    run = decoder_refinement(
        decoded,
        section,
        cameras,
        targets,
        iterations,
        background,
        seed,
        lr_scale,
        in_place,
        precision,
        drawn,
        cells,
    )
    limit = Deadline(deadline) if deadline is not None else None
    run.run(deadline=limit, progress=refine_progress(progress, stage, iterations))
    return run.result()


def reconstruct(
    scene: GaussianScene,
    section: AttributeSection | None,
    views: Sequence[ViewRecord],
    images: dict[int, bytes],
    restorer,
    iterations: int,
    background: Sequence[float],
    stages: Stages | None = None,
    seed: int = 0,
    lr_scale: float = 1.0,
    precision: PrecisionMap | None = None,
    drawn: GaussianScene | None = None,
    cells: dict[str, Box] | None = None,
) -> Refined:
    """The decoder's reconstruction (spec 10.8), of a file or of one tile (10.15) or span (10.17): G~
    rendered at the stored ``views``, the renders restored with their residuals, G~ refined against them in
    its cells (``section``'s, or ``cells`` given whole; neither: cells off) in place, each step a stage of
    ``stages`` (its progress and deadline). ``drawn``: the Gaussians of the tiles a tile's views show with
    its own, rendered, never refined."""
    stages = stages if stages is not None else Stages()
    cams = [v.camera.to_camera() for v in views]
    with stages.stage("render", announce=False):
        degraded = render_images(with_drawn(scene, drawn), cams, background, stages.progress, "render coded")
    with stages.stage("restore", announce=False):
        targets = restored_targets(degraded, views, images, restorer, stages.progress)
    del degraded
    with stages.stage("refine", announce=False):
        return refine_in_cells(
            scene,
            section,
            cams,
            targets,
            iterations,
            background,
            stages.progress,
            seed=seed,
            lr_scale=lr_scale,
            deadline=stages.deadline,
            in_place=True,  # G~ is not needed after
            precision=precision,
            drawn=drawn,
            cells=cells,
        )
