"""Spans: side information one tile's TSID serves for a run of neighbouring tiles (spec 10.17).

With side information per tile (gspc/encoder/tiles.py, spec 10.15) a view that sees several tiles is coded
once for each, and each tile is refined against its views with the others frozen: on a capture that every
view shows whole, that keeps part of what one refinement of the whole scene gains (bench/tiles.md,
"Refinement per tile against shared views"). A span joins consecutive tiles (neighbours on the Morton
curve) while their Gaussians fit ``--span-size``: its views are stored, and their residuals coded, once, and
the decoder refines its tiles together.

A span is a task after its tiles' codings: each tile coded at the rate for the decoder's refinement (its
values untuned), then the span's views rendered from the original and the coded tiles, the residuals coded,
and the check run as the decoder would run it, from the coded bytes: the span refined against its restored
views must beat, at views that carry none, both its coding and the same bytes spent on its tiles'
attributes, tuned as the encoder then writes them (each tile coded again in its bytes and its share of the
side information's). A span that sends none keeps those tuned tiles; coded to a fidelity, it keeps the
tiles tuned at the fidelity instead, and the side information's bytes stay unspent (as a tile's do:
gspc/encoder/side_decision.py).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import torch

from gspc.cameras import Camera
from gspc.codec.attributes import DecodedSection, decode_section
from gspc.codec.cells import span_cells
from gspc.encoder.policy import check_cameras
from gspc.encoder.prepare import iteration_counts, sample_side_views, side_candidates
from gspc.encoder.side import SideCandidate, view_residuals
from gspc.encoder.side_decision import CHUNK_ENTRY_BYTES, side_cameras
from gspc.encoder.tiles import (
    TileCoding,
    TileJob,
    TilePlan,
    TilesAtRate,
    TileSettings,
    TileSide,
    code_tile,
    code_tiles,
    plan_neighbours,
    retarget,
    tile_jobs,
)
from gspc.limits import MAX_DRAWN_TILES, MAX_SPAN_TILES
from gspc.metrics import mean_psnr
from gspc.options import EncodeOptions
from gspc.progress import Progress
from gspc.reconstruct import decode_work, decoder_refinement, render_images, restored_targets, work_bound
from gspc.render.work import drawn_beside
from gspc.restore.restorer import load_restorer
from gspc.scene import GaussianScene, with_drawn
from gspc.visibility import seeing_cameras
from gspc.workers import run_tasks


def plan_spans(sizes: Sequence[int], span_size: int) -> list[tuple[int, int]]:
    """(first, end) runs of consecutive tiles of ``sizes`` Gaussians, joined while they fit ``span_size``
    and MAX_SPAN_TILES (a tile larger than ``span_size`` is a span of its own)."""
    runs: list[tuple[int, int]] = []
    total = 0
    for k, n in enumerate(sizes):
        if runs and total + n <= span_size and k - runs[-1][0] < MAX_SPAN_TILES:
            runs[-1] = (runs[-1][0], k + 1)
            total += n
        else:
            runs.append((k, k + 1))
            total = n
    return runs


@dataclass(frozen=True)
class SpanJob:
    """What weighing one span's side information needs: its tiles' coding jobs and their codings at the rate
    for the decoder's refinement, the run's options, and the tiles its views draw beside it (spec 10.15)."""

    first: int
    tiles: tuple[TileJob, ...]
    codings: tuple[TileCoding, ...]
    opts: EncodeOptions
    drawn: tuple[int, ...] = ()
    drawn_tiles: tuple[tuple[object, object], ...] = ()  # each drawn tile's source and rows, as TileJob's
    targets: tuple[int, ...] | None = None  # each tile's share of a byte target (None: at the rate)


@dataclass(frozen=True)
class SpanCoding:
    """A span's tiles as the file holds them (its first tile's record names the span and its drawn tiles)
    and its side information (on the first tile; the others carry none)."""

    first: int
    codings: tuple[TileCoding, ...]
    side: TileSide
    seconds: float


def code_span(job: SpanJob) -> SpanCoding:
    """Weigh one span's side information (the module's docstring): a task, the same bytes wherever it
    runs."""
    t0 = time.perf_counter()
    opts = job.opts
    original = GaussianScene.concat([_source(t) for t in job.tiles])
    parts = [_decoded(c) for c in job.codings]
    coded = GaussianScene.concat([p.scene for p in parts])
    cams = _seeing(original, job.tiles[0].cameras)
    view_indices, view_cams = sample_side_views(cams, opts)
    runs = iteration_counts(opts, coded.num_gaussians)
    if len(cams) < 2 or not view_indices:
        return _declined(job, "none (no view sampled)", runs.refine, t0)
    seen = side_cameras(cams, opts)
    drawn = drawn_beside((_source_of(s, r) for s, r in job.drawn_tiles), seen) if job.drawn_tiles else None
    bg = opts.background
    shown = with_drawn(original, drawn)
    reference_views = render_images(shown, view_cams, bg, backend="torch")
    coded_views = render_images(with_drawn(coded, drawn), view_cams, bg, backend="torch")
    side = side_candidates(opts, view_cams, view_residuals(reference_views, coded_views), runs.check)[0]
    if side.payload is not None and job.targets is not None:
        # In a byte target: the tiles coded again in what the side information leaves, its residuals made
        # again for that coding (as gspc/encoder/side_decision.py does for one scene).
        room = _shares(job.targets, len(side.payload) + CHUNK_ENTRY_BYTES)
        again = (code_tile(replace(t, byte_target=r, tuning=None)) for t, r in zip(job.tiles, room))
        job = replace(job, codings=tuple(again))
        parts = [_decoded(c) for c in job.codings]
        coded = GaussianScene.concat([p.scene for p in parts])
        coded_views = render_images(with_drawn(coded, drawn), view_cams, bg, backend="torch")
        side = side_candidates(opts, view_cams, view_residuals(reference_views, coded_views), runs.check)[0]
    if side.payload is None:
        return _declined(job, "none (no view's residual was worth sending)", runs.refine, t0)
    # No more iterations than a decode of a file of at least these payloads runs (spec 10.8).
    least = sum(c.num_bytes for c in job.codings) + len(side.payload)
    runs = iteration_counts(
        opts, coded.num_gaussians, work_bound(with_drawn(coded, drawn), view_cams, side.images, least)
    )
    if runs.check == 0:
        return _sent(
            job, side, "sent (unchecked, --check-iterations 0)", runs.refine, coded, drawn, view_cams, t0
        )
    checks = check_cameras(cams, view_indices, opts.check_views)
    reference = render_images(shown, checks, bg)

    def score(s: GaussianScene) -> float:
        # Capped per view, as the tile's check is (gspc/encoder/policy.py).
        return mean_psnr(render_images(with_drawn(s, drawn), checks, bg), reference, capped=True)

    before = score(coded)
    rivals = _rivals(job, len(side.payload) + CHUNK_ENTRY_BYTES)
    rival_db = score(GaussianScene.concat([_decoded(c).scene for c in rivals]))
    restorer = load_restorer(opts.restorer, device=torch.device("cpu"))
    targets = restored_targets(coded_views, side.records, side.images, restorer)
    cells = span_cells([(p.scene, c.tile.section, p.precision) for p, c in zip(parts, job.codings)])
    run = decoder_refinement(coded, None, view_cams, targets, runs.refine, bg, drawn=drawn, cells=cells)
    run.run()
    after = score(run.scene())
    measured = (
        f"at {len(checks)} views carrying none: coded {before:.2f} dB, refined {after:.2f} dB, the same "
        f"bytes on its tiles' attributes (tuned) {rival_db:.2f} dB"
    )
    if after < max(before, rival_db) + opts.check_margin_db:
        kept = rivals if job.tiles[0].fidelity is None else _tuned(job)
        why = "spent on its tiles' attributes" if job.tiles[0].fidelity is None else "left unspent"
        return SpanCoding(
            job.first, kept, TileSide(None, f"none: {measured}; {why}", runs.refine, None), _since(t0)
        )
    return _sent(job, side, f"sent: {measured}", runs.refine, coded, drawn, view_cams, t0)


def _sent(
    job: SpanJob,
    side: SideCandidate,
    reason: str,
    iterations: int,
    coded: GaussianScene,
    drawn: GaussianScene | None,
    view_cams: list[Camera],
    t0: float,
) -> SpanCoding:
    """The span's tiles as coded for refinement, its first naming the span and its drawn tiles, and the side
    information with what its views ask of a decoder (with its neighbours as the original has them; the
    file's check counts them decoded)."""
    work = decode_work(with_drawn(coded, drawn), view_cams, side.images, None)
    sent = TileSide(side.payload, reason, iterations, work, side.views_with_residual)
    lead = job.codings[0]
    lead = replace(lead, tile=replace(lead.tile, drawn=job.drawn, span=len(job.codings)))
    return SpanCoding(job.first, (lead, *job.codings[1:]), sent, _since(t0))


def _declined(job: SpanJob, reason: str, iterations: int, t0: float) -> SpanCoding:
    """A span that weighed no side information: its tiles tuned, as a file without any holds them."""
    return SpanCoding(job.first, _tuned(job), TileSide(None, reason, iterations, None), _since(t0))


def _tuned(job: SpanJob) -> tuple[TileCoding, ...]:
    """The span's tiles coded as a file without side information codes them (tuned, at the fidelity or the
    rate)."""
    return tuple(code_tile(replace(t, params=t.params.unrefined(), side=None)) for t in job.tiles)


def _rivals(job: SpanJob, extra: int) -> tuple[TileCoding, ...]:
    """Each tile coded again in its bytes and its share of ``extra`` (by its bytes; in a byte target, its
    share of it), tuned, for no refinement: the same bytes as the span with its side information, on
    attributes alone."""
    budgets = job.targets
    if budgets is None:
        total = sum(c.num_bytes for c in job.codings)
        budgets = tuple(c.num_bytes + extra * c.num_bytes // max(total, 1) for c in job.codings)
    return tuple(
        code_tile(replace(t, params=t.params.unrefined(), byte_target=b, fidelity=None))
        for t, b in zip(job.tiles, budgets)
    )


def _shares(targets: Sequence[int], extra: int) -> list[int]:
    """Each tile's target less its share of ``extra`` bytes (by its target)."""
    total = sum(targets)
    return [max(1, t - extra * t // max(total, 1)) for t in targets]


def _decoded(coding: TileCoding) -> DecodedSection:
    return decode_section(coding.chunks, coding.tile.section)


def _source(t: TileJob) -> GaussianScene:
    return t.source if t.rows is None else t.source.rows(t.rows)


def _source_of(source, rows) -> GaussianScene:
    return source if rows is None else source.rows(rows)


def _seeing(scene: GaussianScene, cameras: Sequence[Camera]) -> list[Camera]:
    seen = seeing_cameras(scene.means.detach().numpy(), scene.log_scales.detach().numpy(), list(cameras))
    return [cameras[k] for k in seen] or list(cameras)


def _since(t0: float) -> float:
    return time.perf_counter() - t0


def span_drawn(neighbours: Sequence[tuple[int, ...]], first: int, end: int, limit: int) -> tuple[int, ...]:
    """The tiles a span's views draw: its tiles' neighbours outside it, in tile order, at most ``limit``."""
    inside = set(range(first, end))
    out = [j for j in itertools.chain(*neighbours[first:end]) if j not in inside]
    return tuple(sorted(dict.fromkeys(out))[:limit])


def code_spans(
    source,
    settings: TileSettings,
    tile_size: int,
    span_size: int,
    workers,
    progress: Progress | None = None,
    byte_target: int | None = None,
    at_rate: TilesAtRate | None = None,
) -> tuple[TilePlan, list[TileCoding], TilesAtRate, list[SpanCoding]]:
    """The tiles of ``source`` coded at the rate for the decoder's refinement (or each in its share of
    ``byte_target`` attribute and side-information bytes), joined into spans of at most ``span_size``
    Gaussians, and each span's side information weighed (the module's docstring), on ``workers``: the tiles
    as the file holds them, in order, each span's first carrying its side information (TileCoding.side; the
    others None). ``at_rate``: an earlier call's tiles at the rate (code_tiles')."""
    untuned = replace(settings, side=None, tuning=None)
    plan, first, at_rate = code_tiles(source, untuned, tile_size, workers, byte_target, progress, at_rate)
    targets = None if byte_target is None else retarget(at_rate.codings, byte_target)
    runs = plan_spans([c.given for c in first], span_size)  # what its task holds: the given Gaussians
    neighbours: list[tuple[int, ...]] = [() for _ in plan.rows]
    if settings.neighbours:
        neighbours = plan_neighbours(plan.rows, source.positions())
    tiles = list(tile_jobs(source, replace(settings, side=None), at_rate, targets))

    def jobs() -> Iterator[SpanJob]:
        for a, b in runs:
            drawn = span_drawn(neighbours, a, b, MAX_DRAWN_TILES)
            others = tuple(source.tile(plan.rows[j]) for j in drawn)
            shares = None if targets is None else tuple(targets[a:b])
            yield SpanJob(a, tuple(tiles[a:b]), tuple(first[a:b]), settings.side, drawn, others, shares)

    stage = "spans' side information"
    spans = list(run_tasks(code_span, jobs(), workers, _span_name, len(runs), progress, stage))
    out: list[TileCoding] = []
    for (a, b), span in zip(runs, spans):
        lead, *rest = span.codings
        seconds = sum(c.seconds for c in first[a:b]) + span.seconds  # its tiles' first codings and its task
        out.append(replace(lead, side=span.side, seconds=seconds))
        out.extend(replace(c, side=None, seconds=0.0) for c in rest)
    return plan, out, at_rate, spans


def spans_line(codings: Sequence[TileCoding]) -> str:
    """The summary's side-information line of a file coded in spans (spec 10.17)."""
    leads = [c for c in codings if c.side is not None]
    sent = [c for c in leads if c.side.payload is not None]
    sizes = [c.tile.span for c in sent]
    if not sent:
        if len(leads) == 1:
            return leads[0].side.reason
        checked = sum(c.side.reason.startswith("none: at") for c in leads)
        return (
            f"none sent by its {len(leads)} spans: {checked} declined by the check, "
            f"{len(leads) - checked} had no residual worth sending"
        )
    size = sum(len(c.side.payload) for c in sent)
    views = sum(c.side.views_with_residual for c in sent)
    line = (
        f"shared by spans of tiles: sent for {len(sent)} of {len(leads)} spans ({min(sizes)}-{max(sizes)} "
        f"tiles each, {sum(sizes)} of {len(codings)} tiles), {views} views with a residual, {size:,} B"
    )
    if len(sent) == 1:
        line += f"; {sent[0].side.reason}"
    return line


def _span_name(job: SpanJob) -> str:
    return f"span from tile {job.first}"
