"""Residual side-information codecs: bytes vs PSNR of R~ against R, and the per-view rate plan.

Until gspc's attribute codec produces real degraded renders, residuals are synthesised from the
lego training photos (../shared/data/lego/train): each RGBA PNG is composited on white and
2x2-averaged to 400x400 (I); I~ is I blurred with a Gaussian of sigma s and quantised to L levels
per channel (a stand-in for the smoothing and colour loss of attribute compression); R = I - I~.
Views use different (s, L) so residual energy varies as it does across real views.

PSNR of R~ against R (peak 1) equals the PSNR of I~ + R~ against I.

    python tools/bench_residual_codecs.py [--views 8] [--out bench/residual_codecs.md]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import imagecodecs
import numpy as np
import torch
from scipy.ndimage import gaussian_filter

from gspc.codec.residuals import (
    IMAGE_CODECS,
    ResidualParams,
    decode_residual,
    encode_residual,
    plan_residual_rates,
    quality_for_distance,
)
from gspc.restore.nafnet import NAFNet, count_parameters
from gspc.restore.restorer import Restorer

NAFNET_CONFIGS = {
    "small": {"width": 16, "enc_blocks": [1, 1, 1], "middle_blocks": 1, "dec_blocks": [1, 1, 1]},
    "medium": {"width": 32, "enc_blocks": [1, 1, 1, 1], "middle_blocks": 1, "dec_blocks": [1, 1, 1, 1]},
    "NAFNet-width32": {
        "width": 32,
        "enc_blocks": [1, 1, 1, 28],
        "middle_blocks": 1,
        "dec_blocks": [1, 1, 1, 1],
    },
}
DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "lego" / "train"
# Distances (gspc/codec/residuals.py): WebP's are qualities 5, 20, 40, 60, 80, 95 and AVIF's 10, 25, 40, 55,
# 70, 85 (quality = 100 - 10 distance).
KNOBS = {"jxl": [0.5, 1, 2, 3, 4, 6, 8], "webp": [9.5, 8, 6, 4, 2, 0.5], "avif": [9, 7.5, 6, 4.5, 3, 1.5]}
# (blur sigma, quantisation levels) per view, cycling: mild to strong degradation.
DEGRADE = [(0.6, 64), (1.0, 32), (1.5, 24), (0.8, 48), (2.0, 16), (0.5, 128), (1.2, 32), (0.7, 96)]


def load_views(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(I, R) pairs, float32 400x400x3."""
    out = []
    for i in range(n):
        rgba = imagecodecs.png_decode((DATA / f"r_{i * 7}.png").read_bytes()).astype(np.float32) / 255
        rgb = rgba[..., :3] * rgba[..., 3:] + (1 - rgba[..., 3:])
        img = rgb.reshape(400, 2, 400, 2, 3).mean((1, 3))
        sigma, levels = DEGRADE[i % len(DEGRADE)]
        deg = np.round(gaussian_filter(img, (sigma, sigma, 0)) * (levels - 1)) / (levels - 1)
        out.append((img, (img - deg).astype(np.float32)))
    return out


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / max(np.mean((a.astype(np.float64) - b) ** 2), 1e-20)))


def run(residuals, params: ResidualParams) -> tuple[int, float, float, float]:
    """Total bytes, mean PSNR, mean encode ms, mean decode ms over views."""
    size, scores, enc_t, dec_t = 0, [], [], []
    for r in residuals:
        t0 = time.perf_counter()
        payload, meta = encode_residual(r, params)
        t1 = time.perf_counter()
        rt = decode_residual(payload, meta)
        t2 = time.perf_counter()
        size += len(payload)
        scores.append(psnr(rt, r))
        enc_t.append(t1 - t0)
        dec_t.append(t2 - t1)
    return size, float(np.mean(scores)), 1e3 * float(np.mean(enc_t)), 1e3 * float(np.mean(dec_t))


