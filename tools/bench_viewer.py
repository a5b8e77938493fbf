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
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parent.parent

from gspc.io import read_scene, write_ply  # noqa: E402
from gspc.io.camera_files import load_cameras  # noqa: E402
from gspc.metrics import mean_psnr, mse  # noqa: E402
from gspc.options import DecodeOptions, EncodeOptions  # noqa: E402
from gspc.pipeline import decode_bytes, encode_scene  # noqa: E402
from gspc.reconstruct import render_images  # noqa: E402
from gspc.views import limit_size, synthesize_views  # noqa: E402

SHARED = REPO.parent / "shared" / "data"


def scene_and_cameras(name: str):
    if name == "lego":
        d = REPO / "examples" / "lego"
        return read_scene(d / "point_cloud.ply"), limit_size(load_cameras(d / "cameras.json"), 400), (1, 1, 1)
    s = read_scene(SHARED / "statues" / f"{name}.sog")
    return s, synthesize_views(s, 64, 320, 320), (0, 0, 0)


def scores(scene, held, refs, bg) -> tuple[float, float]:
    imgs = render_images(scene, held, bg)
    fl = float(np.mean([-10 * math.log10(max(float(mse(a, b)), 1e-12)) for a, b in zip(imgs, refs)]))
    return fl, mean_psnr(imgs, refs)


def splat_transform(npm: Path, src: Path, out: Path) -> None:
    tool = npm / "node_modules" / ".bin" / "splat-transform"
    subprocess.run([str(tool), "-w", "-g", "cpu", str(src), str(out)], check=True, capture_output=True)


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
        scene, cams, bg = scene_and_cameras(name)
        train, held = [c for i, c in enumerate(cams) if i % 8], cams[::8]
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
                splat_transform(args.npm_dir, src, out)
                row(
                    f"{ext.upper()} (splat-transform)",
                    out.stat().st_size,
                    read_scene(out),
                    time.perf_counter() - t0,
                )


if __name__ == "__main__":
    sys.exit(main())
