"""Refinement iterations and time against PSNR, the decoder's schedule before and after, side by side.

    python tools/bench_refine.py [--lego examples/lego] [--statue massa] [--fit /work/fits/bird_q4_100k] \
        [--check] [--out bench/refine.md]

Per scene: the low preset's file with side information always sent (``--check-iterations 0``), decoded up
to the refinement's targets (G~ rendered at the stored views and restored, as gspc/pipeline.py's decoder
does); then, on those same targets, refinement runs under the schedule before this change (INRIA rates,
the preset's iterations before it: 1000, at most 5e7 / Gaussians, runs under 300 at proportionally smaller
rates) and under the decoder's schedule now (gspc/reconstruct.py, decoder_schedule), each timed on one
thread and scored at held-out views that carry no side information: against the original's renders and,
for fits, against the held-out photos. Each "after" run is also scored where the encoder's check scores
its trial (gspc/encoder/policy.py, CheckPolicy), which calibrates the check's gain ratios.
``--check``: the default encode with the check as it is (a trial, run on only where it does not settle
the decision) and with the full check (the whole refinement run), side by side: decision, seconds.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import imagecodecs
import numpy as np
import torch
import torch.nn.functional as F

import gspc.pipeline as pipeline
from gspc.cameras import Camera
from gspc.codec.attributes import decode_attributes
from gspc.codec.cells import quantisation_cells
from gspc.encoder.policy import CheckPolicy
from gspc.format import container
from gspc.format.attribute_section import AttributeSection, attribute_chunks
from gspc.format.header import FileHeader
from gspc.format.side_chunk import read_side_views
from gspc.io import read_scene
from gspc.io.camera_files import load_cameras
from gspc.metrics import mean_psnr
from gspc.options import EncodeOptions
from gspc.reconstruct import FULL_RATE_FROM, decoder_schedule, render_images, restored_targets
from gspc.refine import Refinement, Schedule
from gspc.restore.restorer import load_restorer
from gspc.scene import GaussianScene
from gspc.views import sample_views, split_test_views, synthesize_views

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
# The schedule before this change: the low preset's 1000 iterations, at most OLD_WORK / Gaussians, at
# INRIA's rates, runs under OLD_FULL_RATE_FROM iterations at proportionally smaller rates.
OLD_ITERATIONS, OLD_WORK, OLD_MIN, OLD_FULL_RATE_FROM = 1000, 50_000_000, 50, 300


@dataclasses.dataclass
class Setup:
    name: str
    scene: GaussianScene
    train: list[Camera]  # the encoder samples side-information views from these
    held_out: list[Camera]  # carry none; scored here
    background: tuple[float, float, float]
    photos: list[torch.Tensor] | None


def _resized(img: np.ndarray, cam: Camera, background: float) -> torch.Tensor:
    t = torch.from_numpy(img.astype(np.float32) / 255).permute(2, 0, 1)[None]
    t = F.interpolate(t, size=(cam.height, cam.width), mode="area")[0].permute(1, 2, 0)
    if t.shape[-1] == 4:  # composited on the fit's background, as tools/fit_scene.py does
        return t[..., :3] * t[..., 3:] + background * (1 - t[..., 3:])
    return t[..., :3]


def fit_setup(folder: Path, photo_root: Path | None) -> Setup:
    """A tools/fit_scene.py output (or examples/lego): held-out views every 8th camera, with their photos
    from ``folder``/test or, when that is absent, ``photo_root``."""
    fit = json.loads((folder / "fit.json").read_text())
    bg = float(fit.get("background", 1.0 if fit.get("source") != "colmap" else 0.0))
    cams = load_cameras(folder / "cameras.json")
    train, test = split_test_views(cams, every=8)
    photos = []
    for i in test:
        own = folder / "test" / f"{cams[i].name}.png"
        path = own if own.exists() else photo_root / f"{cams[i].name}.png"
        photos.append(_resized(imagecodecs.png_decode(path.read_bytes()), cams[i], bg))
    scene = read_scene(folder / "point_cloud.ply")
    return Setup(folder.name, scene, [cams[i] for i in train], [cams[i] for i in test], (bg,) * 3, photos)


def statue_setup(name: str) -> Setup:
    """bench/pipeline.md's statue set-up: 60 synthesised 320x320 views, 12 held out of the sampled ones."""
    scene = read_scene(SHARED / "statues" / f"{name}.sog")
    cams = synthesize_views(scene, 60, width=320, height=320)
    side = set(sample_views(cams, 0.4))
    rest = [i for i in range(len(cams)) if i not in side]
    pick = [rest[int(j)] for j in np.linspace(0, len(rest) - 1, 12).round()]
    return Setup(f"statue {name}", scene, cams, [cams[i] for i in pick], (0.0,) * 3, None)


