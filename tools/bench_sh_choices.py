"""The SH choices checked per scene: the encoder's trial of every SH band kept without a dead zone, in the
same bytes, against the presets' fixed SH rules (bench/precision.md, "SH choices checked per scene").

    GSPC_THREADS=1 python tools/bench_sh_choices.py [--scenes lego,glossy,massa]

Per scene and preset, the default encode (no side information, as a viewer gets it) with the SH trial and
without it (RemovalParams.sh_options empty): bytes, the SH choice kept, and float PSNR against the original's
renders at held-out views (every eighth of the scene's cameras, which the encoder does not see).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import torch
from bench_setups import bench_scene, float_psnr, held_out

import gspc.encoder.decisions as decisions
from gspc.options import EncodeOptions
from gspc.pipeline import decode_bytes, encode_scene
from gspc.reconstruct import render_images


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="lego,glossy,massa")
    args = ap.parse_args()
    torch.set_num_threads(1)
    print("| scene | preset | SH trial | bytes | held-out PSNR dB | kept | encode s |")
    print("|---|---|---|---:|---:|---|---:|")
    real = decisions.removal_params
    for name in args.scenes.split(","):
        scene, cams, bg = bench_scene(name)
        train, held = held_out(cams)
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
                p = float_psnr(render_images(dec, held, bg), refs)
                kept = rep.decisions.removal.chosen() if rep.decisions.removal else "no search"
                print(
                    f"| {name} | {quality} | {'on' if trial else 'off'} | {len(data):,} | {p:.2f} | {kept} | "
                    f"{seconds:.0f} |",
                    flush=True,
                )
    decisions.removal_params = real


if __name__ == "__main__":
    main()
