"""Coding to a fidelity: ``--target-psnr`` at several targets per scene, the PSNR the encoder reports against
what held-out views show, the bytes and the codings it took (bench/precision.md, "Coding to a fidelity");
with ``--presets``, each preset at its rate (``--lambda``, what it coded before it aimed at a fidelity) and
as it is, side by side (bench/precision.md, "Presets that aim at a fidelity").

    GSPC_THREADS=1 python tools/bench_fidelity.py [--scenes lego,massa] [--targets 36,40,44] [--starts 8,30]
    GSPC_THREADS=1 python tools/bench_fidelity.py --presets low,medium,high [--scenes ...]

Per scene and target: an encode without side information (what a file for viewers holds, and the measure
the presets aim at) of the scene at all but every eighth of its cameras; the PSNR the encoder reached at its
own views (between its cameras), and the float PSNR of the decoded attributes against the original's renders
at the held-out cameras, which the encoder does not see.
"""

from __future__ import annotations

import argparse
import time

import torch
from bench_setups import bench_scene, float_psnr, held_out

from gspc.encoder.removal import RemovalParams, scorer, scoring_views
from gspc.options import EncodeOptions
from gspc.pipeline import decode_bytes, encode_scene
from gspc.presets import quality_preset
from gspc.reconstruct import render_images


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="lego,massa")
    ap.add_argument("--targets", default="36,40,44")
    ap.add_argument("--presets", default="", help="compare these presets at their rate and as they are")
    ap.add_argument(
        "--starts", default="", help="lambdas each search starts from (the removal and grid trials run there)"
    )
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.presets:
        return presets(args.scenes.split(","), args.presets.split(","))
    starts = [float(x) for x in args.starts.split(",")] if args.starts else [None]
    print(
        "| scene | target dB | started at | reached dB (its views) | held-out dB | bytes | lambda | "
        "codings | seconds | trials kept |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for name in args.scenes.split(","):
        scene, cams, bg = bench_scene(name)
        train, held = held_out(cams)
        refs = render_images(scene, held, bg)
        for target, start in ((float(t), x) for t in args.targets.split(",") for x in starts):
            opts = EncodeOptions(side_info=False, background=bg, target_psnr=target, lam=start)
            data, rep, held_db, seconds = coded_point(scene, train, held, refs, opts)
            fid = rep.decisions.fidelity
            kept = rep.info.get("removal", "no search").split(":")[0]
            print(
                f"| {name} | {target:g} | {'the preset' if start is None else f'lambda {start:g}'} | "
                f"{fid.psnr_db:.2f} | {held_db:.2f} | {len(data):,} | {fid.encoded.lam:.3g} | "
                f"{fid.codings} | {seconds:.1f} | {kept} |",
                flush=True,
            )


def coded_point(scene, train, held, refs, opts: EncodeOptions) -> tuple[bytes, object, float, float]:
    """(file, report, held-out PSNR, encode seconds) of ``scene`` encoded at ``train`` with ``opts``."""
    t0 = time.perf_counter()
    data, rep = encode_scene(scene, train, opts)
    seconds = time.perf_counter() - t0
    dec, _ = decode_bytes(data)
    return data, rep, float_psnr(render_images(dec, held, opts.background), refs), seconds


def presets(names: list[str], qualities: list[str]) -> None:
    """Each preset at its starting rate and as it is (aiming at its fidelity), per scene."""
    print(
        "| scene | Gaussians | SH | preset | coded to | its views dB | held-out dB | bytes | B/G | lambda | "
        "seconds |"
    )
    print("|---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|")
    for name in names:
        scene, cams, bg = bench_scene(name)
        train, held = held_out(cams)
        refs = render_images(scene, held, bg)
        score = scorer(scene, scoring_views(train, scene.num_gaussians, RemovalParams()), bg)
        for q in qualities:
            preset = quality_preset(q)
            for lam in (preset.attributes.lam, None):
                opts = EncodeOptions(quality=q, side_info=False, background=bg, lam=lam)
                data, rep, held_db, seconds = coded_point(scene, train, held, refs, opts)
                enc = rep.decisions.attributes
                how = f"lambda {lam:g}" if lam is not None else f"{preset.target_db:g} dB"
                per = len(data) / scene.num_gaussians
                print(
                    f"| {name} | {scene.num_gaussians:,} | {scene.sh_degree} | {q} | {how} | "
                    f"{score(enc):.2f} | {held_db:.2f} | {len(data):,} | {per:.2f} | {enc.lam:.3g} | "
                    f"{seconds:.1f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
