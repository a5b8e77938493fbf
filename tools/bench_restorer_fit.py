"""Full decode of a real fit with several restorers: their effect after refinement, on views they never saw.

    python tools/bench_restorer_fit.py /work/fits/bird_q4_100k \
        --side-cameras /work/restorer_cams/bird_unseen.json \
        --restorers none,nafnet-s16-v2,nafnet-s16-v3 --iterations 500

Encodes the fit (a tools/fit_scene.py folder) once at the low preset with side information from
``--side-cameras`` only (pick cameras the restorers were not trained on) and the encoder's check off, then
decodes the same file with each restorer and scores the result at the fit's held-out photos' poses, against
the original's renders and the photos. Prints a Markdown table; one torch thread.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import torch
import typer
from bench_setups import fit_setup, score

from gspc.io import read_scene
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode
from gspc.reconstruct import render_images


def main(
    fit: Path = typer.Argument(..., help="tools/fit_scene.py output folder"),
    side_cameras: Path = typer.Option(..., help="cameras (JSON) the side information is taken from"),
    restorers: str = typer.Option("none,nafnet-s16-v3", help="comma-separated restorer names"),
    iterations: int = typer.Option(500, help="refinement iterations of every decode"),
    max_side: int = typer.Option(240, help="the encoder's view size limit"),
) -> None:
    torch.set_num_threads(1)
    s = fit_setup(fit)
    ref = render_images(read_scene(s.scene_path), s.eval_cams, s.background)
    with tempfile.TemporaryDirectory() as tmp:
        coded = Path(tmp) / "scene.gspc"
        opts = EncodeOptions(check_iterations=0, max_side=max_side, background=s.background)
        encode(s.scene_path, coded, side_cameras, opts)
        size = coded.stat().st_size
        print(f"{fit.name}: {size:,} B, low preset, side information from {side_cameras.name}")
        print("| restorer | PSNR vs original's renders | PSNR vs photos | decode s |\n|---|---|---|---|")
        for name in [r for r in restorers.split(",") if r]:
            out = Path(tmp) / f"{name}.ply"
            t0 = time.perf_counter()
            decode(coded, out, DecodeOptions(iterations=iterations, restorer=name))
            secs = time.perf_counter() - t0
            r = score(out, s, ref)
            print(f"| {name} | {r['psnr']:.2f} | {r['psnr_photo']:.3f} | {secs:.0f} |", flush=True)


if __name__ == "__main__":
    typer.run(main)
