"""Encoding many scenes in one run (``gspc encode A.ply B.ply -o OUT/``, ``gspc encode FOLDER -o OUT/``).

The scenes share one executor (gspc/workers.py): a scene no larger than a tile is one task, coded where a
worker runs it; a larger scene's tiles are tasks, planned and packed here. Each scene's file is written
here, atomically, as ``OUT/<name>.gspc``: a scene that fails leaves no file and one line naming it, and the
others go on. Every file holds the bytes a single-scene run writes for that scene.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from gspc.atomic import atomic_write_bytes
from gspc.cameras import Camera
from gspc.device import check_device
from gspc.errors import InputError
from gspc.io import read_scene
from gspc.io.camera_files import load_cameras
from gspc.limits import encode_worker_bytes
from gspc.options import EncodeOptions
from gspc.paths import refuse_output_over_input
from gspc.pipeline import Report, encode_rows, encode_scene, large_ply
from gspc.progress import Progress
from gspc.scene import GaussianScene
from gspc.workers import TaskFailure, error_line, open_executor

# A scene folder (the INRIA layout's names, as the district scenes use): its Gaussians, and its cameras.
SCENE_FILE = "point_cloud.ply"
CAMERAS_FILE = "cameras.json"
SOG_META = "meta.json"  # a SOG scene written as a folder is one scene
SCENE_SUFFIXES = (".ply", ".spz", ".sog")


@dataclass(frozen=True)
class BatchScene:
    """One scene of a batch: its name (its file's, or its folder's), file and cameras (None: synthesised)."""

    name: str
    path: Path
    cameras: Path | None = None


@dataclass(frozen=True)
class SceneResult:
    """What became of one scene: its file's bytes (None: it failed, ``error`` says why)."""

    name: str
    output: Path
    bytes: int | None
    given: int = 0
    coded: int = 0
    seconds: float = 0.0
    error: str | None = None


def is_batch(paths: list[Path]) -> bool:
    """Whether ``gspc encode PATHS`` is a batch: several inputs, or a folder that is not one SOG scene."""
    return len(paths) > 1 or (paths[0].is_dir() and not (paths[0] / SOG_META).is_file())


def _is_scene_folder(path: Path) -> bool:
    return (path / SCENE_FILE).is_file() or (path / SOG_META).is_file()


def _folder_scene(path: Path) -> BatchScene:
    if not (path / SCENE_FILE).is_file():
        return BatchScene(path.name, path)  # a SOG folder
    cams = path / CAMERAS_FILE
    return BatchScene(path.name, path / SCENE_FILE, cams if cams.is_file() else None)


def find_scenes(paths: list[Path]) -> list[BatchScene]:
    """The scenes ``paths`` name: a file is a scene (no cameras); a scene folder (point_cloud.ply, and
    cameras.json where it has them; or a SOG folder) is one; another folder holds scenes: its scene
    folders and scene files, by name. InputError for a folder that holds none, or two scenes of one name
    (their files would collide)."""
    scenes: list[BatchScene] = []
    for p in paths:
        if not p.is_dir():
            scenes.append(BatchScene(p.stem, p))
        elif _is_scene_folder(p):
            scenes.append(_folder_scene(p))
        else:
            found = [
                _folder_scene(c) if c.is_dir() else BatchScene(c.stem, c)
                for c in sorted(p.iterdir())
                if _is_scene_folder(c) or (c.is_file() and c.suffix.lower() in SCENE_SUFFIXES)
            ]
            if not found:
                raise InputError(
                    f"{p}: holds no scene (scene files, or folders holding {SCENE_FILE} or a SOG {SOG_META})"
                )
            scenes += found
    seen: dict[str, Path] = {}
    for s in scenes:
        if s.name in seen:
            raise InputError(
                f"two scenes named {s.name} ({seen[s.name]} and {s.path}): their files would collide"
            )
        seen[s.name] = s.path
    return scenes


