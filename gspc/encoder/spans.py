"""Spans: side information one tile's TSID serves for a run of neighbouring tiles (spec 10.17).

With side information per tile (gspc/encoder/tiles.py, spec 10.15) a view that sees several tiles is coded
once for each, and each tile is refined against its views with the others frozen: on a capture that every
view shows whole, that keeps part of what one refinement of the whole scene gains (bench/tiles.md,
"Refinement per tile against shared views"). A span joins consecutive tiles (neighbours on the Morton
curve) while their Gaussians fit ``--span-size``: its views are stored, and their residuals coded, once, and
the decoder refines its tiles together.

After its tiles' codings (each tile coded at the rate for the decoder's refinement, its values untuned), a
span is weighed in rounds of tasks, so that the workers share the work of a file of few spans: its views
rendered from the original and the coded tiles and the residuals coded (a task per span); its rival, each
tile coded again in its bytes and its share of the side information's and tuned, as the encoder then writes
a file without side information (a task per tile); and the check, run as the decoder would run it, from the
coded bytes (a task per span): the span refined against its restored views must beat, at views that carry
none, both its coding and its rival. A span that sends none keeps its rival's tiles; coded to a fidelity, it
keeps its tiles tuned at the fidelity instead, and the side information's bytes stay unspent (as a tile's
do: gspc/encoder/side_decision.py).
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Sequence
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


@dataclass(frozen=True)
class SpanCandidate:
    """A span's side information before its check: the tiles it goes with (coded again where a byte target
    leaves them less) and its residuals, or why it has none; ``done`` where nothing is left to weigh (sent
    unchecked)."""

    codings: tuple[TileCoding, ...]
    side: SideCandidate | None
    reason: str
    iterations: int
    seconds: float
    done: SpanCoding | None = None


@dataclass(frozen=True)
class SpanCheckJob:
    """A span's check: the span, its candidate and its rival (its tiles on attributes alone)."""

    span: SpanJob
    candidate: SpanCandidate
    rivals: tuple[TileCoding, ...]


@dataclass(frozen=True)
class _Seen:
    """What a span's views are: the cameras that see it, the side-information views among them, and the
    original Gaussians of the tiles they draw beside it."""

    cams: list[Camera]
    view_indices: list[int]
    view_cams: list[Camera]
    drawn: GaussianScene | None


def _seen(job: SpanJob, original: GaussianScene) -> _Seen:
    cams = _seeing(original, job.tiles[0].cameras)
    view_indices, view_cams = sample_side_views(cams, job.opts)
    drawn = None
    if job.drawn_tiles and view_indices:
        seen = side_cameras(cams, job.opts)
        drawn = drawn_beside((_source_of(s, r) for s, r in job.drawn_tiles), seen)
    return _Seen(cams, view_indices, view_cams, drawn)


def span_candidate(job: SpanJob) -> SpanCandidate:
    """A span's views and residuals (the module's docstring), a task: the same bytes wherever it runs."""
    t0 = time.perf_counter()
    opts = job.opts
    original = GaussianScene.concat([_source(t) for t in job.tiles])
    coded = _joined(job.codings)
    seen = _seen(job, original)
    runs = iteration_counts(opts, coded.num_gaussians)
    if len(seen.cams) < 2 or not seen.view_indices:
        return SpanCandidate(job.codings, None, "none (no view sampled)", runs.refine, _since(t0))
    bg = opts.background
    reference_views = render_images(with_drawn(original, seen.drawn), seen.view_cams, bg, backend="torch")

    def residuals(coded: GaussianScene) -> SideCandidate:
        coded_views = render_images(with_drawn(coded, seen.drawn), seen.view_cams, bg, backend="torch")
        res = view_residuals(reference_views, coded_views)
        return side_candidates(opts, seen.view_cams, res, runs.check)[0]

    codings = job.codings
    side = residuals(coded)
    if side.payload is not None and job.targets is not None:
        # In a byte target: the tiles coded again in what the side information leaves, its residuals made
        # again for that coding (as gspc/encoder/side_decision.py does for one scene).
        room = _shares(job.targets, len(side.payload) + CHUNK_ENTRY_BYTES)
        codings = tuple(code_tile(replace(t, byte_target=r, tuning=None)) for t, r in zip(job.tiles, room))
        coded = _joined(codings)
        side = residuals(coded)
    if side.payload is None:
        why = "none (no view's residual was worth sending)"
        return SpanCandidate(codings, None, why, runs.refine, _since(t0))
    # No more iterations than a decode of a file of at least these payloads runs (spec 10.8).
    least = sum(c.num_bytes for c in codings) + len(side.payload)
    shown = with_drawn(coded, seen.drawn)
    runs = iteration_counts(opts, coded.num_gaussians, work_bound(shown, seen.view_cams, side.images, least))
    if runs.check > 0:
        return SpanCandidate(codings, side, "", runs.refine, _since(t0))
    why = "sent (unchecked, --check-iterations 0)"
    done = _sent(job, codings, coded, side, why, runs.refine, seen, t0)
    return SpanCandidate(codings, side, why, runs.refine, _since(t0), done)


