"""Is each group of Gaussians coded at the rate's balance? (issue 25: "each Gaussian coded at the precision
its effect on the views calls for")

    GSPC_THREADS=1 python tools/bench_balance.py -o bench/balance.md

The encoder gives each Gaussian a precision class from its significance (gspc/encoder/precision_plan.py: the
class exponent falls by one as the sensitivity grows fourfold). Where a group of Gaussians is served as its
effect on the views calls for, the last byte spent on it buys as much PSNR as the last byte spent anywhere
else: moving the group's classes either way, and no other, lands on or below the scene's own rate-distortion
curve.
So per group, its significance gradients are scaled by ``f`` before the class plan (f = 4: one class finer,
1/4: one coarser; past the tail at half the pace), the scene is coded at the preset's lambda, and its bytes
are set against the curve the unscaled coding draws over ``--lams``: bytes at equal PSNR over the curve's
(log-linear between its two nearest points, bench_setups.bytes_at). Under 1 at f > 1: the group was
under-served; under 1 at f < 1: over-served; about 1 or over at both: at the balance. Removal is left to the
weight, which no scaling touches (a variant that searches removal and grid, such as v4-low-chosen, still
searches them, as ``gspc encode`` does).

Scenes and their scoring are tools/bench_precision.py's (``Bench``): the bird fit at its held-out cameras,
the statues and massa inside tools/scenes.py's shells at views between the encoder's, 1x and 2x, 8-bit and
float PSNR. Groups:

- **larger half**: the Gaussians whose world size (largest axis) over the distance to the nearest encoder
  camera is above the median, the issue's own split ("the larger half carries it all");
- **room**: those outside the codec's region of interest (gspc/codec/positions.py ``region_of_interest``),
  where the scene has one (the bird's room, the shells' sky);
- **sky**: the shells' added Gaussians (the world's rows past the object's).
"""

from __future__ import annotations

import os
import platform
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
import typer
from bench_precision import ROOT, STATUE_VIEWS, STATUES, VARIANTS, Bench, Point, Variant, coded_point
from bench_setups import SHARED, bytes_at, fit_setup, synth_setup
from scenes import Shells, with_shells

from gspc.cameras import Camera
from gspc.codec.positions import region_of_interest
from gspc.encoder.precision_plan import Significance
from gspc.io import read_scene
from gspc.scene import GaussianScene


def scaled(measure: Significance, rows: np.ndarray, factor: float) -> Significance:
    """``measure`` with every gradient of the Gaussians in ``rows`` (a boolean mask) times ``factor``; the
    weight (removal's), the SH band changes and the view count as they are."""
    s = np.where(rows, float(factor), 1.0)
    grads = {k: g * (s if g.ndim == 1 else s[:, None]) for k, g in measure.gradient.items()}
    return replace(measure, gradient=grads)


def larger_half(scene: GaussianScene, cams: list[Camera]) -> np.ndarray:
    """Mask of the Gaussians whose largest axis over the distance to the nearest camera centre is above the
    median: what they span of a view, before the view's own focal length."""
    means = scene.means.detach().double().numpy()
    size = np.exp(scene.log_scales.detach().double().numpy().max(1))
    centres = np.stack([c.center for c in cams])
    near = np.full(len(means), np.inf)
    for c in centres:  # one camera at a time: a million Gaussians by a hundred cameras stays small
        near = np.minimum(near, np.sqrt(((means - c) ** 2).sum(1)))
    angle = size / np.maximum(near, 1e-12)
    return angle > np.median(angle)


def outside_region(scene: GaussianScene) -> np.ndarray | None:
    """Mask of the Gaussians outside the codec's region of interest, or None for a bounded scene."""
    means = scene.means.detach().double().numpy()
    roi = region_of_interest(means)
    if roi is None:
        return None
    centre, radius = roi
    return np.sqrt(((means - centre) ** 2).sum(1)) > radius


@dataclass(frozen=True)
class Row:
    scene: str
    group: str
    count: int
    factor: float
    point: Point
    ratio: tuple[float | None, float | None, float | None]  # bytes over the curve's: 8-bit 1x, 2x, float 1x


def ratios(curve: list[Point], p: Point) -> tuple[float | None, float | None, float | None]:
    """``p``'s bytes over the curve's bytes at ``p``'s PSNR (8-bit 1x, 8-bit 2x, float 1x)."""
    out = []
    for pick in (lambda q: q.psnr[0], lambda q: q.psnr[1], lambda q: q.float_psnr[0]):
        at = bytes_at([(q.bytes, pick(q)) for q in curve], pick(p))
        out.append(None if at is None else p.bytes / at)
    return out[0], out[1], out[2]


def balance(
    b: Bench, groups: dict[str, np.ndarray], variant: Variant, lams: list[float], lam: float,
    factors: list[float],
) -> tuple[list[Point], list[Row]]:  # fmt: skip
    """The scene's curve over ``lams`` and, per group and factor, its coding at ``lam`` with the group's
    gradients scaled."""
    base = b.measure
    curve = [coded_point(b, variant, x) for x in lams]
    rows = []
    try:
        for name, mask in groups.items():
            for f in factors:
                b.measure = scaled(base, mask, f)
                p = coded_point(b, variant, lam)
                rows.append(Row(b.name, name, int(mask.sum()), f, p, ratios(curve, p)))
                print(f"{b.name} {name} x{f:g}: {p.bytes:,} B, ratios {rows[-1].ratio}", flush=True)
    finally:
        b.measure = base
    return curve, rows


