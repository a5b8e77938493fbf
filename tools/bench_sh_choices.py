"""The SH choices checked per scene: the encoder's trials of SH rules that drop less view-dependent colour, in
the same bytes, against the presets' fixed SH rules (bench/precision.md, "SH choices checked per scene").

    GSPC_THREADS=1 python tools/bench_sh_choices.py [--scenes lego,glossy,glossy-faint,massa]
        [--presets low,high] [--variants off,bands,faint,both] [--lam 8]

A scene is one of tools/bench_setups.py bench_scene's names or a tools/fit_scene.py output folder (the
bird: /work/fits/bird_q4_100k). Per scene, preset and variant of the trials (RemovalParams.sh_options:
``off`` none; ``bands`` every band kept, no dead zone; ``faint`` that and faint Gaussians' SH rest kept
too; ``both`` the two in turn; ``book``, ``book1024`` the SH rest by a codebook of up to 4,096 or 1,024
entries; ``faint-book`` ``faint`` then ``book``; ``preset`` the preset's own), the default encode (no side
information, as a viewer gets it): bytes, the SH rules kept, and float PSNR against the original's renders
at held-out views (every eighth of the scene's cameras, or the fit's own held-out ones, which the encoder
does not see).
``--lam``: at that rate instead of the preset's fidelity (equal bytes but for the trials' own search).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import torch
from bench_setups import bench_scene, fit_setup, float_psnr, held_out

import gspc.encoder.decisions as decisions
from gspc.cameras import Camera
from gspc.encoder.params import CodecParams, SHRules
from gspc.io import read_scene
from gspc.options import EncodeOptions
from gspc.pipeline import decode_bytes, encode_scene
from gspc.reconstruct import render_images
from gspc.scene import GaussianScene

BANDS = SHRules(0.0, 0.0, CodecParams().sh_faint_alpha)  # every band, faint Gaussians still without
FAINT = SHRules(0.0, 0.0, 0.0)
# The SH rest by a codebook (attribute codec version 5) of as many entries as the rate asks, at most 4,096 or
# 1,024 (gspc/encoder/codebook.py), the preset's bands and faint Gaussians deciding which Gaussians carry one.
BOOK = SHRules(4.0, 0.0, CodecParams().sh_faint_alpha, 4096)
BOOK1024 = replace(BOOK, codebook=1024)
VARIANTS: dict[str, tuple[SHRules, ...] | None] = {
    "off": (),
    "bands": (BANDS,),
    "faint": (FAINT,),
    "both": (BANDS, FAINT),
    "book": (BOOK,),
    "book1024": (BOOK1024,),
    "faint-book": (FAINT, BOOK),
    "preset": None,
}


def scene_and_views(
    name: str,
) -> tuple[GaussianScene, list[Camera], list[Camera], tuple[float, float, float]]:
    """(scene, the encoder's cameras, held-out cameras, background) of bench_scene's ``name``, or of a
    tools/fit_scene.py output folder (its own held-out photos' cameras)."""
    if Path(name).is_dir():
        s = fit_setup(Path(name))
        return read_scene(s.scene_path), s.train_cams, s.eval_cams, s.background
    scene, cams, bg = bench_scene(name)
    return (scene, *held_out(cams), bg)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="lego,glossy,glossy-faint,massa")
    ap.add_argument("--presets", default="low,high")
    ap.add_argument("--variants", default="off,preset")
    ap.add_argument("--lam", type=float, default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    print("| scene | preset | SH trials | bytes | held-out PSNR dB | kept | encode s |")
    print("|---|---|---|---:|---:|---|---:|")
    real = decisions.removal_params
    for name in args.scenes.split(","):
        scene, train, held, bg = scene_and_views(name)
        refs = render_images(scene, held, bg)
        for quality in args.presets.split(","):
            for variant in args.variants.split(","):
                options = VARIANTS[variant]

                def params(opts, options=options):
                    rp = real(opts)
                    return rp if rp is None or options is None else replace(rp, sh_options=options)

                decisions.removal_params = params
                t0 = time.perf_counter()
                opts = EncodeOptions(quality=quality, side_info=False, background=bg, lam=args.lam)
                data, rep = encode_scene(scene, train, opts)
                seconds = time.perf_counter() - t0
                dec, _ = decode_bytes(data)
                p = float_psnr(render_images(dec, held, bg), refs)
                kept = rep.decisions.removal.chosen() if rep.decisions.removal else "no search"
                print(
                    f"| {name} | {quality} | {variant} | {len(data):,} | {p:.2f} | {kept} | {seconds:.0f} |",
                    flush=True,
                )
    decisions.removal_params = real


if __name__ == "__main__":
    main()
