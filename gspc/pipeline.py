"""encode() and decode(): orchestration of the gspc stages; the maths lives in the modules called here.

encode:  scene -> attribute codec -> G~ (through the decoder's own path)
         cameras -> sampled views -> render G and G~ -> residuals -> JPEG XL -> container
decode:  container -> G~ -> render at stored views -> restore (I~ (+) R~) -> refine -> PLY
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from gspc import __version__, header
from gspc.atomic import atomic_write_bytes
from gspc.cameras import Camera, limit_size, load_cameras, sample_views, synthesize_views
from gspc.codec import container, residuals
from gspc.codec.attributes import (
    EncodedAttributes,
    attribute_chunks,
    decode_attributes,
    encode_attributes,
    search_lambda,
)
from gspc.codec.cells import quantisation_cells
from gspc.codec.sideinfo import pack_side, side_views
from gspc.errors import CodecError, DeviceError, InputError
from gspc.io import read_scene, write_ply
from gspc.metrics import psnr, quantize8
from gspc.options import check_decode_options, check_encode_options
from gspc.paths import refuse_output_over_input
from gspc.presets import DEFAULT_RESTORER, quality_preset
from gspc.progress import Progress
from gspc.refine import refine
from gspc.render import render
from gspc.restore.restorer import load_restorer
from gspc.scene import GaussianScene
from gspc.visibility import visible_mask

ATTRIBUTE_CHUNKS = ("POSN", "OPAC", "SCAL", "ROTN", "SHDC", "SHRS")
SIDE_CHUNK = "SIDE"  # all side-information views in one chunk (spec 10.9); 1.0's RESI form is still read
# Held-out PSNR gain after refinement per dB that the residuals add to their own views' renders (I~ + R~ over
# I~), measured with 1000 iterations inside the cells: lego fit lambda 8, 0.86 (residuals at 1/2 resolution)
# and 0.82 (1/4); donut lambda 64, 0.89 (1/4). The encoder predicts with it which resolution pays best.
REFINE_TRANSFER = 0.85
# The rival may fall this far under the side information's bytes: search_lambda's default 3% is worth 1.5 dB
# on a curve as steep as the donut's (5 dB per 10% of bytes), a handicap that would favour side information.
RIVAL_TOLERANCE = 0.005
CHUNK_ENTRY_BYTES = 48  # a chunk-table entry plus alignment padding, about (spec section 5)


@dataclass
class EncodeOptions:
    quality: str = "low"
    lam: float | None = None  # continuous rate knob; overrides the preset's
    target_size: int | None = None  # bytes for the attribute bitstream; searches lam
    views_fraction: float = 0.4
    synth_views: int = 60  # cameras synthesised when the input has none
    max_side: int = 400  # side-information views are rendered at most this large
    residual_codec: str | None = None  # overrides the preset's
    residual_distance: float | None = None  # overrides the preset's
    residual_scale: int | None = None  # overrides the preset's
    side_info: bool = True
    restorer: str = DEFAULT_RESTORER
    keep_invisible: bool = False
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # The encoder runs the decoder's refinement for this many iterations (None: the preset's) and keeps the
    # side information only if it beats, at views that carry none, the same bytes spent on attributes
    # (0: no check, keep it).
    check_iterations: int | None = None
    check_views: int = 8
    # Side information must beat its rivals by this much at the check views: a tie within the noise of
    # 8 sampled views lost 0.25 dB at 13 others on the lego fit (bench/pipeline_equal_bytes.md).
    check_margin_db: float = 0.15

    def validate(self) -> None:
        """InputError naming the first option out of range (gspc/options.py); called before any work."""
        check_encode_options(self)


@dataclass
class DecodeOptions:
    iterations: int | None = None  # None: what the encoder validated (header), else 300
    restore: bool = True
    refine: bool = True
    restorer: str | None = None  # None: the one the bitstream names
    device: str = "cpu"
    seed: int = 0
    lr_scale: float = 1.0  # multiplies every refinement learning rate
    # Keep refined attributes inside their quantisation cells (gspc/codec/cells.py).
    in_cells: bool = True

    def validate(self) -> None:
        """InputError naming the first option out of range (gspc/options.py); called before any work."""
        check_decode_options(self)


@dataclass
class Report:
    """What a run did: bytes per part and seconds per stage, for the CLI's summary table."""

    num_gaussians_in: int = 0
    num_gaussians_out: int = 0
    bytes: dict[str, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    info: dict[str, object] = field(default_factory=dict)

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
        self.t0 = time.perf_counter()

    def __exit__(self, *exc):
        self.sink[self.stage] = self.sink.get(self.stage, 0.0) + time.perf_counter() - self.t0


@torch.no_grad()
def render_images(
    scene: GaussianScene,
    cameras: list[Camera],
    background,
    progress: Progress | None = None,
    stage: str = "render",
) -> list[torch.Tensor]:
    """Clamped renders, one per camera (what a viewer displays)."""
    bg = torch.tensor(background, dtype=scene.means.dtype, device=scene.means.device)
    out = []
    if progress:
        progress(stage, 0, len(cameras))
    for i, cam in enumerate(cameras):
        out.append(render(scene, cam, background=bg).image.clamp(0, 1))
        if progress:
            progress(stage, i + 1, len(cameras))
    return out


def _codec_params(opts: EncodeOptions):
    params = quality_preset(opts.quality).attributes
    if opts.lam is not None:
        params = replace(params, lam=opts.lam)
    if opts.keep_invisible:
        params = replace(params, keep_invisible=True)
    return params


def encode(
    scene_path: str | Path,
    out_path: str | Path,
    cameras_path: str | Path | None = None,
    opts: EncodeOptions | None = None,
    progress: Progress | None = None,
) -> Report:
    opts = opts or EncodeOptions()
    opts.validate()
    refuse_output_over_input(out_path, scene_path, cameras_path)
    rep = Report()
    with _stage(rep, progress, "read"):
        scene = read_scene(scene_path)
        cameras = load_cameras(cameras_path) if cameras_path else synthesize_views(scene, opts.synth_views)
        cameras = limit_size(cameras, opts.max_side)
    rep.num_gaussians_in = scene.num_gaussians
    params = _codec_params(opts)
    restorer = load_restorer(opts.restorer)  # fails early on a name the package lacks

    with _stage(rep, progress, "attributes"):
        visible = visible_mask(scene.means.numpy(), scene.log_scales.numpy(), cameras)
        if opts.target_size is not None:
            enc = search_lambda(scene, opts.target_size, params, visible=visible)
        else:
            enc = encode_attributes(scene, params, visible=visible)
    rep.num_gaussians_out = enc.decoded.num_gaussians

    chunks = [container.Chunk(name, enc.chunks[name]) for name in ATTRIBUTE_CHUNKS if name in enc.chunks]
    views = sample_views(cameras, opts.views_fraction) if opts.side_info else []
    side: _Side | None = None  # the side information sent, if any
    preset_iterations = quality_preset(opts.quality).refine_iterations
    check_iterations = preset_iterations if opts.check_iterations is None else opts.check_iterations
    refine_iterations = check_iterations or preset_iterations  # unchecked files name the preset's
    if views:
        # Round-trip through the stored form so the encoder renders exactly the cameras the decoder reads.
        view_cams = [Camera.from_dict(cameras[i].to_dict()) for i in views]
        with rep.timed("render"):
            original = render_images(scene, view_cams, opts.background, progress, "render original")
            coded = render_images(enc.decoded, view_cams, opts.background, progress, "render coded")
        with _stage(rep, progress, "side info"):
            res = [(a - b).numpy().astype(np.float32) for a, b in zip(original, coded)]
            q = quality_preset(opts.quality)
            level = opts.residual_distance if opts.residual_distance is not None else q.residual_level
            codec = opts.residual_codec or q.residual_codec
            plan = residuals.plan_residual_rates(res, level)
            # The preset's resolution, and half of it as a cheaper candidate for the check to weigh.
            scales = [opts.residual_scale or q.residual_scale]
            if not opts.residual_scale and check_iterations > 0:
                scales.append(2 * q.residual_scale)
            candidates = [_side_info(view_cams, res, plan, codec, sc) for sc in scales]
        # No residual anywhere: no chunk at all (cameras alone would be dead weight).
        side = candidates[0] if candidates[0].payload is not None else None
        if side is not None and check_iterations > 0:
            with _stage(rep, progress, "check"):
                side, enc = _check_side_info(
                    scene,
                    enc,
                    params,
                    visible,
                    cameras,
                    views,
                    original,
                    coded,
                    candidates,
                    restorer,
                    refine_iterations,
                    opts,
                    progress,
                    rep,
                )
            chunks = [container.Chunk(n, enc.chunks[n]) for n in ATTRIBUTE_CHUNKS if n in enc.chunks]
            rep.num_gaussians_out = enc.decoded.num_gaussians
        if side is not None:
            chunks.append(container.Chunk(SIDE_CHUNK, side.payload))

    file_header = {
        "encoder": f"gspc {__version__}",
        "scene": {
            "num_gaussians": enc.decoded.num_gaussians,
            "sh_degree": enc.decoded.sh_degree,
            "source_gaussians": scene.num_gaussians,
        },
        "attributes": enc.meta,
        "side_info": {
            "background": list(opts.background),
            "restorer": opts.restorer,
            "refine_iterations": refine_iterations,
        },
    }
    with _stage(rep, progress, "write"):
        data = container.pack(file_header, chunks)
        # The decoder refuses views beyond its pixel budget for this file size (gspc/limits.py): refuse to
        # write a file it would refuse.
        try:
            header.check_view_sizes(side.records if side is not None else [], len(data))
        except CodecError as e:
            raise InputError(f"{e}; lower --max-side or --views-fraction") from None
        atomic_write_bytes(out_path, data, fsync=True)
    rep.bytes = _byte_budget(Path(out_path))
    stored = side.records if side is not None else []
    rep.info["views"] = len(stored)
    rep.info["views with residual"] = sum("residual" in v for v in stored)
    return rep


@dataclass
class _Side:
    """One candidate form of the side information: per-view records, residual images, the SIDE payload."""

    scale: int
    records: list[dict]
    images: dict[int, bytes]
    payload: bytes | None  # None: no view's residual was worth sending


def _side_info(view_cams: list[Camera], res: list[np.ndarray], plan: list, codec: str, scale: int) -> _Side:
    records, images = [], {}
    for k, (cam, r, d) in enumerate(zip(view_cams, res, plan)):
        record = {"camera": cam.to_dict()}
        if d is not None:
            images[k], record["residual"] = residuals.encode_residual(
                r, {"codec": codec, "level": d, "scale": scale}
            )
        records.append(record)
    return _Side(scale, records, images, pack_side(records, images) if images else None)


def _target_gain(original: list[torch.Tensor], coded: list[torch.Tensor], side: _Side) -> float:
    """Mean PSNR gain of I~ + R~ over I~ against I at the side-information views (0 where none is sent)."""
    gains = []
    for k, (ref, img, v) in enumerate(zip(original, coded, side.records)):
        if k not in side.images:
            gains.append(0.0)
            continue
        r = torch.from_numpy(residuals.decode_residual(side.images[k], v["residual"])).to(img)
        gains.append(_mean_psnr([(img + r).clamp(0, 1)], [ref]) - _mean_psnr([img], [ref]))
    return float(np.mean(gains))


def _check_side_info(
    scene,
    enc,
    params,
    visible,
    cameras,
    views,
    original,
    coded,
    candidates: list[_Side],
    restorer,
    iterations: int,
    opts: EncodeOptions,
    progress,
    rep: Report,
) -> tuple[_Side | None, EncodedAttributes]:
    """Run the decoder's refinement at views that carry no side information and keep the side information
    only if it beats the same bytes spent on attributes: (side information to send or None, attributes)."""
    sent = set(views)
    view_cams = [Camera.from_dict(cameras[i].to_dict()) for i in views]
    others = [c for i, c in enumerate(cameras) if i not in sent] or view_cams
    pick = np.linspace(0, len(others) - 1, min(opts.check_views, len(others))).round().astype(int)
    check_cams = [Camera.from_dict(others[i].to_dict()) for i in pick]
    reference = render_images(scene, check_cams, opts.background, progress, "check render original")

    def score(s: GaussianScene) -> float:
        return _mean_psnr(render_images(s, check_cams, opts.background), reference)

    def rival(candidate: _Side) -> tuple[EncodedAttributes, float]:
        """The fair rival: the same total bytes spent on attributes alone, and its PSNR."""
        extra = len(candidate.payload) + CHUNK_ENTRY_BYTES
        alt = search_lambda(scene, enc.num_bytes + extra, params, visible=visible, rel_tol=RIVAL_TOLERANCE)
        return alt, score(alt.decoded)

    before = score(enc.decoded)
    rivals = []
    for k, c in enumerate(candidates):
        if progress:
            progress("check rivals", k, len(candidates))
        rivals.append(rival(c))
    if progress:
        progress("check rivals", len(candidates), len(candidates))
    side, (alt, alt_psnr) = candidates[0], rivals[0]
    if len(candidates) > 1:
        # Predict each candidate's refined PSNR from how much its residuals improve the renders they were
        # sent for, and refine only the most promising one.
        gains = [_target_gain(original, coded, c) for c in candidates]
        margins = [REFINE_TRANSFER * g - max(0.0, r[1] - before) for g, r in zip(gains, rivals)]
        best = int(np.argmax(margins))
        side, (alt, alt_psnr) = candidates[best], rivals[best]
        rep.info["side info resolution"] = (
            "; ".join(
                f"1/{c.scale}: {len(c.payload):,} B, renders +{g:.2f} dB, same bytes on attributes "
                f"{r[1] - before:+.2f} dB"
                for c, g, r in zip(candidates, gains, rivals)
            )
            + f"; chose 1/{side.scale}"
        )
    targets = restored_targets(coded, side.records, side.images, restorer)
    # A run a tenth as long first: where refinement makes the coded scene worse, the long run is not worth
    # its minutes.
    short = _short_length(iterations)
    after = score(_refined(enc, view_cams, targets, short, opts, progress, "check refine (short)"))
    if after < before:
        rep.info["short check"] = f"{short} iterations: {after:.2f} dB, worse than coded"
    elif short < iterations:
        after = score(_refined(enc, view_cams, targets, iterations, opts, progress, "check refine"))
    rep.info["check"] = (
        f"at {len(check_cams)} unsent views: coded {before:.2f} dB, refined {after:.2f} dB, "
        f"same bytes on attributes {alt_psnr:.2f} dB"
    )
    if after >= max(before, alt_psnr) + opts.check_margin_db:
        return side, enc
    # Side information does not pay for its bytes: send none (the decoder will not refine), and spend the
    # bytes on attributes when that measured better.
    if alt_psnr > before:
        rep.info["side info"] = "spent on attributes instead (measured better at equal bytes)"
        return None, alt
    rep.info["side info"] = "dropped (refinement did not improve unsent views)"
    return None, enc


def restored_targets(
    degraded: list[torch.Tensor],
    views: list[dict],
    res_chunks: dict[int, bytes],
    restorer,
    progress: Progress | None = None,
):
    """The decoder's refinement targets: renders restored with their decoded residuals where one was sent."""
    out = []
    if progress:
        progress("restore", 0, len(degraded))
    for k, (img, v) in enumerate(zip(degraded, views)):
        if k in res_chunks and restorer is not None:
            r = torch.from_numpy(residuals.decode_residual(res_chunks[k], v["residual"])).to(img)
            img = restorer.restore(img, r)
        # A view without a residual keeps its render: the restorer alone measured no gain (bench/restorer.md).
        out.append(img.clamp(0, 1))
        if progress:
            progress("restore", k + 1, len(degraded))
    return out


def _mean_psnr(a: list[torch.Tensor], b: list[torch.Tensor]) -> float:
    return float(np.mean([float(psnr(quantize8(x), quantize8(y))) for x, y in zip(a, b)]))


def _refined(
    enc, view_cams, targets, iterations: int, opts: EncodeOptions, progress: Progress | None, stage: str
) -> GaussianScene:
    """The decoder's refinement as the encoder predicts it (same targets, iterations and cells)."""
    decoded = enc.decoded
    bg = torch.tensor(opts.background, dtype=decoded.means.dtype)
    cb = _refine_progress(progress, stage, iterations)
    return refine(
        decoded,
        view_cams,
        targets,
        iterations=iterations,
        background=bg,
        progress=cb,
        cells=quantisation_cells(decoded, enc.meta),
    )


def _refine_progress(progress: Progress | None, stage: str, iterations: int):
    """refine()'s per-iteration callback reporting to ``progress`` under ``stage`` (opened here)."""
    if progress is None:
        return None
    progress(stage, 0, iterations)
    return lambda i, loss: progress(stage, i + 1, iterations)


def _short_length(iterations: int) -> int:
    """The check's trial runs: a tenth of a long refinement, the whole of a short one."""
    return iterations // 10 if iterations >= 500 else iterations


def _byte_budget(path: Path) -> dict[str, int]:
    d = container.describe(path)
    budget = {"file": int(d["file_size"])}
    budget.update({k: int(v) for k, v in d["bytes_per_type"].items()})
    budget["header+framing"] = budget["file"] - sum(v for k, v in budget.items() if k != "file")
    return budget


def _check_device(device: str) -> torch.device:
    if device not in ("cpu", "cuda"):
        raise DeviceError(f"unknown device {device!r}; use cpu or cuda")
    if device == "cuda" and not torch.cuda.is_available():
        raise DeviceError("--device cuda was requested but no CUDA GPU is available")
    return torch.device(device)


def decode(
    in_path: str | Path,
    out_path: str | Path,
    opts: DecodeOptions | None = None,
    progress: Progress | None = None,
) -> Report:
    opts = opts or DecodeOptions()
    opts.validate()
    device = _check_device(opts.device)
    refuse_output_over_input(out_path, in_path)
    rep = Report()
    with _stage(rep, progress, "read"):
        c = container.read(in_path)
        fields = header.parse(c.header)
        attr_meta, side, background = fields.attributes, fields.side_info, fields.background
        chunks = attribute_chunks(c.chunks)
        views, res_chunks = side_views(side, c.chunks)
        # Sizes before any camera is built or view rendered: the file's pixel budget (gspc/limits.py).
        header.check_view_sizes(views, Path(in_path).stat().st_size)
        for k, image in res_chunks.items():  # each image's declared size, before anything is decoded
            cam = views[k]["camera"]
            residuals.check_residual(image, views[k].get("residual"), (cam["height"], cam["width"]))
        restorer_name = opts.restorer if opts.restorer is not None else fields.restorer
        restorer = load_restorer(restorer_name) if opts.restore else None
    rep.bytes = _byte_budget(Path(in_path))
    with _stage(rep, progress, "attributes"):
        scene = decode_attributes(chunks, attr_meta)
    rep.num_gaussians_in = rep.num_gaussians_out = scene.num_gaussians
    scene = scene.to(device)
    cams = [Camera.from_dict(v["camera"]) for v in views]

    if cams and (opts.restore or opts.refine):
        with rep.timed("render"):
            degraded = render_images(scene, cams, background, progress, "render coded")
        with rep.timed("restore"):
            targets = restored_targets(degraded, views, res_chunks, restorer, progress)
        # With no residual anywhere every target equals the render: the gradients are only round-off, and
        # Adam would turn them into full-size steps (measured: 50.7 -> 41.7 dB on a statue), so skip.
        has_residual = any("residual" in v for v in views) and opts.restore
        iterations = opts.iterations if opts.iterations is not None else fields.refine_iterations
        if opts.refine and iterations > 0 and not has_residual:
            rep.info["refine"] = "skipped (no view carries a residual)"
        if opts.refine and iterations > 0 and has_residual:
            rep.info["refine"] = f"{iterations} iterations" + ("" if opts.in_cells else ", cells off")
            with rep.timed("refine"):
                cb = _refine_progress(progress, "refine", iterations)
                bg = torch.tensor(background, dtype=scene.means.dtype, device=device)
                scene = refine(
                    scene,
                    cams,
                    targets,
                    iterations=iterations,
                    background=bg,
                    seed=opts.seed,
                    lr_scale=opts.lr_scale,
                    progress=cb,
                    cells=quantisation_cells(scene, attr_meta) if opts.in_cells else None,
                )
    rep.info["restorer"] = restorer_name if opts.restore else "off"
    rep.info["views"] = len(cams)
    with _stage(rep, progress, "write"):
        write_ply(scene.to("cpu"), out_path)
    return rep
