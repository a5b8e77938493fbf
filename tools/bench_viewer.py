"""What a viewer shows: the attributes as they decode (no restorer, no refinement), against gspc's full
decode, a file made for viewers (``--quality web``) and the formats viewers read today, SPZ v4 and SOG, side
by side (bench/web.md, "What a viewer shows").

    GSPC_THREADS=1 python tools/bench_viewer.py --npm-dir /tmp/interop-npm [--scenes lego,massa] [--sog]

Per scene, at held-out views (every eighth camera, which no encoder sees), float and 8-bit PSNR against the
original's renders of: the default file decoded in full (what ``gspc decode`` writes) and as a viewer draws it
(``--no-refine``), the web preset's file, and SPZ v4 and SOG made by splat-transform (npm, ``-g cpu``) from
the same original, read back by gspc's readers and rendered by gspc's renderer.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import torch
from bench_setups import bench_scene, float_psnr, held_out, splat_transform

from gspc.io import read_scene, write_ply
from gspc.metrics import mean_psnr
from gspc.options import DecodeOptions, EncodeOptions
from gspc.pipeline import decode_bytes, encode_scene
from gspc.reconstruct import render_images


def scores(scene, held, refs, bg) -> tuple[float, float]:
    """(float, 8-bit) PSNR of ``scene`` against ``refs`` at the held-out cameras."""
    imgs = render_images(scene, held, bg)
    return float_psnr(imgs, refs), mean_psnr(imgs, refs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="lego,massa")
    ap.add_argument("--npm-dir", type=Path, default=None, help="a folder with @playcanvas/splat-transform")
    ap.add_argument("--sog", action="store_true", help="also SOG (its SH k-means takes minutes)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    print("| scene | what | bytes | B/Gaussian | held-out PSNR dB (float / 8-bit) | seconds |")
    print("|---|---|---:|---:|---|---:|")
    for name in args.scenes.split(","):
        scene, cams, bg = bench_scene(name)
        train, held = held_out(cams)
        refs = render_images(scene, held, bg)
        n = scene.num_gaussians

        def row(what: str, size: int, s, seconds: float, held=held, refs=refs, bg=bg, name=name, n=n) -> None:
            fl, b8 = scores(s, held, refs, bg)
            print(
                f"| {name} | {what} | {size:,} | {size / n:.2f} | {fl:.2f} / {b8:.2f} | {seconds:.0f} |",
                flush=True,
            )

        for quality in ("low", "web"):
            t0 = time.perf_counter()
            data, rep = encode_scene(scene, train, EncodeOptions(quality=quality, background=bg))
            enc = time.perf_counter() - t0
            t0 = time.perf_counter()
            full, _ = decode_bytes(data)
            row(f"gspc {quality}, full decode", len(data), full, enc + time.perf_counter() - t0)
            if quality == "low":
                viewer, _ = decode_bytes(data, DecodeOptions(refine=False))
                row("gspc low, as a viewer draws it", len(data), viewer, 0.0)
        if args.npm_dir is None:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            src = Path(tmp) / "in.ply"
            write_ply(scene, src)
            for ext, on in (("spz", True), ("sog", args.sog)):
                if not on:
                    continue
                out = Path(tmp) / f"out.{ext}"
                t0 = time.perf_counter()
                res, _ = splat_transform(args.npm_dir, src, out, "-g", "cpu")
                if res.returncode:
                    raise SystemExit(f"splat-transform failed on {out.name}: {res.stderr.strip()[-300:]}")
                row(
                    f"{ext.upper()} (splat-transform)",
                    out.stat().st_size,
                    read_scene(out),
                    time.perf_counter() - t0,
                )


if __name__ == "__main__":
    sys.exit(main())
