"""Benchmark the shipped restorer: restoration on held-out views, speed, and the full decode.

    python tools/bench_restorer.py --data /work/restorer_data --restorer nafnet-s16 \
        --scene ../shared/data/statues/massa.sog --iterations 300

Writes bench/restorer.md:
1. Restoration at every rate point on the validation views of the data set (scenes the restorer
   never saw in training): PSNR of I~, of I~ + R~ (side information alone, restorer "none") and
   of the restored view, each clamped and quantised to 8 bits against the original render.
2. Seconds to restore one 400x300 view on one CPU thread (median of 5).
3. Full pipeline on a held-out scene: encode at the preset, then decode without refinement (G~),
   with refinement towards I~ + R~ (restorer "none") and towards the restored views; PSNR of the
   decoded scene's renders against the original scene's at the views the encoder did not send.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import typer

from gspc.io import read_scene
from gspc.metrics import mean_psnr
from gspc.options import DecodeOptions, EncodeOptions
from gspc.pipeline import decode, encode
from gspc.reconstruct import render_images
from gspc.restore.data import load_view, read_manifest, validate
from gspc.restore.nafnet import count_parameters
from gspc.restore.restorer import load_restorer
from gspc.views import limit_size, sample_views, synthesize_views


def restoration_table(data_dir: Path, name: str) -> tuple[list[str], dict]:
    entries = [e for e in read_manifest(data_dir) if e["split"] == "val"]
    views = [load_view(data_dir, e) for e in entries]
    model = load_restorer(name).model
    lines = [
        "| scene | rate point | lambda | base distance | views | n | with R~ | I~ dB | I~ + R~ dB "
        "| restored dB | gain dB |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    results = {}
    for scene in sorted({e["scene"] for e in entries}):
        sv = [v for v in views if v["entry"]["scene"] == scene]
        for rate in sorted({v["entry"]["rate"] for v in sv}):
            rv = [v for v in sv if v["entry"]["rate"] == rate]
            e = rv[0]["entry"]
            with_r = [v for v in rv if v["entry"]["distances"][0] > 0]
            without = [v for v in rv if v["entry"]["distances"][0] <= 0]
            subsets = [("all", rv)]
            if with_r and without:  # the encoder skips views whose residual RMS is below 1/255
                subsets += [("with R~", with_r), ("without R~", without)]
            for label, views_ in subsets:
                r = validate(model, views_)
                results[(scene, rate, label)] = r
                sent = sum(v["entry"]["distances"][0] > 0 for v in views_)
                lines.append(
                    f"| {scene} | {rate} | {e['lam']:g} | {e['base_distance']:g} | {label} | {len(views_)} "
                    f"| {sent} | {r['degraded']:.2f} | {r['side']:.2f} | {r['restored']:.2f} "
                    f"| **{r['gain']:+.2f}** |"
                )
    return lines, results


def inference_seconds(name: str, width: int = 400, height: int = 300, repeats: int = 5) -> float:
    restorer = load_restorer(name)
    gen = torch.Generator().manual_seed(0)
    img, res = (
        torch.rand(height, width, 3, generator=gen),
        0.01 * torch.randn(height, width, 3, generator=gen),
    )
    restorer.restore(img, res)  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        restorer.restore(img, res)
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def pipeline_rows(scene_path: Path, name: str, quality: str, iterations: int, every: int) -> list[str]:
    scene = read_scene(scene_path)
    opts = EncodeOptions(quality=quality, restorer=name)
    cams = limit_size(synthesize_views(scene, opts.synth_views), opts.max_side)
    sent = set(sample_views(cams, opts.views_fraction))
    eval_cams = [c for i, c in enumerate(cams) if i not in sent][::every]
    refs = render_images(scene, eval_cams, opts.background)

    def score(ply: Path) -> float:
        return mean_psnr(render_images(read_scene(ply), eval_cams, opts.background), refs)

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rep = encode(scene_path, tmp / "s.gspc", None, opts)
        size = rep.bytes["file"]
        runs = [
            ("G~ (no restore, no refinement)", DecodeOptions(restore=False, refine=False)),
            ("refine towards I~ + R~ (restorer none)", DecodeOptions(iterations=iterations, restorer="none")),
            (f"refine towards restored views ({name})", DecodeOptions(iterations=iterations, restorer=name)),
        ]
        for label, dopts in runs:
            t = time.perf_counter()
            decode(tmp / "s.gspc", tmp / "d.ply", dopts)
            secs = time.perf_counter() - t
            db = score(tmp / "d.ply")
            rows.append(f"| {scene_path.name} | {quality} | {label} | {size} | {db:.2f} | {secs:.0f} |")
    return rows


def main(
    data: Path = typer.Option(Path("/work/restorer_data"), help="make_restorer_data.py output"),
    restorer: str = typer.Option(..., help="shipped restorer name"),
    scene: list[Path] = typer.Option([], help="held-out scene(s) for the full-pipeline rows"),
    quality: str = typer.Option("low"),
    iterations: int = typer.Option(300, help="refinement iterations in the full decode"),
    every: int = typer.Option(3, help="score every n-th view the encoder did not send"),
    out: Path = typer.Option(Path("bench/restorer.md")),
) -> None:
    torch.set_num_threads(1)
    cmd = "python tools/bench_restorer.py " + " ".join(sys.argv[1:])
    model = load_restorer(restorer).model
    lines = [
        "# Restorer",
        "",
        f"Command: `{cmd}` (one torch thread, shared 2-core CPU).",
        "",
        f"Restorer `{restorer}`: NAFNet with {count_parameters(model)} parameters "
        "(see gspc/restore/weights/MODEL_CARD.md). All scenes below were held out of its training.",
        "",
        "## Restoration of held-out views",
        "",
        "PSNR against the original render, both clamped and quantised to 8 bits, averaged over views.",
        "I~ + R~ is the side information alone (restorer `none`); R~ is coded at the encoder's planned",
        "JPEG XL distance per view (views whose residual RMS is below 1/255 get none: R~ = 0).",
        "",
    ]
    table, _ = restoration_table(data, restorer)
    lines += table
    secs = inference_seconds(restorer)
    lines += [
        "",
        "## Speed",
        "",
        f"Restoring one 400x300 view: {secs:.3f} s on one CPU thread (median of 5).",
        "",
    ]
    if scene:
        lines += [
            "## Full decode",
            "",
            f"Encode at the `{quality}` preset (60 synthesised views, 40% sent as side information), decode",
            f"with {iterations} refinement iterations; PSNR of the decoded scene's renders against the",
            f"original's at every n-th view the encoder did not send (n = {every}; 8-bit).",
            "",
            "| scene | preset | decode | bytes | PSNR dB | decode s |",
            "|---|---|---|---|---|---|",
        ]
        for s in scene:
            lines += pipeline_rows(s, restorer, quality, iterations, every)
        lines.append("")
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(json.dumps({"inference_s_400x300": secs}))


if __name__ == "__main__":
    typer.run(main)
