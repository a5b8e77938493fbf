"""encode() and decode(): the stage lists. Every choice the encoder makes is in gspc/encoder/decisions.py,
every step the decoder takes in the modules called below.

encode:  read the scene -> the encoder's decisions (gspc/encoder/) -> pack the file -> write it
decode:  read the file once (gspc/format/file.py) -> decode the attributes -> render at the stored views
         -> restore (I~ (+) R~) -> refine -> PLY

Rendering, the check, restoration and refinement run on the options' device; the attribute codec runs on
the CPU (gspc/device.py), and its decoded scene is moved to the device where it is rendered.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from gspc.atomic import atomic_write, atomic_write_bytes
from gspc.cameras import Camera
from gspc.codec.attributes import DecodedSection, decode_section
from gspc.codec.precision import PrecisionMap
from gspc.codec.tiles import TileDecodeJob, decode_tile, file_tile_jobs
from gspc.device import check_device, renderer_info
from gspc.encoder.decisions import EncoderDecisions, decide, decide_tiled, file_bytes, is_tiled
from gspc.encoder.policy import SideInfoDecision
from gspc.errors import InputError
from gspc.format import container
from gspc.format.file import FileReader, GspcFile, byte_budget, file_chunks, read_file, tiled_file_chunks
from gspc.format.header import FileHeader
from gspc.format.side_chunk import SideViews
from gspc.io import read_scene, scene_writer
from gspc.io.camera_files import load_cameras
from gspc.io.ply import PlyRows, write_ply, write_ply_parts
from gspc.jit import compile_kernels, uncompiled_kernels
from gspc.limits import decode_worker_bytes, default_refine_iterations
from gspc.options import DecodeOptions, EncodeOptions, check_region
from gspc.paths import refuse_output_over_input
from gspc.progress import Progress
from gspc.reconstruct import check_decode_work, decode_work, reconstruct, refine_iterations
from gspc.restore.restorer import load_restorer
from gspc.scene import GaussianScene
from gspc.stages import Stages
from gspc.tile_reconstruct import (
    TileOutcome,
    TileReconstructJob,
    TileSideSettings,
    reconstruct_tile,
)
from gspc.workers import DriverReads, Executor, open_executor, run_tasks


@dataclass
class Report:
    """What a run did: bytes per part, seconds per stage and, for people, what it decided (``info``, one
    line per fact, which the command line prints)."""

    num_gaussians_in: int = 0
    num_gaussians_out: int = 0
    bytes: dict[str, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    info: dict[str, object] = field(default_factory=dict)
    num_views: int = 0  # side-information views stored (encode) or read (decode)
    num_views_with_residual: int = 0
    started: float = field(default_factory=time.perf_counter)  # a time budget counts from here
    decisions: EncoderDecisions | None = None  # the encoder's, as typed records
    refine_iterations: int = 0  # refinement iterations the decoder ran (0: none)

    @property
    def side_info(self) -> SideInfoDecision | None:
        """The encoder's side-information check, when it ran."""
        return self.decisions.check if self.decisions is not None else None

    def stages(self, progress: Progress | None, budget: float | None) -> Stages:
        """The run's stage clock, writing into this report's seconds."""
        return Stages(progress, budget, self.seconds, self.started)


def encode(
    scene_path: str | Path,
    out_path: str | Path,
    cameras_path: str | Path | None = None,
    opts: EncodeOptions | None = None,
    progress: Progress | None = None,
) -> Report:
    """Encode the scene file at ``scene_path`` (with the cameras at ``cameras_path``) into ``out_path``."""
    opts = opts or EncodeOptions()
    opts.validate()
    check_device(opts.device)
    refuse_output_over_input(out_path, scene_path, cameras_path)
    rep = Report()
    stages = rep.stages(progress, opts.time_budget)
    with stages.stage("read"):
        cameras = load_cameras(cameras_path) if cameras_path else None
        rows = large_ply(scene_path, opts)  # a scene larger than a tile is read by rows, tile by tile
        scene = read_scene(scene_path) if rows is None else None
    if rows is not None:
        data = encode_rows(rows, cameras, opts, progress, rep)
    else:
        data, rep = encode_scene(scene, cameras, opts, progress, rep)
    with stages.stage("write"):
        atomic_write_bytes(out_path, data, fsync=True)
    return rep