def check_span(task: SpanCheckJob) -> SpanCoding:
    """A span's check (the module's docstring): its coding refined against its restored views against its
    coding and its rival at views that carry none; a task, the same bytes wherever it runs. A span that
    declines keeps its rival (coded to a fidelity: its tiles tuned at the fidelity, which the caller codes
    where ``codings`` is empty)."""
    t0 = time.perf_counter()
    job, cand = task.span, task.candidate
    opts, bg, side = job.opts, job.opts.background, cand.side
    original = GaussianScene.concat([_source(t) for t in job.tiles])
    seen = _seen(job, original)
    parts = [_decoded(c) for c in cand.codings]
    coded = GaussianScene.concat([p.scene for p in parts])
    checks = check_cameras(seen.cams, seen.view_indices, opts.check_views)
    reference = render_images(with_drawn(original, seen.drawn), checks, bg)

    def score(s: GaussianScene) -> float:
        # Capped per view, as the tile's check is (gspc/encoder/policy.py).
        return mean_psnr(render_images(with_drawn(s, seen.drawn), checks, bg), reference, capped=True)

    before = score(coded)
    rival_db = score(_joined(task.rivals))
    restorer = load_restorer(opts.restorer, device=torch.device("cpu"))
    coded_views = render_images(with_drawn(coded, seen.drawn), seen.view_cams, bg, backend="torch")
    targets = restored_targets(coded_views, side.records, side.images, restorer)
    cells = span_cells([(p.scene, c.tile.section, p.precision) for p, c in zip(parts, cand.codings)])
    drawn = seen.drawn
    run = decoder_refinement(
        coded, None, seen.view_cams, targets, cand.iterations, bg, drawn=drawn, cells=cells
    )
    run.run()
    after = score(run.scene())
    measured = (
        f"at {len(checks)} views carrying none: coded {before:.2f} dB, refined {after:.2f} dB, the same "
        f"bytes on its tiles' attributes (tuned) {rival_db:.2f} dB"
    )
    if after >= max(before, rival_db) + opts.check_margin_db:
        return _sent(job, cand.codings, coded, side, f"sent: {measured}", cand.iterations, seen, t0)
    at_fidelity = job.tiles[0].fidelity is not None
    kept = () if at_fidelity else task.rivals
    why = "left unspent" if at_fidelity else "spent on its tiles' attributes"
    return SpanCoding(
        job.first, kept, TileSide(None, f"none: {measured}; {why}", cand.iterations, None), _since(t0)
    )


def _sent(
    job: SpanJob,
    codings: tuple[TileCoding, ...],
    coded: GaussianScene,
    side: SideCandidate,
    reason: str,
    iterations: int,
    seen: _Seen,
    t0: float,
) -> SpanCoding:
    """The span's tiles as coded for refinement (``coded``: their decoded Gaussians), its first naming the
    span and its drawn tiles, and the side information with what its views ask of a decoder (with its
    neighbours as the original has them; the file's check counts them decoded)."""
    work = decode_work(with_drawn(coded, seen.drawn), seen.view_cams, side.images, None)
    sent = TileSide(side.payload, reason, iterations, work, side.views_with_residual)
    lead = replace(codings[0], tile=replace(codings[0].tile, drawn=job.drawn, span=len(codings)))
    return SpanCoding(job.first, (lead, *codings[1:]), sent, _since(t0))


def _tuned_jobs(job: SpanJob) -> list[TileJob]:
    """The span's tiles as a file without side information codes them (tuned, at the fidelity or the rate,
    for no refinement)."""
    return [replace(t, params=t.params.unrefined(), side=None) for t in job.tiles]


