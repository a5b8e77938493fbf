"""encode() and decode(): the stage lists; the maths lives in the modules called here, the encoder's
side-information policy in gspc/encoder/policy.py.

encode:  scene -> attribute codec -> G~ (through the decoder's own path)
         cameras -> sampled views -> render G and G~ -> residuals -> image codec (JPEG XL) -> container
decode:  container -> G~ -> render at stored views -> restore (I~ (+) R~) -> refine -> PLY

Rendering, the check, restoration and refinement run on the options' device; the attribute codec runs on
the CPU (gspc/device.py), and its decoded scene is moved to the device where it is rendered.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from gspc import __version__
from gspc.atomic import atomic_write_bytes
from gspc.cameras import Camera
from gspc.codec.attributes import (
    EncodedAttributes,
    coded_with,
    decode_attributes,
    decoded_precision,
    search_lambda,
)
from gspc.codec.precision import PrecisionMap
from gspc.device import check_device, renderer_info, synchronize
from gspc.encoder.policy import CheckInputs, Outcome, SideInfoDecision, check_cameras, check_side_info
from gspc.encoder.prepare import (
    CodedAttributes,
    code_attributes,
    codec_params,
    encoder_cameras,
    iteration_counts,
    removal_params,
    sample_side_views,
    side_candidates,
    tuning_params,
)
from gspc.encoder.side import SideCandidate, view_residuals
from gspc.encoder.tuning import tune_coding
from gspc.errors import CodecError, InputError
from gspc.format import container
from gspc.format.attribute_section import attribute_chunks
from gspc.format.chunks import ATTRIBUTE_TYPES, SIDE
from gspc.format.header import FileHeader, SceneSummary, SideInfoHeader
from gspc.format.side_chunk import SideViews, read_side_views
from gspc.format.view_records import check_view_pixels
from gspc.io import read_scene, write_ply
from gspc.io.camera_files import load_cameras
from gspc.options import DecodeOptions, EncodeOptions
from gspc.paths import refuse_output_over_input
from gspc.progress import Progress
from gspc.reconstruct import (
    check_decode_work,
    decode_work,
    refine_in_cells,
    refine_iterations,
    render_images,
    restored_targets,
    work_bound,
)
from gspc.restore.restorer import load_restorer
from gspc.scene import GaussianScene


@dataclass
class Report:
    """What a run did: bytes per part and seconds per stage, for the CLI's summary table."""

    num_gaussians_in: int = 0
    num_gaussians_out: int = 0
    bytes: dict[str, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    # What the run decided, for people (the CLI prints it): the same facts as the typed fields below.
    info: dict[str, object] = field(default_factory=dict)
    num_views: int = 0  # side-information views stored (encode) or read (decode)
    num_views_with_residual: int = 0
    started: float = field(default_factory=time.perf_counter)  # a time budget counts from here
    side_info: SideInfoDecision | None = None  # the encoder's check, when it ran
    refine_iterations: int = 0  # refinement iterations the decoder ran (0: none)

    def timed(self, stage: str):
        return _Timer(self.seconds, stage)


@contextmanager
def _stage(rep: Report, progress: Progress | None, name: str):
    """A timed stage of one step, reported as opened and closed (for progress lines in logs)."""
    if progress:
        progress(name, 0, 1)
    with rep.timed(name):
        yield
    if progress:
        progress(name, 1, 1)


class _Timer:
    def __init__(self, sink: dict[str, float], stage: str):
        self.sink, self.stage = sink, stage

    def __enter__(self):
        synchronize()  # on a GPU, a stage's seconds are its own work, not what was queued before it
        self.t0 = time.perf_counter()

    def __exit__(self, *exc):
        synchronize()
        self.sink[self.stage] = self.sink.get(self.stage, 0.0) + time.perf_counter() - self.t0


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
    with _stage(rep, progress, "read"):
        scene = read_scene(scene_path)
        cameras = load_cameras(cameras_path) if cameras_path else None
    data, rep = encode_scene(scene, cameras, opts, progress, rep)
    with _stage(rep, progress, "write"):
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
    rep.num_gaussians_in = scene.num_gaussians
    rep.info["renderer"] = renderer_info(device, progress, encoder=True)
    cameras = encoder_cameras(scene, cameras, opts)
    restorer = load_restorer(opts.restorer, device=device)  # fails early on a name the package lacks
    removal = removal_params(opts)
    with _stage(rep, progress, "attributes"):
        coded_attributes = code_attributes(
            scene,
            cameras,
            codec_params(opts),
            opts.target_size,
            opts.background,
            progress,
            removal,
            _deadline(opts, rep),
        )
    if coded_attributes.removal is not None:
        rep.info["removal"] = coded_attributes.removal.summary()
    choice = _side_information(scene, cameras, coded_attributes, restorer, opts, device, progress, rep)
    if choice.side is None:  # a file the decoder does not refine: its coded values are tuned
        choice.attributes = _tuned(scene, choice.attributes, coded_attributes, cameras, opts, progress, rep)
    if opts.target_size is not None:  # what the search reached, so a missed target is visible
        enc = choice.attributes
        reached = f"attributes {enc.num_bytes:,} B for a {opts.target_size:,} B target"
        rep.info["lambda"] = f"{enc.lam:.4g} ({reached})"
    rep.num_gaussians_out = choice.attributes.decoded.num_gaussians
    with rep.timed("write"):
        data = _file_bytes(scene, choice, opts)
    rep.bytes = _byte_budget(data)
    rep.num_views = len(choice.side.records) if choice.side is not None else 0
    rep.num_views_with_residual = choice.side.views_with_residual if choice.side is not None else 0
    rep.info["views"] = rep.num_views
    rep.info["views with residual"] = rep.num_views_with_residual
    return data, rep


@dataclass
class _EncoderChoice:
    """What the encoder sends: the attributes, the side information (None: none) and the refinement
    iterations it names."""

    attributes: EncodedAttributes
    side: SideCandidate | None
    refine_iterations: int


def _side_information(
    scene: GaussianScene,
    cameras: list[Camera],
    coded_attributes: CodedAttributes,
    restorer,
    opts: EncodeOptions,
    device,
    progress: Progress | None,
    rep: Report,
) -> _EncoderChoice:
    """Render the sampled views, code their residuals and, where the check runs, keep the side information
    only if it pays for its bytes (gspc/encoder/policy.py)."""
    enc = coded_attributes.encoded
    runs = iteration_counts(opts, enc.decoded.num_gaussians)
    deadline = _deadline(opts, rep)
    view_indices, view_cams = sample_side_views(cameras, opts)
    if not view_indices:
        return _EncoderChoice(_unrefined(scene, coded_attributes, progress, rep, deadline), None, runs.refine)
    with rep.timed("render"):
        bg = opts.background
        # The residuals go into the file: rendered by the file's renderer rules (spec 10.12), which the
        # torch renderer follows on every device and gsplat 1.5 does not (gspc/render/gsplat_backend.py)
        original = render_images(scene.to(device), view_cams, bg, progress, "render original", "torch")
        coded = render_images(enc.decoded.to(device), view_cams, bg, progress, "render coded", "torch")
    with _stage(rep, progress, "side info"):
        candidates = side_candidates(opts, view_cams, view_residuals(original, coded), runs.check)
    # No residual anywhere: no chunk at all (cameras alone would be dead weight).
    side = candidates[0] if candidates[0].payload is not None else None
    if side is None:
        return _EncoderChoice(_unrefined(scene, coded_attributes, progress, rep, deadline), None, runs.refine)
    # No more iterations than a decode of a file of at least these payloads runs (gspc/limits.py).
    least = enc.num_bytes + min(len(c.payload) for c in candidates if c.payload is not None)
    bound = work_bound(enc.decoded, view_cams, side.images, least)
    runs = iteration_counts(opts, enc.decoded.num_gaussians, bound)
    if runs.check == 0:
        return _EncoderChoice(enc, side, runs.refine)
    inputs = CheckInputs(
        scene=scene,
        attributes=enc,
        params=coded_attributes.params.unrefined(),
        visible=coded_attributes.visible,
        significance=coded_attributes.significance,
        view_cameras=view_cams,
        check_cameras=check_cameras(cameras, view_indices, opts.check_views),
        original=original,
        coded=coded,
        candidates=candidates,
        restorer=restorer,
        iterations=runs.refine,
        background=opts.background,
        margin_db=opts.check_margin_db,
        device=device,
        deadline=deadline,
    )
    with _stage(rep, progress, "check"):
        result = check_side_info(inputs, progress)
    rep.side_info = result.decision
    rep.info.update(result.decision.summary())
    # The decoder runs what the check ran (a time budget may cut it).
    iterations = result.decision.iterations if result.side is not None else runs.refine
    attributes = result.attributes
    if result.decision.outcome is Outcome.DROPPED:
        attributes = _unrefined(scene, coded_attributes, progress, rep, deadline)
    return _EncoderChoice(attributes, result.side, iterations)


def _deadline(opts: EncodeOptions | DecodeOptions, rep: Report) -> float | None:
    """The ``time.perf_counter()`` by which the command should end (``--time-budget``), or None."""
    return None if opts.time_budget is None else rep.started + opts.time_budget


def _tuned(
    scene: GaussianScene,
    enc: EncodedAttributes,
    coded: CodedAttributes,
    cameras: list[Camera],
    opts: EncodeOptions,
    progress: Progress | None,
    rep: Report,
) -> EncodedAttributes:
    """``enc`` (the preset's coding, the one for no side information, or the check's rival: all with
    ``coded``'s visibility and measure) with its values tuned as the options ask (gspc/encoder/tuning.py),
    within ``--target-size`` where given.

    Only files without side information are tuned: where the decoder refines against side information it
    moves the same values inside the same cells, and tuning before the check gained the bird 0.15 dB and lego
    0.27 dB end to end for 56 s and 14 s more encode, against +1.2 .. +3.2 dB codec alone at the low preset
    (bench/tuning.md)."""
    tuning = tuning_params(opts)
    if tuning is None:
        return enc
    unrefined = coded.params.unrefined()
    params = unrefined if coded_with(enc, unrefined) else coded.params
    with _stage(rep, progress, "tune"):
        tuned = tune_coding(
            scene,
            enc,
            params,
            cameras,
            opts.background,
            coded.visible,
            coded.significance,
            tuning,
            byte_limit=opts.target_size,
            deadline=_deadline(opts, rep),
            progress=progress,
        )
    rep.info["tuning"] = tuned.report.summary()
    return tuned.encoded


def _unrefined(
    scene: GaussianScene,
    coded: CodedAttributes,
    progress: Progress | None,
    rep: Report,
    deadline: float | None = None,
) -> EncodedAttributes:
    """The attributes of a file without side information, which the decoder does not refine: coded with
    the parameters for that (CodecParams.unrefined) in the bytes the refined coding takes. Past the
    ``deadline`` no search starts, and one it cuts short keeps the refined coding unless it found better."""
    enc = coded.encoded
    params = coded.params.unrefined().with_lambda(enc.lam)
    if coded_with(enc, params) or (deadline is not None and time.perf_counter() >= deadline):
        return enc  # the same steps (a fine rate, or the uniform codec), or no time left
    with _stage(rep, progress, "attributes for no side information"):
        found = search_lambda(
            scene,
            enc.num_bytes,
            params,
            visible=coded.visible,
            significance=coded.significance,
            rel_tol=0.005,
            deadline=deadline,
        )
    return found if found.num_bytes <= enc.num_bytes else enc


def _file_bytes(scene: GaussianScene, choice: _EncoderChoice, opts: EncodeOptions) -> bytes:
    """The .gspc file of the encoder's choice: header, attribute chunks and the SIDE chunk."""
    enc, side = choice.attributes, choice.side
    chunks = [container.Chunk(name, enc.chunks[name]) for name in ATTRIBUTE_TYPES if name in enc.chunks]
    iterations, work = choice.refine_iterations, None
    if side is not None:
        chunks.append(container.Chunk(SIDE, side.payload))  # all views in one chunk (spec 10.9)
        # Name no more iterations than a decode of this file runs (its payloads' bytes: a lower bound).
        work = decode_work(enc.decoded, [v.camera.to_camera() for v in side.records], side.images, None)
        iterations = refine_iterations(iterations, work, sum(len(c.payload) for c in chunks))
    file_header = FileHeader(
        encoder=f"gspc {__version__}",
        scene=SceneSummary(enc.decoded.num_gaussians, enc.decoded.sh_degree, scene.num_gaussians),
        attributes=enc.section,
        side_info=SideInfoHeader(opts.background, opts.restorer, iterations),
    )
    data = container.pack(file_header.to_dict(), chunks)
    # The decoder refuses views beyond its pixel and work budgets for this file size (gspc/limits.py):
    # refuse to make a file it would refuse.
    try:
        check_view_pixels(side.records if side is not None else [], len(data))
        if work is not None:
            check_decode_work(work, len(data))
    except CodecError as e:
        raise InputError(f"{e}; lower --max-side or --views-fraction") from None
    return data


def _byte_budget(data: bytes) -> dict[str, int]:
    d = container.describe(data)
    budget = {"file": int(d["file_size"])}
    budget.update({k: int(v) for k, v in d["bytes_per_type"].items()})
    budget["header+framing"] = budget["file"] - sum(v for k, v in budget.items() if k != "file")
    return budget


def decode(
    in_path: str | Path,
    out_path: str | Path,
    opts: DecodeOptions | None = None,
    progress: Progress | None = None,
) -> Report:
    """Decode the .gspc file at ``in_path`` into an INRIA PLY at ``out_path``."""
    opts = opts or DecodeOptions()
    opts.validate()
    check_device(opts.device)
    refuse_output_over_input(out_path, in_path)
    rep = Report()
    with rep.timed("read"):
        data = container.read_bytes(in_path)
    scene, rep = decode_bytes(data, opts, progress, rep)
    with _stage(rep, progress, "write"):
        write_ply(scene.to("cpu"), out_path)
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
    rep.info["renderer"] = renderer_info(device, progress)
    with _stage(rep, progress, "read"):
        file = _read(data)
        restorer_name = opts.restorer if opts.restorer is not None else file.header.side_info.restorer
        restorer = load_restorer(restorer_name, device=device) if opts.restore else None
    rep.bytes = _byte_budget(data)
    with _stage(rep, progress, "attributes"):
        scene = decode_attributes(file.attribute_chunks, file.header.attributes)
    rep.num_gaussians_in = rep.num_gaussians_out = scene.num_gaussians
    scene = scene.to(device)
    side = file.side
    cams = [v.camera.to_camera() for v in side.views]
    if cams and (opts.restore or opts.refine):
        precision = decoded_precision(file.attribute_chunks, file.header.attributes)
        scene = _restore_and_refine(
            scene, file.header, side, cams, restorer, opts, progress, rep, precision, len(data)
        )
    rep.info["restorer"] = restorer_name if opts.restore else "off"
    rep.num_views = rep.info["views"] = len(cams)
    rep.num_views_with_residual = len(side.images)
    return scene, rep


@dataclass(frozen=True)
class _ReadFile:
    """A .gspc file as read and checked: the typed header, the attribute payloads and the side views."""

    header: FileHeader
    attribute_chunks: dict[str, bytes]
    side: SideViews


def _read(data: bytes) -> _ReadFile:
    """Unpack and check everything a decode will use, before any camera is built or view rendered: the
    header's records, the views' pixels against the file's budget (gspc/limits.py) and each residual
    image's declared size."""
    c = container.unpack(data)
    header = FileHeader.from_dict(c.header)
    side = read_side_views(header.side_info.legacy_views, c.chunks, len(data))
    return _ReadFile(header, attribute_chunks(c.chunks), side)


def _restore_and_refine(
    scene: GaussianScene,
    header: FileHeader,
    side: SideViews,
    cams: list[Camera],
    restorer,
    opts: DecodeOptions,
    progress: Progress | None,
    rep: Report,
    precision: PrecisionMap | None,
    file_size: int,
) -> GaussianScene:
    """Render G~ at the stored views, restore them with their residuals and refine G~ against them."""
    background = header.side_info.background
    with rep.timed("render"):
        # What rendering, restoring and refining ask for, bounded by the file's bytes (gspc/limits.py).
        work = decode_work(scene, cams, side.images if restorer is not None else (), file_size)
        check_decode_work(work, file_size)
        degraded = render_images(scene, cams, background, progress, "render coded")
    with rep.timed("restore"):
        targets = restored_targets(degraded, side.views, side.images, restorer, progress)
    # With no residual anywhere every target equals the render: the gradients are only round-off, and
    # Adam would turn them into full-size steps (measured: 50.7 -> 41.7 dB on a statue), so skip.
    has_residual = bool(side.images) and opts.restore
    # The file's number is a default, bounded by its Gaussians and its bytes' work budget (gspc/limits.py).
    file_default = refine_iterations(header.side_info.refine_iterations, work, file_size)
    iterations = opts.iterations if opts.iterations is not None else file_default
    if not (opts.refine and iterations > 0):
        return scene
    if not has_residual:
        rep.info["refine"] = "skipped (no view carries a residual)"
        return scene
    deadline = _deadline(opts, rep)
    with rep.timed("refine"):
        refined = refine_in_cells(
            scene,
            header.attributes if opts.in_cells else None,
            cams,
            targets,
            iterations,
            background,
            progress,
            seed=opts.seed,
            lr_scale=opts.lr_scale,
            deadline=deadline,
            in_place=True,  # G~ is not needed after
            precision=precision,
        )
    rep.refine_iterations = refined.iterations
    ran = f"{refined.iterations} iterations"
    if refined.iterations < iterations:
        ran += f" of {iterations} (time budget {opts.time_budget:g} s)"
    rep.info["refine"] = ran + ("" if opts.in_cells else ", cells off")
    return refined.scene