def _r(x: float | None) -> str:
    return "beyond" if x is None else f"{x:.3f}"


def _dual(p: Point) -> str:
    return f"{p.psnr[0]:.2f} / {p.psnr[1]:.2f} ({p.float_psnr[0]:.2f})"


def main(
    bird: str = typer.Option("/work/fits/bird_q4_100k", help="a tools/fit_scene.py output ('' to skip)"),
    statues: str = typer.Option(STATUES, help="statues (SH degree 0) in ../shared/data/statues, by name"),
    shells_object: str = typer.Option("massa", help="the statue the shells surround ('' to skip)"),
    covers: str = typer.Option("1,0.1", help="the shells' sky cover (tools/scenes.py Shells.cover)"),
    shell_views: int = typer.Option(
        67, min=1, help="the shells' scoring views (67: the whole unseen sphere)"
    ),
    variant: str = typer.Option("v4-low-chosen", help=f"the codec variant: {', '.join(VARIANTS)}"),
    lams: str = typer.Option("6,8,11", help="the curve's lambdas; the middle one is the coding's"),
    factors: str = typer.Option("0.25,4,16", help="what each group's gradients are multiplied by"),
    out: Path = typer.Option(ROOT / "bench" / "balance.md", "-o"),
) -> None:
    torch.set_num_threads(1)
    t0, load0 = time.perf_counter(), os.getloadavg()
    v = VARIANTS[variant]
    lam_list = [float(x) for x in lams.split(",")]
    lam = lam_list[len(lam_list) // 2]
    fs = [float(x) for x in factors.split(",")]
    benches: list[tuple[Bench, dict[str, np.ndarray]]] = []
    if bird:
        s = fit_setup(Path(bird))
        benches.append((Bench.of(Path(bird).name, "bird", None, read_scene(s.scene_path), s), {}))
    for name in [x for x in statues.split(",") if x]:
        path = SHARED / "statues" / f"{name}.sog"
        benches.append(
            (Bench.of(name, "statue", None, read_scene(path), synth_setup(name, path, unseen=True)), {})
        )
    if shells_object:
        path = SHARED / "statues" / f"{shells_object}.sog"
        setup = synth_setup(path.stem, path, views=STATUE_VIEWS, n_eval=shell_views, unseen=True)
        obj = read_scene(path)
        for cover in [float(x) for x in covers.split(",") if x]:
            world = with_shells(obj, replace(Shells(), cover=cover))
            sky = np.arange(world.num_gaussians) >= obj.num_gaussians
            name = f"{path.stem} in shells, cover {cover:g}"
            benches.append((Bench.of(name, "shells", None, world, setup), {"sky": sky}))
    rows: list[Row] = []
    curves: dict[str, list[Point]] = {}
    for b, extra in benches:
        print(f"== {b.name}", flush=True)
        b.measure_significance()
        groups = {"larger half": larger_half(b.scene, b.encoder_cams)}
        room = outside_region(b.scene)
        if room is not None and "sky" not in extra:
            groups["room"] = room
        groups.update(extra)
        curves[b.name], got = balance(b, groups, v, lam_list, lam, fs)
        rows += got
    text = report(rows, curves, v, lam_list, lam, load0, os.getloadavg(), time.perf_counter() - t0)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(text)
    os.replace(tmp, out)
    print(text)


def report(rows, curves, v, lam_list, lam, load0, load1, secs) -> str:
    head = subprocess.run(
        ["git", "-C", str(ROOT), "describe", "--always", "--dirty"], capture_output=True, text=True
    )
    lines = [
        "# Each group of Gaussians at the rate's balance (issue 25)",
        "",
        f"Command: `GSPC_THREADS=1 python tools/bench_balance.py {shlex.join(sys.argv[1:])}` at commit "
        f"{head.stdout.strip()}; {secs / 60:.0f} min.",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} vCPUs (load average {load0[0]:.1f} at the start, "
        f"{load1[0]:.1f} at the end), one torch thread. Variant **{v.name}**: {v.about}. How each number is "
        "made: the docstring of tools/bench_balance.py. Codec alone (no side information, no refinement); "
        "PSNR of 8-bit renders (float in brackets: clamped, not rounded) at views the encoder did not use, "
        "at the scene's size (1x) and twice it (2x).",
        "",
        f"Each group's gradients times f, coded at lambda {lam:g}; **bytes at equal PSNR over the scene's "
        f"own curve** (lambda {', '.join(f'{x:g}' for x in lam_list)}, unscaled): under 1 the move pays. "
        "At the balance both directions give about 1 or more.",
        "",
        "| scene | group (Gaussians) | f | bytes | PSNR 1x / 2x (float 1x) | over the curve: 1x | 2x "
        "| float 1x |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.scene} | {r.group} ({r.count:,}) | {r.factor:g} | {r.point.bytes:,} | {_dual(r.point)} "
            f"| {_r(r.ratio[0])} | {_r(r.ratio[1])} | {_r(r.ratio[2])} |"
        )
    lines += [
        "",
        "The curves (unscaled):",
        "",
        "| scene | lambda | bytes | PSNR 1x / 2x (float 1x) |",
        "|---|---|---|---|",
    ]
    for name, curve in curves.items():
        for x, p in zip(lam_list, curve):
            lines.append(f"| {name} | {x:g} | {p.bytes:,} | {_dual(p)} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    typer.run(main)
