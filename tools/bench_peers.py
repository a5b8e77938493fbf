"""gspc's attribute codec against real peers on the same scene: SPZ and PlayCanvas SOG, bytes at equal PSNR.

    npm install --prefix /tmp/gspc-spz-npm @playcanvas/splat-transform@3.7.0
    python tools/bench_peers.py /work/fits/bird_q4_120k --npm-dir /tmp/gspc-spz-npm -o bench/peers.md

The scene is a tools/fit_scene.py output (point_cloud.ply, cameras.json, test/*.png held-out photos,
fit.json). Peers are written by splat-transform (SPZ v4 through Niantic's C++ in WASM; SOG with `-g cpu`,
whose SH k-means is seeded by Math.random, so SOG bytes vary a little between runs) and read back by gspc's
own readers.
gspc is the attribute codec alone (`--no-side-info`, decode without refinement) over a lambda sweep; its bytes
at each peer's PSNR are interpolated (linear in log bytes) between the two nearest points of that curve.
All PSNRs: 8-bit renders at the held-out views against the original scene's renders, and against the photos.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import torch
import typer
from bench_setups import bytes_at, fit_setup, held_out_line, splat_transform

from gspc.io import read_scene
from gspc.io.cameras_json import save_cameras_json
from gspc.metrics import mean_psnr
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode, render_images


def main(
    fit: Path = typer.Argument(..., help="tools/fit_scene.py output folder"),
    npm_dir: Path = typer.Option(Path("/tmp/gspc-spz-npm"), help="where splat-transform is installed"),
    lams: str = typer.Option("0.5,1,2,4,8,16,32", help="lambdas of gspc's curve"),
    peers: str = typer.Option("spz,sog", help="peers to run: spz, sog"),
    sog_iterations: int = typer.Option(
        10,
        help="splat-transform's SH k-means iterations for SOG (its default, 10, ran over 100 CPU min here)",
    ),
    out: Path = typer.Option(Path("bench/peers.md"), "-o"),
) -> None:
    torch.set_num_threads(1)
    setup = fit_setup(fit)
    ply, bg, eval_cams, photos = setup.scene_path, setup.background, setup.eval_cams, setup.photos
    scene = read_scene(ply)
    ref = render_images(scene, eval_cams, bg)
    rows = [
        f"| original PLY | {ply.stat().st_size:,} | {ply.stat().st_size / scene.num_gaussians:.2f} | ∞ | "
        f"{mean_psnr(ref, photos):.2f} | | |"
    ]
    tmp = Path(tempfile.mkdtemp())
    cams_file = tmp / "train.json"
    save_cameras_json(setup.train_cams, cams_file)
    max_side = max(max(c.width, c.height) for c in [*setup.train_cams, *eval_cams])

    curve = []
    for lam in [float(x) for x in lams.split(",")]:
        g, o = tmp / f"l{lam}.gspc", tmp / f"l{lam}.ply"
        t0 = time.perf_counter()
        encode(ply, g, cams_file, EncodeOptions(lam=lam, side_info=False, max_side=max_side, background=bg))
        enc_s = time.perf_counter() - t0
        decode(g, o, DecodeOptions(refine=False, restore=False))
        imgs = render_images(read_scene(o), eval_cams, bg)
        p, n = mean_psnr(imgs, ref), g.stat().st_size
        curve.append((n, p))
        rows.append(
            f"| gspc lambda {lam:g} | {n:,} | {n / scene.num_gaussians:.2f} | {p:.2f} | "
            f"{mean_psnr(imgs, photos):.2f} | {enc_s:.1f} | |"
        )
        print(rows[-1], flush=True)

    for peer in [x for x in peers.split(",") if x]:
        path = tmp / f"peer.{peer}"
        sog = ["-g", "cpu", "-i", str(sog_iterations)]
        res, secs = splat_transform(npm_dir, ply, path, *(sog if peer == "sog" else []))
        if res.returncode != 0:
            rows.append(f"| {peer} | failed: {res.stderr.strip()[-80:]} | | | | | |")
            continue
        imgs = render_images(read_scene(path), eval_cams, bg)
        p, n = mean_psnr(imgs, ref), path.stat().st_size
        ours = bytes_at(curve, p)
        ratio = f"{ours / n:.3f} ({ours:,.0f} B)" if ours else "outside gspc's curve"
        name = f"{peer} (splat-transform 3.7.0" + (f", -i {sog_iterations})" if peer == "sog" else ")")
        rows.append(
            f"| {name} | {n:,} | {n / scene.num_gaussians:.2f} | {p:.2f} | "
            f"{mean_psnr(imgs, photos):.2f} | {secs:.1f} | {ratio} |"
        )
        print(rows[-1], flush=True)

    text = "\n".join(
        [
            f"# gspc's attribute codec against real peers: {fit.name}",
            "",
            f"Command: `python {' '.join(sys.argv)}`",
            "",
            held_out_line(scene, eval_cams) + ", other jobs running. Codec alone (no side "
            "information, no refinement).",
            "",
            "| coder | bytes | B/Gaussian | PSNR vs original | PSNR vs photos | encode s | gspc bytes at "
            "this PSNR / peer bytes |",
            "|---|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    typer.run(main)