def large_ply(path: str | Path, opts: EncodeOptions) -> PlyRows | None:
    """The PLY at ``path`` as rows to read on demand, where it holds more Gaussians than one tile and its
    layout allows (little-endian float32 properties of one vertex element); else None: read it whole.
    On Ray its path is absolute (a worker's folder is not this one's); with ``ship_inputs`` this process
    reads each tile's rows for its task (gspc/workers.py DriverReads)."""
    if not str(path).lower().endswith(".ply"):
        return None
    try:
        rows = PlyRows(os.path.abspath(path) if opts.ray else path)
    except InputError:
        return None  # another layout: read_scene reads it, and names anything wrong with it
    if not is_tiled(rows.num_gaussians, opts):
        return None
    return DriverReads(rows) if opts.ship_inputs else rows


def encode_rows(
    rows,
    cameras: list[Camera] | None,
    opts: EncodeOptions,
    progress: Progress | None,
    rep: Report,
    executor: Executor | None = None,
) -> bytes:
    """The .gspc file of a scene larger than a tile read by rows (:func:`large_ply`), its tiles coded on
    ``executor`` (None: the options' own), reported in ``rep``."""
    stages = rep.stages(progress, opts.time_budget)

    def decide_fn() -> EncoderDecisions:
        return decide_tiled(rows, cameras, opts, stages, executor)

    return _encode_with(decide_fn, None, opts, progress, rep)


def encode_scene(
    scene: GaussianScene,
    cameras: list[Camera] | None = None,
    opts: EncodeOptions | None = None,
    progress: Progress | None = None,
    rep: Report | None = None,
    executor: Executor | None = None,
) -> tuple[bytes, Report]:
    """Encode a scene in memory: (the .gspc file's bytes, what was done). ``cameras`` None: synthesised.
    A scene larger than a tile is coded on ``executor`` (None: the options' workers or Ray), each tile's
    Gaussians sent with its task."""
    opts = opts or EncodeOptions()
    opts.validate()
    device = check_device(opts.device)
    rep = rep or Report()
    stages = rep.stages(progress, opts.time_budget)
    data = _encode_with(
        lambda: decide(scene, cameras, opts, stages, device, executor), scene, opts, progress, rep
    )
    return data, rep


def _encode_with(decide_fn, scene: GaussianScene | None, opts: EncodeOptions, progress, rep: Report) -> bytes:
    """The encoder's decisions (``decide_fn``), then the file they describe, reported in ``rep``."""
    device = check_device(opts.device)
    stages = rep.stages(progress, opts.time_budget)
    rep.info["renderer"] = renderer_info(device, progress, encoder=True)
    if uncompiled_kernels():  # a first run on this machine says why it waits
        with stages.stage("compile", announce=False):
            compile_kernels(progress, encoder=True)
    decisions = decide_fn()
    with stages.stage("write", announce=False):
        data = file_bytes(decisions, scene, opts)
    side = decisions.side
    if decisions.tiles:  # the chunks the file was packed from: it is not parsed again
        chunks = tiled_file_chunks([(t.tile, t.chunks) for t in decisions.tiles], None, decisions.tile_sides)
    else:
        chunks = file_chunks(decisions.attributes.chunks, side and side.payload)
    rep.bytes = byte_budget(len(data), chunks)
    rep.decisions = decisions
    rep.num_gaussians_in = decisions.counts.given
    rep.num_gaussians_out = decisions.counts.coded
    rep.num_views = len(side.records) if side is not None else 0
    rep.num_views_with_residual = side.views_with_residual if side is not None else 0
    rep.info.update(decisions.summary())
    return data


def decode(
    in_path: str | Path,
    out_path: str | Path,
    opts: DecodeOptions | None = None,
    progress: Progress | None = None,
) -> Report:
    """Decode the .gspc file at ``in_path`` into ``out_path``: a PLY, SPZ or glb, as its extension names."""
    opts = opts or DecodeOptions()
    opts.validate()
    check_device(opts.device)
    refuse_output_over_input(out_path, in_path)
    write = scene_writer(out_path)
    rep = Report()
    stages = rep.stages(progress, opts.time_budget)
    with stages.stage("read", announce=False):
        reader = FileReader(in_path)
    with reader:
        if reader.tiles is not None:  # read, decoded and written tile by tile
            _decode_tiles_to(reader, out_path, write, opts, stages, rep)
            return rep
    with stages.stage("read", announce=False):
        data = container.read_bytes(in_path)
    scene, rep = decode_bytes(data, opts, progress, rep)
    with stages.stage("write"):
        write(scene.to("cpu"), out_path)
    return rep


@dataclass(frozen=True)
class DecodedTile:
    """One tile of a tiled file, decoded: its number, box (spec 10.14) and Gaussians."""

    number: int
    box: tuple[float, ...]
    scene: GaussianScene


