"""Spatial tiles: how the encoder splits a scene larger than one tile, and codes each tile on its own.

A tile is a run of the scene's Morton order on the scene's grid, cut where an octree cell ends: the cells
of more than ``tile_size`` Gaussians split into their eight children, and runs of consecutive small cells
join while they fit. Each tile is then coded alone, as a scene of its own on the scene's grid (so its voxels
are the scene's), with the whole method: what no camera sees pruned, its Gaussians measured at the cameras
that see it, its precision planned, its removal and position grid searched, its values tuned. A tile is a
task: a plain function of its rows and the run's settings to its chunks, run in this process or in a
worker's (gspc/workers.py), with the same bytes either way.

Each tile is measured, searched and tuned with its own Gaussians alone; its measure counts of each Gaussian
only what the other tiles leave in view (gspc/encoder/occlusion.py: every tile is first rendered alone to
where it turns opaque, at the scene's cameras and the views halfway between them), and its removal search
and its tuning score only the pixels where some of it is in front of them (bench/tiles.md, "What other tiles
hide"). Its fidelity search scores the tile whole, as the shares below were measured: with its pixels
masked too, the 1M district's preset landed further under its target (bench/tiles.md, "What other tiles
hide").

Asked for side information, a tile gets its own (spec 10.15), made and checked as a whole scene's is
(gspc/encoder/side_decision.py): views among the cameras that see it, residuals of its Gaussians rendered
alone or, asked (--tile-neighbours), with its neighbours' (the tiles whose boxes meet its own, drawn and
never refined; the original's, where the decoder draws them decoded: their coding errors show in the
decoder's renders and targets alike), sent only where its check finds that the decoder's refinement with
them beats the same bytes on the tile's attributes; a tile sent none has its values tuned.

Coded to a fidelity, a tile gets its share of the scene's error: a view's squared error is the sum of the
tiles' it shows, each scored over the whole image, so tiles coded to the target each left a scene of N tiles
in view about 10 log10 N dB under it (bench/tiles.md, "The low preset on tiles"). Each tile's target is
raised by the mean, over the cameras that see it, of 10 log10 of the tiles each of them sees.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np

from gspc.cameras import Camera
from gspc.codec import positions as pos
from gspc.device import check_device
from gspc.encoder.coding import EncodedAttributes, SharedGrid, prune_mask
from gspc.encoder.fidelity import FidelityParams, code_to_fidelity, tuned_to_fidelity
from gspc.encoder.occlusion import (
    DepthMaps,
    Occluders,
    Occlusion,
    OcclusionKnown,
    map_cell,
    opaque_depths,
    scene_views,
)
from gspc.encoder.params import CodecParams
from gspc.encoder.policy import SideInfoDecision, Tune
from gspc.encoder.prepare import CodedAttributes, code_attributes, measure_scene
from gspc.encoder.rate import coded_with
from gspc.encoder.removal import RemovalChoice, RemovalParams
from gspc.encoder.side_decision import SideChoice, side_cameras, side_information
from gspc.encoder.tuning import TuningParams, TuningReport, tune_coding
from gspc.format.tiles import Box, Tile
from gspc.limits import MAX_DRAWN_TILES
from gspc.options import EncodeOptions
from gspc.progress import Progress
from gspc.reconstruct import DecodeWork, decode_work
from gspc.render.work import drawn_beside
from gspc.restore.restorer import load_restorer
from gspc.scene import GaussianScene, with_drawn
from gspc.stages import Stages
from gspc.visibility import seeing_cameras
from gspc.workers import run_tasks


@dataclass(frozen=True)
class TilePlan:
    """The scene's tiles: its shared grid, and each tile's input Gaussians (indices, in curve order)."""

    shared: SharedGrid
    rows: tuple[np.ndarray, ...]


def plan_tiles(means: np.ndarray, log_scales: np.ndarray, precision: float, tile_size: int) -> TilePlan:
    """Tiles of at most ``tile_size`` Gaussians over the scene whose positions and log scales are given,
    on its grid at ``precision`` bits per axis (the rate's: the tiles are the same at every rate)."""
    means = np.asarray(means, np.float64)
    frame = pos.grid_frame(means)
    grid = frame.grid(precision)
    voxels = pos.voxelise(pos.grid_coordinates(means, grid), grid.lo, grid.step, grid.bits)
    codes = pos.morton_encode(voxels, grid.bits)
    order = np.argsort(codes, kind="stable")
    runs = _octree_runs(codes[order], grid.bits, tile_size)
    rows = tuple(order[a:b] for a, b in runs)
    return TilePlan(SharedGrid(frame, _inside_size(means, log_scales, frame)), rows)


def _inside_size(means: np.ndarray, log_scales: np.ndarray, frame: pos.GridFrame) -> float | None:
    """The median world size of the Gaussians the contraction leaves as they are (None: a bounded scene)."""
    if frame.contraction is None:
        return None
    c = frame.contraction
    u = np.sqrt(((means - np.asarray(c.centre)) ** 2).sum(1)) / c.radius
    inside = u <= pos.IDENTITY_RADIUS
    if not inside.any():
        return None
    return float(np.median(np.exp(np.median(np.asarray(log_scales, np.float64)[inside], axis=1))))


def _octree_runs(codes: np.ndarray, bits: int, tile_size: int) -> list[tuple[int, int]]:
    """(start, end) runs of sorted Morton ``codes``: octree cells of at most ``tile_size`` codes (a cell of
    more splits into its children; one voxel of more is cut in pieces), consecutive cells joined while
    they fit."""
    cells: list[tuple[int, int]] = []
    stack = [(0, len(codes), 3 * bits)]  # (start, end, bits of the code below the cell's prefix)
    while stack:
        a, b, low = stack.pop()
        if b - a <= tile_size:
            cells.append((a, b))
        elif low == 0:  # one voxel holds more than a tile
            cells.extend((s, min(s + tile_size, b)) for s in range(a, b, tile_size))
        else:
            child = low - 3
            prefix = (int(codes[a]) >> low) << low
            bounds = [a, *np.searchsorted(codes[a:b], [prefix + (k << child) for k in range(1, 8)]) + a, b]
            # Pushed last child first, so cells come off the stack in curve order.
            for k in range(7, -1, -1):
                if bounds[k + 1] > bounds[k]:
                    stack.append((int(bounds[k]), int(bounds[k + 1]), child))
    runs: list[tuple[int, int]] = []
    for a, b in cells:
        if runs and b - runs[-1][0] <= tile_size:
            runs[-1] = (runs[-1][0], b)
        else:
            runs.append((a, b))
    return runs


class SceneRows:
    """A scene in memory read as a large one is (gspc/io/ply.py PlyRows): its positions and sizes whole,
    its Gaussians by rows."""

    def __init__(self, scene: GaussianScene) -> None:
        self.scene = scene.to("cpu")
        self.num_gaussians, self.sh_degree = scene.num_gaussians, scene.sh_degree
        self.coordinates = scene.coordinates

    def positions(self) -> np.ndarray:
        return self.scene.means.detach().numpy().astype(np.float64)

    def log_scales(self) -> np.ndarray:
        return self.scene.log_scales.detach().numpy().astype(np.float64)

    def rows(self, rows: np.ndarray) -> GaussianScene:
        return self.scene.subset(rows)

    def tile(self, rows: np.ndarray) -> tuple[GaussianScene, None]:
        """What a tile's job carries: its Gaussians themselves (a worker has no other way to them)."""
        return self.rows(rows), None


@dataclass(frozen=True)
class TileJob:
    """What coding one tile needs: its Gaussians (a scene, or a file's rows a worker reads itself), the
    run's cameras and settings; all plain data, so a worker process receives it whole."""

    number: int
    source: object  # the tile's GaussianScene, or a PlyRows whose ``rows`` are the tile
    rows: np.ndarray | None
    cameras: tuple[Camera, ...]
    params: CodecParams  # at the rate's lambda
    shared: SharedGrid
    background: tuple[float, float, float]
    removal: RemovalParams | None
    tuning: TuningParams | None
    byte_target: int | None = None  # code in at most this many bytes (None: at the rate)
    fidelity: FidelityParams | None = None  # code to this fidelity (gspc/encoder/fidelity.py; None: the rate)
    share_db: float = 0.0  # what the fidelity's target was raised by: the tile's share of the views' error
    side: EncodeOptions | None = None  # weigh side information of the tile's own with these options
    occlusion: Occlusion | None = None  # what the other tiles hide of it (gspc/encoder/occlusion.py)
    # The tiles its side information draws with it (spec 10.15), each as its source and rows are (rows
    # None: the source is the tile's scene).
    drawn: tuple[int, ...] = ()
    drawn_tiles: tuple[tuple[object, np.ndarray | None], ...] = ()


@dataclass(frozen=True)
class TileSide:
    """A tile's own side information (spec 10.15) as the encoder sent it, or why it sent none."""

    payload: bytes | None  # the TSID payload (None: none sent)
    reason: str  # the side-information step's line (gspc/encoder/side_decision.py)
    refine_iterations: int  # what the check ran, or the preset's
    work: DecodeWork | None  # what its views ask of a decoder, for the file's checks (spec 10.15)
    views_with_residual: int = 0
    check: SideInfoDecision | None = None


@dataclass(frozen=True)
class TileCoding:
    """One coded tile: its record in the tile index, its chunks and what its coding decided."""

    number: int
    tile: Tile
    chunks: dict[str, bytes]
    kept: np.ndarray  # the tile's input rows it codes, in decoded order
    lam: float
    num_bytes: int
    given: int
    candidates: int  # Gaussians some camera sees and at least 1/255 opaque
    removal: RemovalChoice | None
    tuning: TuningReport | None
    seconds: float
    # Where a fidelity search ran: the tile's PSNR at its views between the cameras less its share (what the
    # scene's views are at least, where every tile is; module docstring), and whether it reached
    # the target (a preset's size can stop it first).
    fidelity_db: float | None = None
    fidelity_reached: bool = True
    share_db: float = 0.0
    side: TileSide | None = None  # where side information was weighed
    occlusion: OcclusionKnown | None = None  # what its job knew of the other tiles


def code_tile(job: TileJob) -> TileCoding:
    """Code one tile with the whole method (the module's docstring): a task, the same bytes wherever it
    runs."""
    t0 = time.perf_counter()
    scene = job.source if job.rows is None else job.source.rows(job.rows)
    seen = seeing_cameras(scene.means.detach().numpy(), scene.log_scales.detach().numpy(), list(job.cameras))
    cams = [job.cameras[k] for k in seen] or list(job.cameras)
    measure = measure_scene(scene, cams, job.params, job.background, occlusion=job.occlusion)
    removal = job.removal if len(cams) > 1 else None  # scoring views lie between two cameras
    coded = code_attributes(
        scene, cams, job.params, job.byte_target, job.background, None, removal, None, measure, job.shared
    )
    fidelity = None
    if job.fidelity is not None:  # the tile's fewest bytes that reach the fidelity, its choices kept
        fidelity = code_to_fidelity(
            scene,
            coded.params,
            coded.visible,
            coded.significance,
            cams,
            job.background,
            job.fidelity,
            job.removal or RemovalParams(),
            grid=job.shared,
        )
        coded = replace(
            coded, encoded=fidelity.encoded, params=coded.params.with_lambda(fidelity.encoded.lam)
        )

    def tune(
        enc: EncodedAttributes, limit: int | None = job.byte_target
    ) -> tuple[EncodedAttributes, TuningReport | None]:
        if job.tuning is None:
            return enc, None
        tuned = tune_coding(
            scene,
            enc,
            params_for(enc),
            cams,
            job.background,
            coded.visible,
            coded.significance,
            job.tuning,
            byte_limit=limit,
            grid=job.shared,
            occlusion=job.occlusion,
        )
        return tuned.encoded, tuned.report

    def params_for(enc: EncodedAttributes) -> CodecParams:
        unrefined = coded.params.unrefined()  # the check's rival is coded for no refinement
        return unrefined if coded_with(enc, unrefined) else coded.params

    side, drawn = None, None
    if job.side is not None and len(cams) > 1:  # the tile's own side information, checked (spec 10.15)
        drawn = _drawn(job, cams)
        side = _tile_side(scene, cams, coded, job, tune, drawn)  # on the scene's grid, which its codings keep
        # Coded to a fidelity, a tile sent none keeps the coding that reached it (tuned below): the same bytes
        # coded for no refinement can fall far under the target at the coarse rates tiles take.
        if side.side is not None or job.fidelity is None:
            coded = replace(coded, encoded=side.attributes)

    def search(target_db: float, lam: float) -> EncodedAttributes:
        lower = replace(job.fidelity, target_db=target_db)
        params = coded.params.with_lambda(lam)
        rp = job.removal or RemovalParams()
        return code_to_fidelity(
            scene,
            params,
            coded.visible,
            coded.significance,
            cams,
            job.background,
            lower,
            rp,
            grid=job.shared,
        ).encoded

    fidelity_db = None
    if side is not None and side.side is not None:  # the decoder refines it: not tuned
        enc, tuning = coded.encoded, None
        if fidelity is not None:
            fidelity_db = fidelity.score(enc)
    elif fidelity is not None:  # tuned, and brought back near the target
        enc, tuning, fidelity_db = tuned_to_fidelity(
            coded.encoded, fidelity, job.fidelity.tolerance_db, tune, search
        )
    elif side is not None and side.tuning is not None:  # the check's tuned rival won: tuned already
        enc, tuning = coded.encoded, side.tuning
    else:
        enc, tuning = tune(coded.encoded)
    candidates = int(prune_mask(scene, coded.params, coded.visible).sum())
    removal_choice = coded.removal if coded.removal is not None and coded.removal.base is not None else None
    sent = side is not None and side.side is not None
    return TileCoding(
        job.number,
        Tile(_box(enc), enc.section, job.drawn if sent else ()),
        enc.chunks,
        enc.kept,
        enc.lam,
        enc.num_bytes,
        scene.num_gaussians,
        candidates,
        removal_choice,
        tuning,
        time.perf_counter() - t0,
        None if fidelity_db is None else fidelity_db - job.share_db,
        fidelity is None or fidelity.reached,
        job.share_db,
        None if side is None else _sent_side(side, enc, drawn),
        None if job.occlusion is None else job.occlusion.known(),
    )


def _drawn(job: TileJob, cams: list[Camera]) -> GaussianScene | None:
    """The original Gaussians of the tiles drawn with this one that the side-information step's cameras
    see, each tile read and culled in turn (None: none)."""
    seen = side_cameras(cams, job.side) if job.drawn_tiles else []
    if not seen:
        return None
    tiles = (source if rows is None else source.rows(rows) for source, rows in job.drawn_tiles)
    return drawn_beside(tiles, seen)


def _tile_side(
    scene: GaussianScene,
    cams: list[Camera],
    coded: CodedAttributes,
    job: TileJob,
    tune: Tune,
    drawn: GaussianScene | None,
) -> SideChoice:
    """The side-information step on the tile, its neighbours ``drawn`` beside it, on this process's CPU (a
    worker has no other device)."""
    opts = job.side
    device = check_device("cpu")
    restorer = load_restorer(opts.restorer, device=device)
    stages = Stages()
    at_fidelity = job.fidelity is not None
    return side_information(
        scene, cams, coded, restorer, opts, device, stages, job.byte_target, at_fidelity, tune, drawn
    )


def _sent_side(side: SideChoice, enc: EncodedAttributes, drawn: GaussianScene | None) -> TileSide:
    """What the file records of a tile's side-information step: its payload and the work its views ask
    (with its neighbours as the original has them; the file's check counts them decoded)."""
    if side.side is None:
        return TileSide(None, side.reason, side.refine_iterations, None, 0, side.check)
    cams = [v.camera.to_camera() for v in side.side.records]
    work = decode_work(with_drawn(enc.decoded, drawn), cams, side.side.images, None)
    views = side.side.views_with_residual
    return TileSide(side.side.payload, side.reason, side.refine_iterations, work, views, side.check)


def _box(enc: EncodedAttributes) -> Box:
    """The box of a coding's decoded positions (the decoder checks every one lies in it: spec 10.14)."""
    m = enc.decoded.means.numpy()
    lo, hi = m.min(0), m.max(0)
    return tuple(float(x) for x in (*lo, *hi))  # type: ignore[return-value]


def retarget(codings: Sequence[TileCoding], target: int) -> list[int]:
    """Each tile's share of ``target`` attribute bytes, in proportion to what it codes at the rate."""
    total = sum(c.num_bytes for c in codings)
    return [max(1, int(c.num_bytes * target / total)) for c in codings]


@dataclass(frozen=True)
class TileSettings:
    """The run's settings every tile is coded with (the preset's, and the options' overrides)."""

    cameras: tuple[Camera, ...]
    params: CodecParams
    background: tuple[float, float, float]
    removal: RemovalParams | None
    tuning: TuningParams | None
    fidelity: FidelityParams | None = None
    side: EncodeOptions | None = None  # each tile weighs side information of its own (spec 10.15)
    neighbours: bool = False  # its views show the tiles next to it too (False: the tile alone)


# A tile's side information draws the tiles whose boxes come within this share of its box's diagonal of it:
# those that share a face, an edge or a corner with it on the grid (bench/tiles.md, "Neighbours drawn").
NEIGHBOUR_MARGIN = 0.05


def plan_neighbours(rows: Sequence[np.ndarray], positions: np.ndarray) -> list[tuple[int, ...]]:
    """Each tile's neighbours: the tiles whose boxes of positions meet its own grown by NEIGHBOUR_MARGIN,
    nearest first, at most MAX_DRAWN_TILES."""
    boxes = np.array([[*positions[r].min(0), *positions[r].max(0)] for r in rows])
    out = []
    for k, b in enumerate(boxes):
        gaps = np.maximum(0.0, np.maximum(boxes[:, :3] - b[3:], b[:3] - boxes[:, 3:]))
        distance = np.linalg.norm(gaps, axis=1)
        distance[k] = np.inf
        near = distance <= NEIGHBOUR_MARGIN * np.linalg.norm(b[3:] - b[:3])
        order = [int(j) for j in np.argsort(distance, kind="stable") if near[j]]
        out.append(tuple(sorted(order[:MAX_DRAWN_TILES])))
    return out


@dataclass(frozen=True)
class TilesAtRate:
    """A run's tiles, what their jobs need, and each one's coding at the rate: kept so that a byte target
    the file's framing missed codes only the tiles in their new shares again."""

    plan: TilePlan
    shares: np.ndarray  # each tile's share of the views' error (dB; zeros without a fidelity)
    drawn: tuple[tuple[int, ...], ...]  # each tile's neighbours, drawn with its side information
    occluders: Occluders | None
    codings: tuple[TileCoding, ...]


def code_tiles(
    source,
    settings: TileSettings,
    tile_size: int,
    workers: int,
    byte_target: int | None = None,
    progress: Progress | None = None,
    at_rate: TilesAtRate | None = None,
) -> tuple[TilePlan, list[TileCoding], TilesAtRate]:
    """The tiles of ``source`` (gspc/io/ply.py PlyRows, or :class:`SceneRows`) and each one's coding, on
    ``workers`` processes. With ``byte_target``, the tiles' attribute bytes in all are brought under it:
    each tile gets its share, in proportion to what it codes at the rate, and is coded again in it.
    ``at_rate``: an earlier call's tiles and codings at the rate, which this one does not make again."""
    if at_rate is None:
        positions, log_scales = source.positions(), source.log_scales()
        plan = plan_tiles(positions, log_scales, settings.params.position_precision, tile_size)
        shares = np.zeros(len(plan.rows))
        if settings.fidelity is not None:
            shares = error_shares(plan.rows, positions, log_scales, list(settings.cameras))
        drawn: list[tuple[int, ...]] = [() for _ in plan.rows]
        if settings.side is not None and settings.neighbours:
            drawn = plan_neighbours(plan.rows, positions)
        del positions, log_scales
        occluders = None
        if len(plan.rows) > 1:
            occluders = opaque_scene(source, plan, settings.cameras, workers, progress)
        at_rate = TilesAtRate(plan, shares, tuple(drawn), occluders, ())
    plan = at_rate.plan

    def run(targets: list[int] | None, stage: str) -> list[TileCoding]:
        jobs = tile_jobs(source, settings, at_rate, targets)
        return list(run_tasks(code_tile, jobs, workers, _job_name, len(plan.rows), progress, stage))

    if not at_rate.codings:
        at_rate = replace(at_rate, codings=tuple(run(None, "tiles")))
    codings = list(at_rate.codings)
    if byte_target is not None:
        codings = run(retarget(codings, byte_target), "tiles in the target")
    return plan, codings, at_rate


def tile_jobs(
    source, settings: TileSettings, at_rate: TilesAtRate, targets: list[int] | None = None
) -> Iterator[TileJob]:
    """Each tile's coding job, in order: at the rate (or its fidelity), or in ``targets`` bytes."""
    plan, shares, drawn, occluders = at_rate.plan, at_rate.shares, at_rate.drawn, at_rate.occluders
    for k, rows in enumerate(plan.rows):
        src, own = source.tile(rows)
        yield TileJob(
            k,
            src,
            own,
            settings.cameras,
            settings.params,
            plan.shared,
            settings.background,
            settings.removal,
            settings.tuning,
            None if targets is None else targets[k],
            _raised(settings.fidelity, shares[k]) if targets is None else None,
            float(shares[k]),
            settings.side,
            None if occluders is None else occluders.others(k),
            drawn[k],
            tuple(source.tile(plan.rows[j]) for j in drawn[k]),
        )


@dataclass(frozen=True)
class TileDepthJob:
    """Rendering one tile alone to where it turns opaque (gspc/encoder/occlusion.py): a task, as a tile's
    coding is."""

    number: int
    source: object
    rows: np.ndarray | None
    cameras: tuple[Camera, ...]
    cell: int


def tile_depths(job: TileDepthJob) -> DepthMaps:
    scene = job.source if job.rows is None else job.source.rows(job.rows)
    return opaque_depths(scene, job.cameras, job.cell)


def opaque_scene(
    source, plan: TilePlan, cameras: Sequence[Camera], workers: int, progress: Progress | None = None
) -> Occluders:
    """The scene's opaque depths at ``cameras`` and the views between them, folded from each tile's on
    ``workers`` processes."""
    views = scene_views(cameras)
    cell = map_cell(views)
    occluders = Occluders(views, cell)

    def jobs():
        for k, rows in enumerate(plan.rows):
            src, own = source.tile(rows)
            yield TileDepthJob(k, src, own, views, cell)

    depths = run_tasks(tile_depths, jobs(), workers, _job_name, len(plan.rows), progress, "tiles' depths")
    for k, d in enumerate(depths):
        occluders.fold(k, d)
    return occluders


def error_shares(
    rows: Sequence[np.ndarray], positions: np.ndarray, log_scales: np.ndarray, cameras: list[Camera]
) -> np.ndarray:
    """Per tile, the dB its fidelity target is raised by: the mean over the cameras that see it of 10 log10
    of how many tiles each of them sees (module docstring)."""
    seen = [seeing_cameras(positions[r], log_scales[r], cameras) for r in rows]
    tiles_in_view = np.zeros(len(cameras))
    for s in seen:
        tiles_in_view[s] += 1
    return np.array([float(np.mean(10 * np.log10(tiles_in_view[s]))) if s else 0.0 for s in seen])


def _raised(fp: FidelityParams | None, db: float) -> FidelityParams | None:
    return None if fp is None else replace(fp, target_db=fp.target_db + db)


def _job_name(job: TileJob | TileDepthJob) -> str:
    return f"tile {job.number}"
