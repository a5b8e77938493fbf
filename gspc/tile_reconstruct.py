"""One tile of a tiled file decoded and, where it carries side information of its own (a TSID chunk, spec
10.15), restored and refined: the decoder's reconstruction (gspc/reconstruct.py) on the tile's Gaussians, at
the tile's views, with the tiles its index names drawn beside them (decoded, never refined), bounded by the
tile's share of the file's budget. A tile whose side information serves a span of tiles (10.17) is decoded
with the span's other tiles and refined with them as one scene, each Gaussian in its own tile's cells. A
task of plain data, so tiles (and spans) reconstruct side by side in worker processes (gspc/workers.py),
each the same wherever it runs: its result depends on the file alone.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch

from gspc.codec.cells import span_cells
from gspc.codec.tiles import TileDecodeJob, decode_tile, decode_tile_section
from gspc.device import check_device
from gspc.format.side_chunk import SideViews
from gspc.jit import compile_kernels, uncompiled_kernels
from gspc.limits import RenderAllowance, default_refine_iterations
from gspc.options import DecodeOptions
from gspc.reconstruct import DecodeWork, check_decode_work, decode_work, reconstruct, refine_iterations
from gspc.render.work import drawn_beside
from gspc.restore.restorer import load_restorer
from gspc.scene import GaussianScene, with_drawn


@dataclass(frozen=True)
class TileSideSettings:
    """What every tile's reconstruction reads from the file's header (``meta["side_info"]``) and the
    decode's options."""

    background: tuple[float, float, float]
    restorer: str  # the file's, or the one the options name
    file_iterations: int  # side_info.refine_iterations
    opts: DecodeOptions


@dataclass(frozen=True)
class TileReconstructJob:
    attributes: TileDecodeJob
    side: SideViews | None  # the tile's TSID, read and checked (None: the tile has none)
    allowance: RenderAllowance  # the tile's share of the file's budget (spec 10.15)
    settings: TileSideSettings | None  # None: the attributes only (no tile of the file carries side info)
    drawn: tuple[TileDecodeJob, ...] = ()  # the tiles its views show with its own (spec 10.15)
    members: tuple[TileDecodeJob, ...] = ()  # the other tiles of its span, in order (spec 10.17)


@dataclass(frozen=True)
class TileOutcome:
    """What a tile's reconstruction did, for the decode's report."""

    iterations: int  # the refinement run (0: none)
    why_not: str | None  # why the tile was not refined, where it was not
    views: int  # its side information's views
    drawn: int = 0  # the Gaussians of other tiles its refinement drew (spec 10.15)
    tiles: int = 1  # the tiles refined together: its span's (spec 10.17)


@dataclass(frozen=True)
class TileReconstruction:
    """The job's tiles (its own, then its span's others), numbered, and what was done to them."""

    tiles: tuple[tuple[int, GaussianScene], ...]
    outcome: TileOutcome


def reconstruct_tile(job: TileReconstructJob) -> TileReconstruction:
    """The tile's Gaussians (and its span's: spec 10.17): decoded, then restored and refined against its own
    views where it carries side information and the options allow (spec 10.15; the decoder procedure of 10.8
    on the tile or span, the tiles its index names drawn beside it)."""
    jobs = (job.attributes, *job.members)
    parts = [decode_tile_section(j) for j in jobs]
    scene = parts[0].scene if len(parts) == 1 else GaussianScene.concat([p.scene for p in parts])
    s = job.settings
    views = len(job.side.views) if job.side is not None else 0

    def unrefined(why: str | None) -> TileReconstruction:
        return TileReconstruction(
            _numbered(jobs, [p.scene for p in parts]), TileOutcome(0, why, views, 0, len(jobs))
        )

    why_not = _no_refinement(job.side, s)
    if why_not is not None or s is None or job.side is None:
        return unrefined(why_not)
    opts = s.opts
    iterations = opts.iterations
    if iterations is None:
        iterations = default_refine_iterations(s.file_iterations, scene.num_gaussians)
    if iterations == 0:
        return unrefined("0 iterations")
    device = check_device(opts.device)
    if device.type == "cpu" and uncompiled_kernels():
        compile_kernels(None)
    drawn, work = tile_views_work(scene, job.side, job.drawn, job.allowance)
    if opts.iterations is None:
        iterations = refine_iterations(s.file_iterations, work, job.allowance)
        if iterations == 0:
            return unrefined("its share of the work budget pays for none (spec 10.15)")
    restorer = load_restorer(s.restorer, device=device)
    section = job.attributes.section if opts.in_cells and not job.members else None
    cells = None
    if opts.in_cells and job.members:  # each tile of the span in its own cells (spec 10.17)
        cells = span_cells([(p.scene, j.section, p.precision) for p, j in zip(parts, jobs)])
        cells = {k: (lo.to(device), hi.to(device)) for k, (lo, hi) in cells.items()}
    side = job.side
    refined = reconstruct(
        scene.to(device),
        section,
        side.views,
        side.images,
        restorer,
        iterations,
        s.background,
        seed=opts.seed,
        lr_scale=opts.lr_scale,
        precision=parts[0].precision,
        drawn=None if drawn is None else drawn.to(device),
        cells=cells,
    )
    shown = 0 if drawn is None else drawn.num_gaussians
    out = refined.scene.to("cpu")
    counts = [p.scene.num_gaussians for p in parts]
    split = [out] if len(parts) == 1 else _split(out, counts)
    return TileReconstruction(
        _numbered(jobs, split), TileOutcome(refined.iterations, None, views, shown, len(jobs))
    )


def _numbered(jobs, scenes: list[GaussianScene]) -> tuple[tuple[int, GaussianScene], ...]:
    return tuple((j.number, s) for j, s in zip(jobs, scenes))


def _split(scene: GaussianScene, counts: list[int]) -> list[GaussianScene]:
    """``scene`` cut back into runs of ``counts`` Gaussians, in order (a span's tiles: spec 10.17)."""
    starts = [0, *itertools.accumulate(counts)]
    return [scene.subset(torch.arange(a, b)) for a, b in zip(starts, starts[1:])]


def tile_views_work(
    scene: GaussianScene, side: SideViews, drawn_tiles: tuple[TileDecodeJob, ...], allowance: RenderAllowance
) -> tuple[GaussianScene | None, DecodeWork]:
    """What a tile's views show beside its own Gaussians (the tiles ``drawn_tiles``, each decoded in turn and
    culled to what the views see), and the work they ask, refused (CodecError) beyond the tile's allowance
    (spec 10.15)."""
    cams = [v.camera.to_camera() for v in side.views]
    drawn = drawn_beside((decode_tile(j) for j in drawn_tiles), cams)
    work = decode_work(with_drawn(scene, drawn), cams, side.images, allowance)
    check_decode_work(work, allowance)
    return drawn, work


def _no_refinement(side: SideViews | None, s: TileSideSettings | None) -> str | None:
    """Why a tile keeps its decoded Gaussians (None: it is refined), as gspc/pipeline.py says it of a file."""
    if s is None or side is None or not side.views:
        return "no side information of its own"
    if not s.opts.refine:
        return "--no-refine"
    if not side.images:
        return "no view carries a residual"
    if not s.opts.restore:
        return "--no-restore: the targets would be the renders themselves"
    return None
