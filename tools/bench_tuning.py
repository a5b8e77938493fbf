"""The encoder's tuning of its coded values (gspc/encoder/tuning.py): what it gains, what it costs, by scene.

    GSPC_THREADS=1 python tools/bench_tuning.py -o F

(bench/tuning.md quotes its runs' tables beside other measurements, so the tool writes elsewhere.)

Codec alone (no side information, no refinement), the scenes of tools/bench_precision.py (the bird fit with
its held-out photos' cameras, the statues between their 60 synthesised views, massa inside shells of sky-sized
Gaussians), each at the low preset as ``gspc encode`` codes it (lambda 8 and the removal the encoder chooses)
and at the high preset (lambda 1): the untuned coding, then the same coding tuned for each count of
iterations, at the encoder's cameras. PSNR of 8-bit renders against the original's at the scoring views, 1x
and 2x. "Bytes at equal PSNR": the tuned coding's bytes over what the untuned codec needs for the same PSNR,
read off its codings at lambda x 1, 1/1.5, 1/2.25 and 1/3.4 (log-linear between the two nearest; "<" where the
tuned coding is closer than the finest of them). Seconds: the tuning alone, one torch thread.
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import torch
import typer
from bench_precision import STATUES, VARIANTS, Bench, coding
from bench_setups import SHARED, bytes_at, fit_setup, synth_setup
from scenes import Shells, with_shells

from gspc.encoder.coding import encode_attributes
from gspc.encoder.tuning import TuningParams, tune_coding
from gspc.io import read_scene
from gspc.presets import quality_preset

PRESETS = ("low", "high")
# Each preset as `gspc encode` codes it before tuning (the low preset with the removal the encoder chooses).
PRESET_VARIANTS = {"low": "v4-low-chosen", "high": "v4-high"}
LAMBDA_DIVISORS = (1.0, 1.5, 2.25, 3.4)


def benches(bird: str, lego: str, statues: str, shells: str):
    if bird:
        s = fit_setup(Path(bird))
        yield Bench.of(Path(bird).name, "bird", s.scene_path, read_scene(s.scene_path), s)
    if lego:
        s = fit_setup(Path(lego))
        yield Bench.of("lego fit", "bird", s.scene_path, read_scene(s.scene_path), s)
    for name in [x for x in statues.split(",") if x]:
        path = SHARED / "statues" / f"{name}.sog"
        yield Bench.of(name, "statue", path, read_scene(path), synth_setup(name, path, unseen=True))
    for cover in [float(x) for x in shells.split(",") if x]:
        path = SHARED / "statues" / "massa.sog"
        world = with_shells(read_scene(path), replace(Shells(), cover=cover))
        setup = synth_setup("massa", path, unseen=True)
        yield Bench.of(f"massa in shells, cover {cover:g}", "shells", None, world, setup)


def equal_psnr_ratio(curve: list[tuple[int, float]], tuned: tuple[int, float]) -> str:
    need = bytes_at(curve, tuned[1])
    if need is not None:
        return f"{tuned[0] / need:.3f}"
    if tuned[1] > max(p for _, p in curve):  # closer than the finest coding of the curve
        return f"<{tuned[0] / max(b for b, _ in curve):.3f}"
    return "-"


def main(
    bird: str = typer.Option("/work/fits/bird_q4_100k", help="a tools/fit_scene.py output ('' to skip)"),
    lego: str = typer.Option("", help="another fit (e.g. the lego fit of bench/pipeline.md; '' to skip)"),
    statues: str = typer.Option(STATUES),
    shells: str = typer.Option("1,0.1", help="massa inside shells of these sky covers ('' to skip)"),
    iterations: str = typer.Option("4,8", help="tuning lengths, each from the untuned coding"),
    steps: str = typer.Option("0.03", help="Adam's learning rates in cells (TuningParams.step), each a run"),
    presets: str = typer.Option("low,high"),
    out: Path = typer.Option(..., "-o", help="the Markdown file to write"),
) -> None:
    torch.set_num_threads(1)
    counts = [int(x) for x in iterations.split(",") if x]
    rates = [float(x) for x in steps.split(",") if x]
    wanted = [p for p in PRESETS if p in presets.split(",")]
    load0, t_start = os.getloadavg(), time.perf_counter()
    rows = []
    for b in benches(bird, lego, statues, shells):
        print(f"== {b.name}", flush=True)
        b.measure_significance()
        for preset in wanted:
            enc, params = coding(b, VARIANTS[PRESET_VARIANTS[preset]], quality_preset(preset).attributes.lam)
            lam = enc.lam
            base = (enc.num_bytes, *b.views.psnr(enc.decoded))
            curve = [(enc.num_bytes, base[1], base[2])]
            for d in LAMBDA_DIVISORS[1:]:
                e = encode_attributes(b.scene, params.with_lambda(lam / d), b.visible, b.measure)
                curve.append((e.num_bytes, *b.views.psnr(e.decoded)))
            rows.append(_row(b.name, preset, lam, "untuned", base, None, curve, 0.0))
            print(rows[-1], flush=True)
            for n, step in [(n, r) for r in rates for n in counts]:
                tuned = tune_coding(
                    b.scene, enc, params, b.encoder_cams, b.views.background, b.visible, b.measure,
                    TuningParams(iterations=n, step=step),
                )  # fmt: skip
                t = tuned.encoded
                point = (t.num_bytes, *b.views.psnr(t.decoded))
                what = f"{n} iterations" + (f", step {step:g}" if len(rates) > 1 else "")
                secs = tuned.report.seconds
                rows.append(_row(b.name, preset, lam, what, point, base, curve, secs))
                print(rows[-1], f"({tuned.report.summary()})", flush=True)
    load1 = os.getloadavg()
    text = _report(rows, counts, load0, load1, time.perf_counter() - t_start)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(text)
    os.replace(tmp, out)
    print(text)


def _row(name, preset, lam, what, point, base, curve, secs) -> str:
    cells = [name, f"{preset} (lambda {lam:g})", what, f"{point[0]:,}", f"{point[1]:.2f} / {point[2]:.2f}"]
    if base is None:
        cells += ["", "", ""]
    else:
        ratios = [
            equal_psnr_ratio([(c[0], c[1 + k]) for c in curve], (point[0], point[1 + k])) for k in (0, 1)
        ]
        growth = (point[0] / base[0] - 1) * 100
        cells += [
            f"{point[1] - base[1]:+.2f} / {point[2] - base[2]:+.2f} ({growth:+.2f}% B)",
            f"{ratios[0]} / {ratios[1]}",
            f"{secs:.1f}",
        ]
    return "| " + " | ".join(cells) + " |"


def _report(rows, counts, load0, load1, secs) -> str:
    lines = [
        "# Tuning the coded values: gain and cost by scene",
        "",
        __doc__[__doc__.index("Codec alone") :].strip(),
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} CPUs, torch {torch.__version__}, one thread; load "
        f"{load0[0]:.2f} at the start, {load1[0]:.2f} at the end; {secs / 60:.0f} min in all.",
        "",
        "| scene | preset | coding | bytes | PSNR 1x / 2x | tuned - untuned | bytes at equal PSNR 1x / 2x | "
        "tuning s |",
        "|---|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    typer.run(main)