def scale_setup(folder: Path, per_copy: int) -> Setup:
    """bench/scale_pipeline.md's set-up: close-up cameras per copy, every 4th held out."""
    from bench_scale_pipeline import closeup_cameras  # a sibling tool (run from tools/, as it is)

    cams = closeup_cameras(json.loads((folder / "scene.json").read_text()), per_copy)
    train, test = split_test_views(cams, every=4)
    scene = read_scene(folder / "point_cloud.ply")
    return Setup(folder.name, scene, [cams[i] for i in train], [cams[i] for i in test], (0.0,) * 3, None)


def _options(s: Setup, **kw) -> EncodeOptions:
    side = max(max(c.width, c.height) for c in s.train)
    return EncodeOptions(background=s.background, max_side=side, **kw)


@dataclasses.dataclass
class Inputs:
    decoded: GaussianScene
    section: AttributeSection
    cameras: list[Camera]
    targets: list[torch.Tensor]
    iterations: int  # the file's (the decoder's default now)


def decode_inputs(s: Setup) -> Inputs:
    """The decoder's refinement inputs for the low preset's file with side information always sent."""
    data, _ = pipeline.encode_scene(s.scene, s.train, _options(s, check_iterations=0))
    c = container.unpack(data)
    fields = FileHeader.from_dict(c.header)
    side = read_side_views(fields.side_info.legacy_views, c.chunks, len(data))
    decoded = decode_attributes(attribute_chunks(c.chunks), fields.attributes)
    cams = [v.camera.to_camera() for v in side.views]
    degraded = render_images(decoded, cams, s.background)
    targets = restored_targets(degraded, side.views, side.images, load_restorer(fields.side_info.restorer))
    return Inputs(decoded, fields.attributes, cams, targets, fields.side_info.refine_iterations)