def run_plan(residuals, distances) -> tuple[int, float, float]:
    """Total bytes, mean PSNR and PSNR of the mean MSE when view i uses distance[i] (None: R~ = 0)."""
    size, scores = 0, []
    for r, d in zip(residuals, distances, strict=True):
        rt = np.zeros_like(r)
        if d is not None:
            payload, meta = encode_residual(r, ResidualParams(codec="jxl", distance=d))
            size += len(payload)
            rt = decode_residual(payload, meta)
        scores.append(psnr(rt, r))
    mse = np.mean([10 ** (-s / 10) for s in scores])
    return size, float(np.mean(scores)), float(-10 * np.log10(mse))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--out", default="bench/residual_codecs.md")
    args = ap.parse_args()
    torch.set_num_threads(1)
    if not DATA.is_dir():
        sys.exit(f"{DATA} not found")
    views = load_views(args.views)
    res = [r for _, r in views]
    pixels = sum(r.shape[0] * r.shape[1] for r in res)
    rms = [float(np.sqrt(np.mean(r**2))) for r in res]
    base = float(np.mean([psnr(np.zeros_like(r), r) for r in res]))

    lines = [
        "# Residual side-information codecs",
        "",
        f"Command: `python tools/bench_residual_codecs.py --views {args.views}` (one torch thread, shared",
        "2-core CPU).",
        "",
        f"Data: {args.views} synthetic residuals R = I - I~ at 400x400 from lego/train (r_0, r_7, ...):",
        "I is the photo on white, 2x2-averaged; I~ is I Gaussian-blurred (sigma 0.5-2) and quantised to",
        "16-128 levels per channel (a stand-in until real compressed-scene renders exist).",
        f"Residual RMS per view: {', '.join(f'{v:.4f}' for v in rms)}. Sending nothing (R~ = 0) scores "
        f"{base:.2f} dB.",
        "PSNR is of R~ against R with peak 1 (= PSNR of I~ + R~ against I), averaged over views; bytes are",
        "per view; bpp over all pixels. 8-bit mapping, gain from the 99.9th percentile of |R|.",
        "",
        "## Codecs over their quality knobs",
        "",
        "| codec | knob | bytes/view | bpp | PSNR dB | encode ms | decode ms |",
        "|---|---|---|---|---|---|---|",
    ]
    for codec in IMAGE_CODECS:
        for distance in KNOBS[codec]:
            size, score, te, td = run(res, ResidualParams(codec=codec, distance=distance))
            knob = f"distance {distance}" if codec == "jxl" else f"quality {quality_for_distance(distance):g}"
            lines.append(
                f"| {codec} | {knob} | {size // len(res)} | {8 * size / pixels:.3f} | {score:.2f} "
                f"| {te:.1f} | {td:.1f} |"
            )
    for level in [0.5, 1, 2, 4]:
        size, score, te, td = run(res, ResidualParams(codec="jxl", distance=level, bits=16))
        lines.append(
            f"| jxl 16-bit | distance {level} | {size // len(res)} | {8 * size / pixels:.3f} | {score:.2f} "
            f"| {te:.1f} | {td:.1f} |"
        )

    lines += [
        "",
        "## Gain percentile (jxl distance 2)",
        "",
        "| percentile | bytes/view | PSNR dB |",
        "|---|---|---|",
    ]
    for pct in [99.0, 99.9, 100.0]:
        size, score, _, _ = run(res, ResidualParams(codec="jxl", distance=2, percentile=pct))
        lines.append(f"| {pct} | {size // len(res)} | {score:.2f} |")

    lines += [
        "",
        "## Per-view rate plan (jxl): uniform distance vs plan_residual_rates",
        "",
        "Plan: distance = base * clip((median RMS / RMS) ** strength, 0.5, 2); views below 1/255 RMS",
        "skipped.",
        "",
        "| rule | base | total bytes | mean PSNR dB | PSNR of mean MSE dB |",
        "|---|---|---|---|---|",
    ]
    for d in [1, 1.5, 2, 3, 4]:
        size, score, pooled = run_plan(res, [d] * len(res))
        lines.append(f"| uniform | {d} | {size} | {score:.2f} | {pooled:.2f} |")
    for strength in [-0.5, 0.5, 1.0]:
        for d in [1, 1.5, 2, 3, 4]:
            size, score, pooled = run_plan(res, plan_residual_rates(res, d, strength=strength))
            lines.append(f"| plan, strength {strength} | {d} | {size} | {score:.2f} | {pooled:.2f} |")

    lines += [
        "",
        "## Zeroing quiet 32x32 tiles before coding (jxl distance 2)",
        "",
        "| zero_rms | bytes/view | PSNR dB |",
        "|---|---|---|",
    ]
    for zr in [0.0, 0.5 / 255, 1 / 255, 2 / 255]:
        size, score, _, _ = run(res, ResidualParams(codec="jxl", distance=2, zero_rms=zr))
        lines.append(f"| {zr:.5f} | {size // len(res)} | {score:.2f} |")

    lines += [
        "",
        "## NAFNet restorer cost (untrained weights; one 400x300 view, best of 3, one thread)",
        "",
        "| config | parameters | untiled s | tiles of 256 (overlap 48) s |",
        "|---|---|---|---|",
    ]
    deg = torch.rand(300, 400, 3, generator=torch.Generator().manual_seed(0))
    resid = 0.03 * torch.randn(300, 400, 3, generator=torch.Generator().manual_seed(1))
    for name, cfg in NAFNET_CONFIGS.items():
        net = NAFNet(**cfg)
        secs = []
        for tile in (1024, 256):
            restorer = Restorer(name, net, tile=tile, overlap=48)
            restorer.restore(deg, resid)  # warm-up
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                restorer.restore(deg, resid)
                times.append(time.perf_counter() - t0)
            secs.append(min(times))
        blocks = f"w{cfg['width']} enc {cfg['enc_blocks']} mid {cfg['middle_blocks']} dec {cfg['dec_blocks']}"
        lines.append(f"| {name}: {blocks} | {count_parameters(net):,} | {secs[0]:.3f} | {secs[1]:.3f} |")

    lines += [
        "",
        "## Reading (of the run that wrote this file; re-check after changing the synthesis)",
        "",
        "- AVIF (4:4:4, speed 8) is on the best curve above ~0.3 bpp: about +1 dB over JPEG XL at 0.6 bpp",
        "  and +2 dB at 1 bpp; WebP is level with or slightly above JPEG XL near 0.5-0.9 bpp and best below",
        "  0.2 bpp among usable settings. JPEG XL stays the default (the paper's choice) behind the table.",
        "- 16-bit JPEG XL samples never pay: each 16-bit point lies below the 8-bit curve.",
        "- Gain percentile: 99.9 and 100 lie on one curve (the gain only moves along it); 99 clips and",
        "  falls below it. Keep 99.9.",
        "- Per-view plan: every rule lies on one mean-PSNR curve, but moving bits to loud views raises the",
        "  pooled PSNR (mean MSE over views, what a refinement loss summed over views sees): strength 0.5",
        "  gains ~0.3 dB and strength 1 ~0.6 dB at equal bytes, for <= 0.2 dB of mean PSNR. Default 0.5.",
        "- Zeroing quiet tiles changes nothing here: lego's background residual is already exactly 0.",
    ]

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".md.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, out)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