def _rival_jobs(job: SpanJob, codings: tuple[TileCoding, ...], extra: int) -> list[TileJob]:
    """Each tile coded again in its bytes and its share of ``extra`` (by its bytes; in a byte target, its
    share of it), tuned, for no refinement: the same bytes as the span with its side information, on
    attributes alone."""
    budgets = job.targets
    if budgets is None:
        total = sum(c.num_bytes for c in codings)
        budgets = tuple(c.num_bytes + extra * c.num_bytes // max(total, 1) for c in codings)
    return [
        replace(t, params=t.params.unrefined(), byte_target=b, fidelity=None)
        for t, b in zip(job.tiles, budgets)
    ]


def _shares(targets: Sequence[int], extra: int) -> list[int]:
    """Each tile's target less its share of ``extra`` bytes (by its target)."""
    total = sum(targets)
    return [max(1, t - extra * t // max(total, 1)) for t in targets]


def _joined(codings: Sequence[TileCoding]) -> GaussianScene:
    """The decoded Gaussians of ``codings``, one tile after another."""
    return GaussianScene.concat([_decoded(c).scene for c in codings])


def _decoded(coding: TileCoding) -> DecodedSection:
    return decode_section(coding.chunks, coding.tile.section)


def _source(t: TileJob) -> GaussianScene:
    return _source_of(t.source, t.rows)


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

    spans: list[SpanJob] = []
    for a, b in runs:
        drawn = span_drawn(neighbours, a, b, MAX_DRAWN_TILES)
        others = tuple(source.tile(plan.rows[j]) for j in drawn)
        shares = None if targets is None else tuple(targets[a:b])
        spans.append(SpanJob(a, tuple(tiles[a:b]), tuple(first[a:b]), settings.side, drawn, others, shares))
    # Each step a round of tasks over every span (or every tile of them), so that the workers share the work
    # of a file of few spans: the views and residuals, then the rivals' tiles, then the checks.
    cands = _tasks(span_candidate, spans, _span_name, workers, progress, "spans' views and residuals")
    rivals = _tiles_for(spans, cands, workers, progress)
    checking = [SpanCheckJob(j, c, rivals[i]) for i, (j, c) in enumerate(zip(spans, cands)) if _checked(c)]
    checked = iter(_tasks(check_span, checking, _check_name, workers, progress, "spans' checks"))
    done: list[SpanCoding] = []
    for i, (job, cand) in enumerate(zip(spans, cands)):
        if cand.done is not None:
            done.append(cand.done)
        elif cand.side is None:  # no residual: the tiles tuned, as a file without side information
            side = TileSide(None, cand.reason, cand.iterations, None)
            done.append(SpanCoding(job.first, rivals[i], side, cand.seconds))
        else:
            done.append(next(checked))
    # Coded to a fidelity, a span that declined keeps its tiles tuned at the fidelity.
    unspent = [i for i, d in enumerate(done) if not d.codings]
    tuned = [t for i in unspent for t in _tuned_jobs(spans[i])]
    again = _tasks(code_tile, tuned, _tile_name, workers, progress, "spans' tiles without side information")
    for i in unspent:
        n = len(spans[i].tiles)
        done[i] = replace(done[i], codings=tuple(again[:n]))
        again = again[n:]
    out: list[TileCoding] = []
    for (a, b), span, cand in zip(runs, done, cands):
        lead, *rest = span.codings
        seconds = sum(c.seconds for c in first[a:b]) + cand.seconds + span.seconds  # every task of the span
        out.append(replace(lead, side=span.side, seconds=seconds))
        out.extend(replace(c, side=None, seconds=0.0) for c in rest)
    return plan, out, at_rate, done


def _checked(cand: SpanCandidate) -> bool:
    return cand.done is None and cand.side is not None


def _tiles_for(
    spans: list[SpanJob], cands: list[SpanCandidate], workers, progress: Progress | None
) -> list[tuple[TileCoding, ...]]:
    """Per span, its tiles on attributes alone, coded as tile tasks on ``workers``: the check's rivals where
    it has side information to weigh, the tiles tuned where it has none (() where it was sent unchecked)."""
    wanted: list[list[TileJob]] = []
    for job, cand in zip(spans, cands):
        if cand.done is not None:
            wanted.append([])
        elif cand.side is None:
            wanted.append(_tuned_jobs(job))
        else:
            wanted.append(_rival_jobs(job, cand.codings, len(cand.side.payload) + CHUNK_ENTRY_BYTES))
    jobs = [t for w in wanted for t in w]
    coded = iter(_tasks(code_tile, jobs, _tile_name, workers, progress, "spans' rivals"))
    return [tuple(next(coded) for _ in w) for w in wanted]


def _tasks(fn, jobs: list, name, workers, progress: Progress | None, stage: str) -> list:
    """``fn`` of each of ``jobs`` as tasks on ``workers`` (gspc/workers.py run_tasks), in order; none where
    there are no jobs."""
    return list(run_tasks(fn, iter(jobs), workers, name, len(jobs), progress, stage)) if jobs else []


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


def _check_name(job: SpanCheckJob) -> str:
    return _span_name(job.span)


def _tile_name(job: TileJob) -> str:
    return f"tile {job.number}"
