"""The SH choices checked per scene: the encoder's trial of every SH band kept without a dead zone, in the
same bytes, against the presets' fixed SH rules (bench/precision.md, "SH choices checked per scene").

    GSPC_THREADS=1 python tools/bench_sh_choices.py [--scenes lego,glossy,massa]

Per scene and preset, the default encode (no side information, as a viewer gets it) with the SH trial and
without it (RemovalParams.sh_options empty): bytes, the SH choice kept, and float PSNR against the original's
renders at held-out views (every eighth of the scene's cameras, which the encoder does not see).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tools"))

from scenes import glossy_scene  # noqa: E402

import gspc.encoder.decisions as decisions  # noqa: E402
from gspc.io import read_scene  # noqa: E402
from gspc.io.camera_files import load_cameras  # noqa: E402
from gspc.metrics import mse  # noqa: E402
from gspc.options import EncodeOptions  # noqa: E402
from gspc.pipeline import decode_bytes, encode_scene  # noqa: E402
from gspc.reconstruct import render_images  # noqa: E402
from gspc.views import limit_size, synthesize_views  # noqa: E402

SHARED = REPO.parent / "shared" / "data"


def scene_and_cameras(name: str):
    if name == "lego":
        d = REPO / "examples" / "lego"
        return read_scene(d / "point_cloud.ply"), limit_size(load_cameras(d / "cameras.json"), 400), (1, 1, 1)
    if name == "glossy":
        s = glossy_scene()
        return s, synthesize_views(s, 64, 320, 320), (0, 0, 0)
    s = read_scene(SHARED / "statues" / f"{name}.sog")
    return s, synthesize_views(s, 64, 320, 320), (0, 0, 0)


def psnr(a, b) -> float:
    return float(np.mean([-10 * math.log10(max(float(mse(x, y)), 1e-12)) for x, y in zip(a, b)]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="lego,glossy,massa")
    args = ap.parse_args()
    torch.set_num_threads(1)
    print("| scene | preset | SH trial | bytes | held-out PSNR dB | kept | encode s |")
    print("|---|---|---|---:|---:|---|---:|")
    real = decisions.removal_params
    for name in args.scenes.split(","):
        scene, cams, bg = scene_and_cameras(name)
        train = [c for i, c in enumerate(cams) if i % 8]
        held = cams[::8]
        refs = render_images(scene, held, bg)
        for quality in ("low", "high"):
            for trial in (True, False):
                decisions.removal_params = (
                    real
                    if trial
                    else (lambda opts: replace(real(opts), sh_options=()) if real(opts) else None)
                )
                t0 = time.perf_counter()
                opts = EncodeOptions(quality=quality, side_info=False, background=bg)
                data, rep = encode_scene(scene, train, opts)
                seconds = time.perf_counter() - t0
                dec, _ = decode_bytes(data)
                p = psnr(render_images(dec, held, bg), refs)
                kept = rep.decisions.removal.chosen() if rep.decisions.removal else "no search"
                print(
                    f"| {name} | {quality} | {'on' if trial else 'off'} | {len(data):,} | {p:.2f} | {kept} | "
                    f"{seconds:.0f} |",
                    flush=True,
                )
    decisions.removal_params = real


if __name__ == "__main__":
    main()
