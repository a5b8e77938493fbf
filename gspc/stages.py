"""Stages that both the encoder and the decoder run: render views, restore them, refine against them.

The encoder predicts what the decoder will render and refine by running the decoder's own code, so these
stages live here, used by gspc/pipeline.py's decoder and gspc/encoder/policy.py alike.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

from gspc.cameras import Camera
from gspc.codec import residuals
from gspc.codec.cells import quantisation_cells
from gspc.format.attribute_section import AttributeSection
from gspc.format.view_records import ViewRecord
from gspc.progress import Progress
from gspc.refine import Refined, refine
from gspc.render import render
from gspc.scene import GaussianScene


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
        # A view without a residual keeps its render: the restorer alone measured no gain (bench/restorer.md).
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


# A refinement shorter than this takes steps in proportion (learning rates x iterations / SHORT_RUN): Adam's
# first steps move every attribute by about its full rate whatever the gradient, and a short schedule has no
# time to undo that. Measured on the 100k scale scene at close-up views (tools/bench_scale_pipeline.py's
# cameras, 16 per copy), 50 iterations against the unrefined 44.22 dB: rates x1 43.69, x0.3 44.16, x0.1
# 44.48; 200 iterations at x1: 45.01. The presets' runs (300 and 1000) are unchanged. A schedule that a time
# budget cuts below SHORT_RUN takes the steps of its new length from then on (gspc/refine.py).
SHORT_RUN = 300


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
) -> Refined:
    """The decoder's refinement of G~ against ``targets``, inside the quantisation cells of the attribute
    ``section`` (None: free refinement), ending by ``deadline`` when one is given. A run shorter
    than SHORT_RUN iterations takes proportionally smaller steps (its length after any cut decides).
    ``in_place``: G~ itself is refined (a caller that keeps no use for it saves a copy)."""
    bg = torch.tensor(background, dtype=decoded.means.dtype, device=decoded.means.device)
    return refine(
        decoded,
        cameras,
        targets,
        iterations=iterations,
        background=bg,
        seed=seed,
        lr_scale=lr_scale,
        short_run=SHORT_RUN,
        progress=refine_progress(progress, stage, iterations),
        cells=quantisation_cells(decoded, section) if section is not None else None,
        deadline=deadline,
        in_place=in_place,
    )