def decode_tiles(
    in_path: str | Path, region: tuple[float, ...] | None = None, workers: int | Executor = 1
) -> Iterator[DecodedTile]:
    """The tiles of the .gspc file at ``in_path`` that meet ``region`` (every tile for None), decoded one
    at a time in file order, on ``workers`` processes (or an executor: gspc/workers.py open_executor):
    memory follows the tiles, not the file. An untiled file is one tile, its box that of its Gaussians.
    The tiles' attributes as they decode: :func:`decode` also restores and refines the tiles that carry side
    information of their own (spec 10.15)."""
    region = check_region(region)
    with FileReader(in_path) as reader:
        if reader.tiles is None:
            scene = decode_bytes(container.read_bytes(in_path), DecodeOptions(refine=False))[0]
            m = scene.means.numpy()
            yield DecodedTile(0, tuple(float(x) for x in (*m.min(0), *m.max(0))), scene)
            return
        chosen = reader.tiles.meeting(region)
        for k, scene in _tile_scenes(reader, chosen, workers, None, None):
            yield DecodedTile(k, reader.tiles.tiles[k].box, scene)
        if region is None:
            reader.check_trailer()


def _tile_scenes(
    reader: FileReader,
    chosen: list[int],
    workers: int | Executor,
    progress: Progress | None,
    settings: TileSideSettings | None,
    log: list[TileOutcome] | None = None,
) -> Iterator[tuple[int, GaussianScene]]:
    """The ``chosen`` tiles decoded, numbered, in order, on ``workers`` (gspc/tile_reconstruct.py), each
    restored and refined with its own side information where ``settings`` are given (a tile of a span with
    the span's other tiles, which are decoded for it and not yielded unless chosen: spec 10.17): each job
    carries its tiles' chunks, read here. What each job did goes into ``log``."""
    total = sum(reader.tile_bytes())
    coordinates = reader.header.scene.coordinates if reader.header.scene else None
    tiles = reader.tiles.tiles
    lead = reader.tiles.span_of() if settings is not None else list(range(len(tiles)))
    leads = list(dict.fromkeys(lead[k] for k in chosen))
    wanted = set(chosen)

    def decoding(j: int) -> TileDecodeJob:
        return TileDecodeJob(j, reader.tile(j), tiles[j].section, tiles[j].box, total)

    def job(k: int) -> TileReconstructJob:
        side = reader.tile_side(k) if settings is not None else None
        drawn = tiles[k].drawn if side is not None else ()  # the tiles its views show (spec 10.15)
        members = range(k + 1, k + tiles[k].span) if side is not None else ()
        return TileReconstructJob(
            decoding(k),
            side,
            reader.tile_allowances[k],
            settings,
            tuple(decoding(j) for j in drawn),
            tuple(decoding(j) for j in members),
        )

    jobs = (job(k) for k in leads)
    stage = "tiles" if settings is None else "tiles with their side information"
    for done in run_tasks(reconstruct_tile, jobs, workers, _tile_name, len(leads), progress, stage):
        if log is not None:
            log.append(done.outcome)
        for k, scene in done.tiles:
            if k in wanted:
                scene.coordinates = coordinates
                yield k, scene


def _tile_name(job: TileReconstructJob) -> str:
    return f"tile {job.attributes.number}"


def _tile_settings(header: FileHeader, has_sides: bool, opts: DecodeOptions) -> TileSideSettings | None:
    """What each tile's reconstruction needs where a tile of the file carries side information (None: the
    tiles' attributes are decoded as they are)."""
    if not has_sides:
        return None
    side_info = header.side_info
    restorer = opts.restorer if opts.restorer is not None else side_info.restorer
    background = tuple(float(x) for x in side_info.background)
    return TileSideSettings(background, restorer, side_info.refine_iterations, opts)


def _refine_line(log: list[TileOutcome]) -> str:
    """The report's refine line of a tiled decode."""
    refined = [t.iterations for t in log if t.iterations > 0]
    if not refined:
        reasons = sorted({t.why_not or "" for t in log})
        return f"none (tiles: {'; '.join(reasons)})"
    drawn = sum(t.drawn for t in log)
    beside = f", {drawn:,} Gaussians of the tiles next to them drawn beside them" if drawn else ""
    spans = [t.tiles for t in log if t.iterations > 0 and t.tiles > 1]
    shared = f" ({len(spans)} spans of {min(spans)}-{max(spans)} tiles refined as one)" if spans else ""
    tiles = sum(t.tiles for t in log)
    return (
        f"{sum(t.tiles for t in log if t.iterations > 0)} of {tiles} tiles refined with their own side "
        f"information{shared}, {min(refined)}-{max(refined)} iterations{beside}"
    )