def check_output_folder(path: str | Path) -> Path:
    """The batch's output folder, made where missing; InputError where the path names something else."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: a batch writes one file per scene; -o must name a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"{out}: cannot make the output folder ({e.strerror})") from None
    return out


@dataclass(frozen=True)
class SceneJob:
    """An untiled scene's task: its file (the worker reads it) or its Gaussians (``--ship-inputs``), its
    cameras and the options, on one worker."""

    name: str
    path: str
    scene: GaussianScene | None
    cameras: tuple[Camera, ...] | None
    opts: EncodeOptions


@dataclass(frozen=True)
class SceneCoded:
    data: bytes
    given: int
    coded: int
    seconds: float


def encode_scene_task(job: SceneJob) -> SceneCoded:
    """One scene's file, as a single-scene run codes it (a task: gspc/workers.py)."""
    t0 = time.perf_counter()
    scene = job.scene if job.scene is not None else read_scene(job.path)
    cameras = list(job.cameras) if job.cameras is not None else None
    data, rep = encode_scene(scene, cameras, job.opts)
    return SceneCoded(data, rep.num_gaussians_in, rep.num_gaussians_out, time.perf_counter() - t0)


def encode_batch(
    scenes: list[BatchScene],
    out_dir: str | Path,
    opts: EncodeOptions,
    progress: Progress | None = None,
    done: Callable[[SceneResult], None] | None = None,
) -> list[SceneResult]:
    """Encode ``scenes`` into ``out_dir`` on one executor (the options' workers or Ray); each scene's
    result, in order (``done`` is called with each as it ends). Only bad options stop the batch."""
    opts.validate()
    check_device(opts.device)
    out = check_output_folder(out_dir)
    results: dict[str, SceneResult] = {}

    def finish(s: BatchScene, coded: SceneCoded | None, error: str | None) -> None:
        target = out / f"{s.name}.gspc"
        if coded is not None:
            try:
                atomic_write_bytes(target, coded.data, fsync=True)
            except Exception as e:
                coded, error = None, error_line(e)
        if coded is None:
            r = SceneResult(s.name, target, None, error=error)
        else:
            r = SceneResult(s.name, target, len(coded.data), coded.given, coded.coded, coded.seconds)
        results[s.name] = r
        if done:
            done(r)

    untiled, tiled = [], []
    for s in scenes:
        try:
            refuse_output_over_input(out / f"{s.name}.gspc", s.path, s.cameras)
            cameras = load_cameras(s.cameras) if s.cameras else None
            rows = large_ply(s.path, opts) if s.path.is_file() else None
        except Exception as e:
            finish(s, None, error_line(e))
            continue
        (untiled if rows is None else tiled).append((s, cameras, rows))

    one = replace(opts, workers=1, ray=None, ship_inputs=False)
    with open_executor(opts.workers, opts.ray, encode_worker_bytes(opts.span_size)) as ex:
        sent: list[BatchScene] = []

        def jobs() -> Iterator[SceneJob]:
            for s, cameras, _ in untiled:
                try:
                    scene = read_scene(s.path) if opts.ship_inputs else None
                except Exception as e:
                    finish(s, None, error_line(e))
                    continue
                sent.append(s)
                cams = tuple(cameras) if cameras is not None else None
                yield SceneJob(s.name, str(s.path.absolute()), scene, cams, one)

        runs = ex.map(encode_scene_task, jobs(), _job_name, len(untiled), progress, "scenes", keep_going=True)
        for k, r in enumerate(runs):
            if isinstance(r, TaskFailure):
                finish(sent[k], None, r.message)
            else:
                finish(sent[k], r, None)
        for s, cameras, rows in tiled:
            t0 = time.perf_counter()
            rep = Report()
            try:
                data = encode_rows(rows, cameras, opts, progress, rep, ex)
            except Exception as e:
                finish(s, None, error_line(e))
                continue
            seconds = time.perf_counter() - t0
            finish(s, SceneCoded(data, rep.num_gaussians_in, rep.num_gaussians_out, seconds), None)
    return [results[s.name] for s in scenes]


def _job_name(job: SceneJob) -> str:
    return job.name