def old_schedule(num_gaussians: int) -> Schedule:
    n = int(min(OLD_ITERATIONS, max(OLD_MIN, OLD_WORK // max(num_gaussians, 1))))
    return Schedule(n, full_rate_from=OLD_FULL_RATE_FROM)


def refine_row(s: Setup, inp: Inputs, schedule: Schedule, reference, trial: int | None) -> dict:
    """One refinement under ``schedule``: seconds, PSNR at the held-out views (and at ``trial``)."""
    bg = torch.tensor(s.background, dtype=inp.decoded.means.dtype)
    cells = quantisation_cells(inp.decoded, inp.section)
    run = Refinement(inp.decoded, inp.cameras, inp.targets, schedule, bg, cells)
    out: dict = {"iterations": schedule.iterations}
    seconds = 0.0
    if trial is not None and trial < schedule.iterations:
        t0 = time.perf_counter()
        run.run(trial)
        seconds += time.perf_counter() - t0
        out["trial_psnr"] = mean_psnr(render_images(run.scene(), s.held_out, s.background), reference)
    t0 = time.perf_counter()
    run.run()
    out["seconds"] = seconds + time.perf_counter() - t0
    images = render_images(run.scene(), s.held_out, s.background)
    out["psnr"] = mean_psnr(images, reference)
    if s.photos is not None:
        out["photo"] = mean_psnr(images, s.photos)
    return out


def bench_refinement(s: Setup, lines: list[str], only_ends: bool = False, decoder_only: bool = False) -> dict:
    inp = decode_inputs(s)
    reference = render_images(s.scene, s.held_out, s.background)
    coded = render_images(inp.decoded, s.held_out, s.background)
    base = {"psnr": mean_psnr(coded, reference), "photo": mean_psnr(coded, s.photos) if s.photos else None}
    n = inp.decoded.num_gaussians
    before, after = old_schedule(n), decoder_schedule(inp.iterations)
    policy = CheckPolicy()
    rows = [
        ("before", before),
        ("before, at the new length", dataclasses.replace(before, iterations=after.iterations)),
        ("after, half the new length", decoder_schedule(max(1, after.iterations // 2))),
        ("after", after),
    ]
    if only_ends:
        rows = [rows[0], rows[-1]]
    if decoder_only:
        rows = [rows[-1]]
    lines += [
        f"### {s.name}",
        "",
        f"{n:,} Gaussians (SH degree {inp.decoded.sh_degree}); {len(inp.cameras)} side-information views, "
        f"{len(s.held_out)} held-out views "
        f"({s.held_out[0].width}x{s.held_out[0].height}). G~ as coded: {base['psnr']:.2f} dB against the "
        "original's renders" + (f", {base['photo']:.2f} dB against the photos." if s.photos else "."),
        "",
        "| schedule | iterations | rates (x INRIA's: sh_rest / others) | refine s | PSNR vs original "
        f"| PSNR photos | PSNR at the check's trial ({policy.trial_fraction:g} of the run) |",
        "|---|---|---|---|---|---|---|",
    ]
    results = {"coded": base}
    for label, sched in rows:
        trial = policy.trial_length(sched.iterations) if sched.group_rates else None
        r = refine_row(s, inp, sched, reference, trial)
        results[label] = r
        rate = f"{sched.rate * sched.group_rate('sh_rest'):g} / {sched.rate:g}"
        if 0 < sched.full_rate_from and sched.iterations < sched.full_rate_from:
            rate += f" (x {sched.iterations}/{sched.full_rate_from})"
        photo = f"{r['photo']:.2f}" if "photo" in r else "-"
        at_trial = f"{r['trial_psnr']:.2f}" if "trial_psnr" in r else "-"
        lines.append(
            f"| {label} | {sched.iterations} | {rate} | {r['seconds']:.1f} | {r['psnr']:.2f} | {photo} "
            f"| {at_trial} |"
        )
        print(lines[-1], flush=True)
    lines.append("")
    return results


def bench_check(s: Setup, lines: list[str]) -> None:
    """The default encode with the check as it is and with the full check, side by side."""
    full = CheckPolicy(trial_from=1 << 30)
    lines += [
        f"Check on {s.name} (default encode; the full check runs the whole refinement):",
        "",
        "| check | outcome | iterations run | coded dB | refined dB | rival dB | check s | encode s "
        "| bytes |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    real = pipeline.CheckInputs
    for label, policy in (("trial (now)", CheckPolicy()), ("full", full)):
        pipeline.CheckInputs = lambda *a, _p=policy, **k: real(*a, **k, policy=_p)  # type: ignore[misc]
        try:
            t0 = time.perf_counter()
            data, rep = pipeline.encode_scene(s.scene, s.train, _options(s))
            wall = time.perf_counter() - t0
        finally:
            pipeline.CheckInputs = real
        d = rep.side_info
        ran = d.trial_iterations if d.predicted else d.iterations
        check_s = rep.seconds.get("check", float("nan"))
        lines.append(
            f"| {label} | {d.outcome.value} | {ran} of {d.iterations} | {d.coded_db:.2f} "
            f"| {d.refined_db:.2f} | {d.best_rival_db:.2f} | {check_s:.0f} | {wall:.0f} | {len(data):,} |"
        )
        print(lines[-1], flush=True)
    lines.append("")


def bench_end_to_end(s: Setup, lines: list[str]) -> None:
    """The default encode and decode in memory (gspc.encode_scene / decode_bytes), timed per stage."""
    t0 = time.perf_counter()
    data, rep = pipeline.encode_scene(s.scene, s.train, _options(s))
    encode_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    decoded, drep = pipeline.decode_bytes(data)
    decode_s = time.perf_counter() - t0
    images = render_images(decoded, s.held_out, s.background)
    p = mean_psnr(images, render_images(s.scene, s.held_out, s.background))
    photo = f", {mean_psnr(images, s.photos):.2f} dB against the photos" if s.photos else ""

    def stages(r) -> str:
        return ", ".join(f"{k} {v:.1f}" for k, v in r.seconds.items())

    lines += [
        f"Default encode and decode of {s.name}, end to end in memory: encode {encode_s:.1f} s "
        f"({stages(rep)}; "
        f"check: {rep.info.get('check', 'none')}), {len(data):,} B; decode {decode_s:.1f} s ({stages(drep)}; "
        f"refine: {drep.info.get('refine', 'none')}); {p:.2f} dB against the original's renders{photo}.",
        "",
    ]
    print(lines[-2], flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--lego", default=str(REPO / "examples" / "lego"), help="'' to skip")
    ap.add_argument("--statue", default="massa", help="a statue in ../shared/data/statues ('' to skip)")
    ap.add_argument("--fit", default="", help="a tools/fit_scene.py output folder, e.g. a bird fit")
    ap.add_argument("--scale", default="", help="a tools/make_scale_scenes.py scene folder")
    ap.add_argument("--per-copy", type=int, default=8, help="close-up cameras per copy (--scale)")
    ap.add_argument("--check", action="store_true", help="also compare the check with the full check")
    ap.add_argument("--check-only", action="store_true", help="only the check's comparison")
    ap.add_argument("--only-ends", action="store_true", help="only the before and after rows")
    ap.add_argument(
        "--decoder-only",
        action="store_true",
        help="only the decoder's schedule (to time one gspc against another: run once per PYTHONPATH)",
    )
    ap.add_argument("--end-to-end", action="store_true", help="only the default encode and decode, timed")
    ap.add_argument("--out", default=str(REPO / "bench" / "refine.md"))
    args = ap.parse_args()
    torch.set_num_threads(1)
    setups = []
    if args.lego:
        setups.append(lambda: fit_setup(Path(args.lego), SHARED / "lego" / "train"))
    if args.statue:
        setups.append(lambda: statue_setup(args.statue))
    if args.fit:
        setups.append(lambda: fit_setup(Path(args.fit), None))
    if args.scale:
        setups.append(lambda: scale_setup(Path(args.scale), args.per_copy))
    t0 = time.perf_counter()
    lines = [
        "# Refinement: iterations and time against PSNR, before and after",
        "",
        "Command: `python tools/bench_refine.py " + " ".join(os.sys.argv[1:]) + "`",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} vCPUs shared with other jobs (loaded), one torch "
        "thread; every row of a table ran in the same process, one after another, on the same targets. PSNR "
        "on 8-bit renders at held-out views (no side information there). Rates: multiples of INRIA 3DGS's "
        f"(gspc/refine.py, BASE_LR). Before: up to 1000 iterations, runs under {OLD_FULL_RATE_FROM} at "
        f"proportionally smaller rates; after: gspc/reconstruct.py's decoder_schedule (runs under "
        f"{FULL_RATE_FROM} at proportionally smaller rates).",
        "",
    ]
    for make in setups:
        s = make()
        if args.end_to_end:
            bench_end_to_end(s, lines)
            continue
        if not args.check_only:
            bench_refinement(s, lines, args.only_ends, args.decoder_only)
        if args.check or args.check_only:
            bench_check(s, lines)
        Path(args.out).write_text("\n".join(lines) + "\n")
    lines.append(f"Benchmark time: {time.perf_counter() - t0:.0f} s.")
    Path(args.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
