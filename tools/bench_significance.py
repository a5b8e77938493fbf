"""Which per-Gaussian measure predicts where the attribute codec's error shows (issue: precision that follows
what each Gaussian does to the views; gspc/encoder/significance.py).

    python tools/bench_significance.py SCENE [SCENE ...] [--lam 8] [--measure-views N] [--out FILE]

SCENE is a fit directory or file (point_cloud.ply with cameras.json and fit.json beside it: the measure
uses the training cameras, scoring the held-out ones) or a scene without cameras (views are synthesised:
24 to measure on, 9 others to score). For each attribute group the scene is coded at ``--lam``
(codec alone), then the original values of that group are put back on the top fraction of Gaussians by
each measure, and the held-out views are rendered at the cameras' size and at twice it. A measure is
good when a small fraction recovers most of what restoring the whole group recovers: the table gives that
share of the MSE drop. Baselines: world size over distance to the nearest camera (the issue's proxy) and a
random order. One torch thread.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from gspc.encoder.coding import encode_attributes
from gspc.encoder.significance import significance
from gspc.io import read_scene
from gspc.io.camera_files import load_cameras
from gspc.metrics import mse
from gspc.presets import quality_preset
from gspc.reconstruct import render_images
from gspc.scene import GaussianScene
from gspc.views import synthesize_views
from gspc.visibility import visible_mask

FRACTIONS = (0.05, 0.1, 0.25)
GROUPS = ("means", "quats", "log_scales", "opacities", "sh_dc", "sh_rest")


def load(path: Path, synth_side: int) -> tuple[GaussianScene, list, list, float]:
    """(scene, measure cameras, scoring cameras, background)."""
    ply = path / "point_cloud.ply" if path.is_dir() else path
    scene = read_scene(ply)
    cams_file, fit_file = ply.parent / "cameras.json", ply.parent / "fit.json"
    if not cams_file.is_file():
        return (scene, synthesize_views(scene, 24, synth_side, synth_side),
                synthesize_views(scene, 9, synth_side, synth_side), 0.0)  # fmt: skip
    cams = load_cameras(cams_file)
    fit = json.loads(fit_file.read_text()) if fit_file.is_file() else {}
    test = set(fit.get("test_names") or [])
    if not test:  # no split stated: every 8th camera scores
        test = {c.name for c in cams[::8]}
    train = [c for c in cams if c.name not in test]
    score = [c for c in cams if c.name in test]
    return scene, train, score[:: max(1, len(score) // 9)][:9], float(fit.get("background", 0.0))


def size_over_distance(scene: GaussianScene, cams) -> np.ndarray:
    """World extent (largest scale) over the distance to the nearest camera centre."""
    means = scene.means.double().numpy()
    centres = np.stack([c.center for c in cams])
    dist = np.full(len(means), np.inf)
    for c in centres:
        dist = np.minimum(dist, np.linalg.norm(means - c, axis=1))
    return np.exp(scene.log_scales.double().numpy().max(1)) / np.maximum(dist, 1e-9)


def renders(scene: GaussianScene, cams, bg: float) -> list[torch.Tensor]:
    return render_images(scene, cams, (bg, bg, bg))


def mean_mse(a: list[torch.Tensor], b: list[torch.Tensor]) -> float:
    """Unquantised MSE over the views: the shares compare small differences that 8 bits would round."""
    return float(np.mean([mse(x, y).item() for x, y in zip(a, b)]))


def psnr(m: float) -> float:
    return 10 * np.log10(1.0 / max(m, 1e-20))


def bench(path: Path, lam: float, synth_side: int, measure_views: int = 0) -> tuple[list[str], dict]:
    scene, train, score, bg = load(path, synth_side)
    if 0 < measure_views < len(train):  # evenly spaced: the measure's cost is per view
        train = [train[int(i)] for i in np.linspace(0, len(train) - 1, measure_views).round()]
    params = replace(quality_preset("low").attributes, lam=lam)
    visible = visible_mask(scene.means.numpy(), scene.log_scales.numpy(), train + score)
    t = time.perf_counter()
    enc = encode_attributes(scene, params, visible=visible)
    code_s = time.perf_counter() - t
    coded = enc.decoded
    kept = torch.from_numpy(enc.kept)
    orig = scene.map(lambda x: x.detach().index_select(0, kept))
    t = time.perf_counter()
    sig = significance(orig, train, (bg, bg, bg))
    measure_s = time.perf_counter() - t
    proxy = size_over_distance(orig, train)
    rng = np.random.default_rng(0)
    orders = {"weight": sig.ranking("weight"), "size/dist": np.argsort(-proxy, kind="stable"),
              "random": rng.permutation(orig.num_gaussians)}  # fmt: skip
    scales = {"1x": score, "2x": [c.scaled(2.0) for c in score]}
    refs = {k: renders(orig, cams, bg) for k, cams in scales.items()}
    base = {k: mean_mse(renders(coded, cams, bg), refs[k]) for k, cams in scales.items()}
    rows, summary = [], {}
    groups = [g for g in GROUPS if g != "sh_rest" or scene.sh_degree > 0]
    for group in groups:
        own = dict(orders, gradient=sig.ranking(f"gradient:{group}"))

        def restored(idx: np.ndarray, group: str = group) -> GaussianScene:
            values = getattr(coded, group).clone()
            ix = torch.from_numpy(np.asarray(idx, np.int64))
            values[ix] = getattr(orig, group)[ix]
            return replace(coded, **{group: values})

        full = {k: mean_mse(renders(restored(np.arange(orig.num_gaussians)), cams, bg), refs[k])
                for k, cams in scales.items()}  # fmt: skip
        for name, order in own.items():
            shares = []
            for f in FRACTIONS:
                sub = restored(order[: int(round(f * len(order)))])
                for k, cams in scales.items():
                    drop = base[k] - full[k]
                    got = base[k] - mean_mse(renders(sub, cams, bg), refs[k])
                    shares.append(got / drop if drop > 0 else float("nan"))
            summary[(group, name)] = shares
            cells = " | ".join(f"{s:.2f}" for s in shares)
            gain = f"{psnr(full['1x']) - psnr(base['1x']):+.2f} / {psnr(full['2x']) - psnr(base['2x']):+.2f}"
            rows.append(f"| {group} | {gain} | {name} | {cells} |")
    head = [
        f"### {path} (lambda {lam:g}, {orig.num_gaussians:,} Gaussians coded, SH degree {scene.sh_degree})",
        "",
        f"Coded alone: {psnr(base['1x']):.2f} dB at the scoring views' size, {psnr(base['2x']):.2f} dB at "
        f"twice it ({len(score)} scoring views, {score[0].width}x{score[0].height}; "
        f"measure over {len(train)} views, "
        f"{train[0].width}x{train[0].height}). Coding took {code_s:.1f} s, both measures {measure_s:.1f} s "
        f"({measure_s / len(train):.2f} s per view).",
        "",
        "Share of the MSE drop that restoring the group's original values on the top fraction recovers "
        "(1.0: all of it); the gain column is restoring the group on every Gaussian (dB, 1x / 2x).",
        "",
        "| group | whole group dB | measure | "
        + " | ".join(f"{f:.0%} {k}" for f in FRACTIONS for k in scales)
        + " |",
        "|---|---|---|" + "---|" * (len(FRACTIONS) * len(scales)),
    ]
    return head + rows + [""], summary


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--lam", type=float, default=8.0)
    ap.add_argument("--synth-side", type=int, default=400, help="size of synthesised views")
    ap.add_argument("--measure-views", type=int, default=0, help="measure over this many views (0: all)")
    ap.add_argument("--out", type=Path, default=None, help="append the tables to this Markdown file")
    a = ap.parse_args()
    torch.set_num_threads(1)
    machine = f"{platform.machine()} {os.cpu_count()}-vCPU VM"
    lines = [f"Machine: {machine}, one torch thread, loaded by other jobs.", ""]
    for p in a.scenes:
        lines += bench(p, a.lam, a.synth_side, a.measure_views)[0]
        print("\n".join(lines), flush=True)
    if a.out:
        with open(a.out, "a") as f:
            f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