def _decode_tiles_to(
    reader: FileReader, out_path, write, opts: DecodeOptions, stages: Stages, rep: Report
) -> None:
    """Decode a tiled file's tiles that meet ``opts.region`` (all of them by default) into ``out_path``:
    a PLY is written tile by tile (memory follows the tiles); another format takes the scene whole. A
    decode of every tile checks the whole file's trailer before its output is in place; a tiled file's
    whole-scene side information is not used; each tile's own (spec 10.15) restores and refines that tile."""
    tiles = reader.tiles
    chosen = tiles.meeting(opts.region)
    if not chosen:
        raise InputError(f"--region meets none of the file's {len(tiles.tiles)} tiles; nothing to write")
    n = sum(tiles.tiles[k].n for k in chosen)
    spans = [sum(t.n for t in tiles.tiles[k : k + s.span]) for k, s in enumerate(tiles.tiles) if s.span > 1]
    executor = open_executor(opts.workers, opts.ray, decode_worker_bytes(max(spans, default=0)))
    with executor as ex, stages.stage("tiles", announce=False):
        rep.bytes = reader.budget
        rep.num_gaussians_in = rep.num_gaussians_out = n
        region = "" if opts.region is None else ", those meeting the region"
        rep.info["tiles"] = f"{len(chosen)} of {len(tiles.tiles)}{region}, decoded on {ex.describe()}"
        settings = _tile_settings(reader.header, reader.has_tile_sides, opts)
        log: list[TileOutcome] = []
        parts = (s for _, s in _tile_scenes(reader, chosen, ex, stages.progress, settings, log))
        if write is write_ply:

            def body(f) -> None:
                write_ply_parts(f, parts, n, tiles.sh_degree)
                if opts.region is None:
                    reader.check_trailer()

            atomic_write(out_path, body)
        else:
            scene = GaussianScene.concat(list(parts))
            if opts.region is None:
                reader.check_trailer()
            write(scene, out_path)
        rep.info["refine"] = _refine_line(log)
        rep.num_views = rep.info["views"] = len(reader.side.views) + sum(t.views for t in log)


def decode_bytes(
    data: bytes,
    opts: DecodeOptions | None = None,
    progress: Progress | None = None,
    rep: Report | None = None,
) -> tuple[GaussianScene, Report]:
    """Decode a .gspc file's bytes in memory: (the decoded, restored and refined scene, what was done)."""
    opts = opts or DecodeOptions()
    opts.validate()
    device = check_device(opts.device)
    rep = rep or Report()
    stages = rep.stages(progress, opts.time_budget)
    with stages.stage("read"):
        file = read_file(data)
    rep.bytes = file.budget
    if file.tiles is not None:
        return _decode_tiled_bytes(file, opts, stages, rep), rep
    with stages.stage("attributes"):
        decoded = _decode_attributes(file)
    scene = decoded.scene
    # The axes the encoder's input stated, for writers that convert to their format's (spec 10.8).
    scene.coordinates = coordinates = file.header.scene.coordinates if file.header.scene else None
    rep.num_gaussians_in = rep.num_gaussians_out = scene.num_gaussians
    side = file.side
    rep.num_views = rep.info["views"] = len(side.views)
    rep.num_views_with_residual = len(side.images)
    iterations = _refine_iterations(file, scene.num_gaussians, opts)
    reason = _no_refinement(side, opts, iterations)
    if reason is not None:
        rep.info["refine"] = reason
        return scene, rep
    rep.info["renderer"] = renderer_info(device, progress)
    if device.type == "cpu" and uncompiled_kernels():
        with stages.stage("compile", announce=False):
            compile_kernels(progress)
    # What rendering, restoring and refining ask for, bounded by the file's bytes before anything is
    # rendered (spec 10.8); the file's default length is bounded by what its work budget pays for.
    cams = [v.camera.to_camera() for v in side.views]
    work = decode_work(scene, cams, side.images, file.file_size)
    check_decode_work(work, file.file_size)
    if opts.iterations is None:
        iterations = refine_iterations(file.header.side_info.refine_iterations, work, file.file_size)
        if iterations == 0:
            rep.info["refine"] = "none (the file's work budget pays for no refinement, spec 10.8)"
            return scene, rep
    restorer_name = opts.restorer if opts.restorer is not None else file.header.side_info.restorer
    restorer = load_restorer(restorer_name, device=device)
    rep.info["restorer"] = restorer_name
    scene = _restore_and_refine(
        scene.to(device), file, restorer, iterations, opts, stages, rep, decoded.precision
    )
    scene.coordinates = coordinates
    return scene, rep


