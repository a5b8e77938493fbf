"""encode() and decode(): the stage lists. Every choice the encoder makes is in gspc/encoder/decisions.py,
every step the decoder takes in the modules called below.

encode:  read the scene -> the encoder's decisions (gspc/encoder/) -> pack the file -> write it
decode:  read the file once (gspc/format/file.py) -> decode the attributes -> render at the stored views
         -> restore (I~ (+) R~) -> refine -> PLY

Rendering, the check, restoration and refinement run on the options' device; the attribute codec runs on
the CPU (gspc/device.py), and its decoded scene is moved to the device where it is rendered.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from gspc.atomic import atomic_write_bytes
from gspc.cameras import Camera
from gspc.codec.attributes import decode_section
from gspc.codec.precision import PrecisionMap
from gspc.device import check_device, renderer_info
from gspc.encoder.decisions import EncoderDecisions, decide, file_bytes
from gspc.encoder.policy import SideInfoDecision
from gspc.format import container
from gspc.format.file import GspcFile, byte_budget, file_chunks, read_file
from gspc.format.header import FileHeader
from gspc.format.side_chunk import SideViews
from gspc.io import read_scene, scene_writer
from gspc.io.camera_files import load_cameras
from gspc.jit import compile_kernels, uncompiled_kernels
from gspc.limits import default_refine_iterations
from gspc.options import DecodeOptions, EncodeOptions
from gspc.paths import refuse_output_over_input
from gspc.progress import Progress
from gspc.reconstruct import refine_in_cells, render_images, restored_targets
from gspc.restore.restorer import load_restorer
from gspc.scene import GaussianScene
from gspc.stages import Stages


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
        scene = read_scene(scene_path)
        cameras = load_cameras(cameras_path) if cameras_path else None
    data, rep = encode_scene(scene, cameras, opts, progress, rep)
    with stages.stage("write"):
        atomic_write_bytes(out_path, data, fsync=True)
    return rep


def encode_scene(
    scene: GaussianScene,
    cameras: list[Camera] | None = None,
    opts: EncodeOptions | None = None,
    progress: Progress | None = None,
    rep: Report | None = None,
) -> tuple[bytes, Report]:
    """Encode a scene in memory: (the .gspc file's bytes, what was done). ``cameras`` None: synthesised."""
    opts = opts or EncodeOptions()
    opts.validate()
    device = check_device(opts.device)
    rep = rep or Report()
    stages = rep.stages(progress, opts.time_budget)
    rep.num_gaussians_in = scene.num_gaussians
    rep.info["renderer"] = renderer_info(device, progress, encoder=True)
    if uncompiled_kernels():  # a first run on this machine says why it waits
        with stages.stage("compile", announce=False):
            compile_kernels(progress, encoder=True)
    decisions = decide(scene, cameras, opts, stages, device)
    with stages.stage("write", announce=False):
        data = file_bytes(decisions, scene, opts)
    side = decisions.side
    rep.bytes = byte_budget(len(data), file_chunks(decisions.attributes.chunks, side and side.payload))
    rep.decisions = decisions
    rep.num_gaussians_out = decisions.counts.coded
    rep.num_views = len(side.records) if side is not None else 0
    rep.num_views_with_residual = side.views_with_residual if side is not None else 0
    rep.info.update(decisions.summary())
    return data, rep


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
        data = container.read_bytes(in_path)
    scene, rep = decode_bytes(data, opts, progress, rep)
    with stages.stage("write"):
        write(scene.to("cpu"), out_path)
    return rep


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
    with stages.stage("attributes"):
        decoded = decode_section(file.attribute_chunks, file.header.attributes)
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
    restorer_name = opts.restorer if opts.restorer is not None else file.header.side_info.restorer
    restorer = load_restorer(restorer_name, device=device)
    rep.info["restorer"] = restorer_name
    scene = _restore_and_refine(
        scene.to(device), file, restorer, iterations, opts, stages, rep, decoded.precision
    )
    scene.coordinates = coordinates
    return scene, rep


def _refine_iterations(file: GspcFile, num_gaussians: int, opts: DecodeOptions) -> int:
    """``--iterations``, else the file's number bounded by the Gaussians it codes (gspc/limits.py)."""
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
    background = header.side_info.background
    cams = [v.camera.to_camera() for v in file.side.views]
    with stages.stage("render", announce=False):
        degraded = render_images(scene, cams, background, stages.progress, "render coded")
    with stages.stage("restore", announce=False):
        targets = restored_targets(degraded, file.side.views, file.side.images, restorer, stages.progress)
    del degraded
    with stages.stage("refine", announce=False):
        refined = refine_in_cells(
            scene,
            header.attributes if opts.in_cells else None,
            cams,
            targets,
            iterations,
            background,
            stages.progress,
            seed=opts.seed,
            lr_scale=opts.lr_scale,
            deadline=stages.deadline,
            in_place=True,  # G~ is not needed after
            precision=precision,
        )
    rep.refine_iterations = refined.iterations
    ran = f"{refined.iterations} iterations"
    if refined.iterations < iterations:
        ran += f" of {iterations} (time budget {opts.time_budget:g} s)"
    rep.info["refine"] = ran + ("" if opts.in_cells else ", cells off")
    return refined.scene
