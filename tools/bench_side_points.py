"""Single rate points beside bench_pipeline's tables: the codec alone at extra lambdas or at a total size, and
side information at a forced residual resolution. Prints a Markdown table (PSNR vs the original's renders at
the same held-out views as bench_pipeline).

    python tools/bench_side_points.py donut --codec-lams 40,48,56 --forced 64:2,64:4
    python tools/bench_side_points.py massa --codec-bytes 452000
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import torch
import typer
from bench_setups import SHARED, fit_setup, run_point, synth_setup

from gspc.io import read_scene
from gspc.reconstruct import render_images


def main(
    scene: str = typer.Argument(..., help="donut, a statue name, or a lego fit folder"),
    codec_lams: str = typer.Option("", help="lambdas for the codec alone"),
    codec_bytes: str = typer.Option("", help="attribute bytes for the codec alone (--target-size)"),
    forced: str = typer.Option("", help="lambda:scale pairs: side information at that resolution, check off"),
) -> None:
    torch.set_num_threads(1)
    if Path(scene).is_dir():
        s = fit_setup(Path(scene))
    elif scene == "donut":
        s = synth_setup("donut", SHARED / "donut" / "fused.ply")
    else:
        s = synth_setup(scene, SHARED / "statues" / f"{scene}.sog")
    ref = render_images(read_scene(s.scene_path), s.eval_cams, s.background)
    print("| point | bytes | side info | PSNR vs original |\n|---|---|---|---|")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        plain = dict(side_info=False, refine=False, restore=False)
        for lam in [float(x) for x in codec_lams.split(",") if x]:
            r = run_point(s, tmp, ref, lam=lam, tag="c", **plain)
            print(f"| codec, lambda {lam:g} | {r['bytes']:,} | 0 | {r['psnr']:.2f} |", flush=True)
        for n in [int(x) for x in codec_bytes.split(",") if x]:
            r = run_point(s, tmp, ref, target_size=n, tag="t", **plain)
            print(f"| codec, --target-size {n:,} | {r['bytes']:,} | 0 | {r['psnr']:.2f} |", flush=True)
        for pair in [x for x in forced.split(",") if x]:
            lam, scale = pair.split(":")
            r = run_point(s, tmp, ref, lam=float(lam), residual_scale=int(scale), check=False, tag="f")
            print(
                f"| lambda {lam}, residuals at 1/{scale} ({r['refine']}) | {r['bytes']:,} | {r['side']:,} "
                f"| {r['psnr']:.2f} |",
                flush=True,
            )


if __name__ == "__main__":
    typer.run(main)