def _decode_attributes(file: GspcFile) -> DecodedSection:
    """The file's attributes: its one section, or every tile's in file order (spec 10.14)."""
    if file.tiles is None:
        return decode_section(file.attribute_chunks, file.header.attributes)
    parts = [decode_tile(job) for job in file_tile_jobs(file.tiles.tiles, file.tile_chunks)]
    return DecodedSection(GaussianScene.concat(parts), None)


def _decode_tiled_bytes(file: GspcFile, opts: DecodeOptions, stages: Stages, rep: Report) -> GaussianScene:
    """A tiled file in memory: every tile decoded in this process, and restored and refined with its own
    side information where it carries some (spec 10.15)."""
    has_sides = any(side is not None for side in file.tile_sides)
    settings = _tile_settings(file.header, has_sides, opts)
    jobs = file_tile_jobs(file.tiles.tiles, file.tile_chunks)
    lead = file.tiles.span_of() if has_sides else list(range(len(jobs)))
    log: list[TileOutcome] = []
    parts = []
    with stages.stage("tiles"):
        for k, t in enumerate(file.tiles.tiles):
            if lead[k] != k:  # refined with its span's first tile (spec 10.17)
                continue
            side = file.tile_sides[k] if has_sides else None
            drawn = t.drawn if side is not None else ()  # the tiles its views show (spec 10.15)
            members = range(k + 1, k + t.span) if side is not None else ()
            job = TileReconstructJob(
                jobs[k],
                side,
                file.tile_allowances[k],
                settings,
                tuple(jobs[j] for j in drawn),
                tuple(jobs[j] for j in members),
            )
            tile = reconstruct_tile(job)
            log.append(tile.outcome)
            parts.extend(s for _, s in tile.tiles)
    scene = GaussianScene.concat(parts)
    scene.coordinates = file.header.scene.coordinates if file.header.scene else None
    rep.num_gaussians_in = rep.num_gaussians_out = scene.num_gaussians
    rep.num_views = rep.info["views"] = len(file.side.views) + sum(t.views for t in log)
    rep.info["refine"] = _refine_line(log)
    return scene


def _refine_iterations(file: GspcFile, num_gaussians: int, opts: DecodeOptions) -> int:
    """``--iterations``, else the file's number bounded by the Gaussians it codes (gspc/limits.py); the
    work its bytes pay for bounds it further once the views are projected (decode_bytes, spec 10.8)."""
    if opts.iterations is not None:
        return opts.iterations
    return default_refine_iterations(file.header.side_info.refine_iterations, num_gaussians)


def _no_refinement(side: SideViews, opts: DecodeOptions, iterations: int) -> str | None:
    """Why the decoder takes the coded Gaussians as they are (None: it refines). Restoration only makes
    refinement's targets, so without refinement nothing is rendered or restored."""
    if not side.views:
        return "none (the file carries no side information)"
    if not opts.refine or iterations == 0:
        return "none (--no-refine)" if not opts.refine else "none (0 iterations)"
    if not (side.images and opts.restore):
        # With no residual anywhere every target equals the render: the gradients are only round-off, and
        # Adam would turn them into full-size steps (bench/refine.md), so nothing is refined.
        if not side.images:
            return "none (no view carries a residual)"
        return "none (--no-restore: the targets would be the renders themselves)"
    return None


def _restore_and_refine(
    scene: GaussianScene,
    file: GspcFile,
    restorer,
    iterations: int,
    opts: DecodeOptions,
    stages: Stages,
    rep: Report,
    precision: PrecisionMap | None,
) -> GaussianScene:
    """Render G~ at the stored views, restore them with their residuals and refine G~ against them."""
    header: FileHeader = file.header
    section = header.attributes if opts.in_cells else None
    background = header.side_info.background
    refined = reconstruct(
        scene,
        section,
        file.side.views,
        file.side.images,
        restorer,
        iterations,
        background,
        stages,
        opts.seed,
        opts.lr_scale,
        precision,
    )
    rep.refine_iterations = refined.iterations
    ran = f"{refined.iterations} iterations"
    if refined.iterations < iterations:
        ran += f" of {iterations} (time budget {opts.time_budget:g} s)"
    rep.info["refine"] = ran + ("" if opts.in_cells else ", cells off")
    return refined.scene
