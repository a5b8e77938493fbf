"""Rate-distortion benchmark of gspc's attribute codec against PLY, PLY+zstd and an SPZ-style format.

    python tools/bench_codec.py [SCENE ...] [--fit PATH] [--views 8] [--size 256] [--synthetic/--no-synthetic]

SCENE is any file gspc reads (PLY, SOG); a ``cameras.json`` beside it (as tools/fit_scene.py
writes) gives the views at their own resolution (the held-out test views where ``fit.json`` names
them) and ``fit.json``'s ``background`` grey level the render background; otherwise
``synthesize_views`` places views and the background is black. With no SCENE: the full-precision
fit at ``--fit`` (a lego fit by default, when present), the shared donut, two SOG statues (already
quantised: reported apart) and a synthetic SH-degree-3 scene. Writes bench/codec.md and bench/codec_rd.png
(drawn with numpy, encoded with imagecodecs; no plotting dependency).
"""

from __future__ import annotations

import gzip
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import imagecodecs
import msgpack
import numpy as np
import torch
import typer
import zstandard

from gspc.codec.attributes import decode_attributes
from gspc.encoder.coding import encode_attributes
from gspc.format.chunks import ATTRIBUTE_TYPES
from gspc.io import read_scene, write_ply
from gspc.io.camera_files import load_cameras
from gspc.metrics import psnr, quantize8, ssim
from gspc.presets import QUALITY
from gspc.render import render
from gspc.scene import GaussianScene, make_scene, num_sh_rest
from gspc.views import synthesize_views

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
GROUPS = ATTRIBUTE_TYPES
FIT = ROOT.parent / "fits" / "lego200_20k" / "point_cloud.ply"
LAMBDAS = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0)


def synthetic_sh3(n: int = 30000, seed: int = 0) -> GaussianScene:
    """Smooth fields over a torus with SH degree 3: a stand-in for full-precision fits."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 2 * np.pi, n)
    r = 0.35 + 0.05 * np.sin(5 * u)
    means = np.stack([(1 + r * np.cos(v)) * np.cos(u), (1 + r * np.cos(v)) * np.sin(u), r * np.sin(v)], 1)
    log_scales = np.log(0.012) + 0.3 * np.sin(3 * u)[:, None] + rng.normal(0, 0.3, (n, 3))
    quats = rng.normal(size=(n, 4))
    opac = rng.normal(2.0, 1.5, n)
    dc = np.stack([np.sin(u), np.cos(v), np.sin(u + v)], 1) * 1.2 + rng.normal(0, 0.15, (n, 3))
    k = num_sh_rest(3)
    rest = rng.normal(0, 0.04, (n, k, 3)) * (rng.uniform(size=(n, 1, 1)) < 0.6)
    return make_scene(means, quats, log_scales, opac, dc, rest, 3)


# ---------------------------------------------------------------------------------------------
# Reference formats


def ply_bytes(scene: GaussianScene) -> bytes:
    with tempfile.TemporaryDirectory() as d:
        write_ply(scene, Path(d) / "s.ply")
        return (Path(d) / "s.ply").read_bytes()


def _fixed(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, levels: int) -> tuple[np.ndarray, np.ndarray]:
    span = np.where(hi > lo, hi - lo, 1.0)
    q = np.clip(np.rint((x - lo) / span * levels), 0, levels)
    return q.astype(np.int64), lo + q * span / levels


def spz_style(scene: GaussianScene) -> tuple[int, GaussianScene]:
    """SPZ-like coding: 24-bit positions, 8-bit log scales, alpha and colour, smallest-three 10-bit
    rotations, SH at 5 bits (degree 1) / 4 bits (higher), columns gzipped. Returns (bytes, decoded)."""
    n = scene.num_gaussians
    f = {k: v.detach().double().numpy() for k, v in scene.tensors().items()}
    cols = []
    qp, means = _fixed(f["means"], f["means"].min(0), f["means"].max(0), (1 << 24) - 1)
    cols.append(np.stack([(qp >> s) & 255 for s in (0, 8, 16)], 2).reshape(n, -1))
    qs, scales = _fixed(f["log_scales"], np.full(3, -10.0), np.full(3, 6.0), 255)
    cols.append(qs)
    alpha = 1 / (1 + np.exp(-f["opacities"]))
    qa, alpha_hat = _fixed(alpha, np.zeros(1), np.ones(1), 255)
    alpha_hat = np.clip(alpha_hat, 1e-6, 1 - 1e-6)
    cols.append(qa[:, None])
    qc, dc = _fixed(f["sh_dc"] * 0.15, np.full(3, -0.5), np.full(3, 0.5), 255)
    cols.append(qc)
    q = f["quats"] / np.linalg.norm(f["quats"], axis=1, keepdims=True)
    big = np.argmax(np.abs(q), 1)
    q *= np.where(q[np.arange(n), big] < 0, -1.0, 1.0)[:, None]
    others = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])[big]
    rest3 = np.take_along_axis(q, others, 1)
    qr, rest_hat = _fixed(rest3, np.full(3, -math.sqrt(0.5)), np.full(3, math.sqrt(0.5)), 1023)
    word = big.astype(np.int64) << 30 | qr[:, 0] << 20 | qr[:, 1] << 10 | qr[:, 2]
    cols.append(np.stack([(word >> s) & 255 for s in (0, 8, 16, 24)], 1))
    quat_hat = np.zeros((n, 4))
    np.put_along_axis(quat_hat, others, rest_hat, 1)
    quat_hat[np.arange(n), big] = np.sqrt(np.maximum(1 - (rest_hat**2).sum(1), 0))
    sh = f["sh_rest"]
    sh_hat = np.zeros_like(sh)
    if sh.shape[1]:
        q8 = np.clip(np.rint(sh * 128 + 128), 0, 255)
        for k in range(sh.shape[1]):
            bucket = 1 << (8 - (5 if k < 3 else 4))
            qk = np.clip(np.rint(q8[:, k] / bucket) * bucket, 0, 255)
            sh_hat[:, k] = (qk - 128) / 128
            cols.append((qk // bucket).astype(np.int64))
    payload = b"".join(c.astype(np.uint8).tobytes(order="F") for c in cols)
    size = 16 + len(gzip.compress(payload, compresslevel=9))
    decoded = make_scene(
        means,
        quat_hat,
        scales,
        np.log(alpha_hat / (1 - alpha_hat)),
        dc / 0.15,
        sh_hat,
        scene.sh_degree,
    )
    return size, decoded


# ---------------------------------------------------------------------------------------------
# Rendering and plotting


def _renders(scene: GaussianScene, cams, background: float = 0.0) -> torch.Tensor:
    bg = torch.full((3,), float(background))
    with torch.no_grad():
        return torch.stack([quantize8(render(scene, c, background=bg).image) for c in cams])


def quality(ref: torch.Tensor, img: torch.Tensor) -> tuple[float, float]:
    return float(psnr(img, ref).clamp(max=100).mean()), float(ssim(img, ref).mean())


def _line(canvas, x0, y0, x1, y1, color):
    n = int(max(abs(x1 - x0), abs(y1 - y0))) + 1
    xs = np.linspace(x0, x1, n).round().astype(int)
    ys = np.linspace(y0, y1, n).round().astype(int)
    ok = (xs >= 0) & (xs < canvas.shape[1]) & (ys >= 0) & (ys < canvas.shape[0])
    canvas[ys[ok], xs[ok]] = color


def plot_rd(curves: dict[str, list[tuple[float, float]]], path: Path) -> list[str]:
    """Bytes/Gaussian (log x) vs PSNR (y) per scene; returns the legend (colour per curve)."""
    w, h, m = 800, 500, 40
    canvas = np.full((h, w, 3), 255, np.uint8)
    pts = [p for c in curves.values() for p in c if math.isfinite(p[1])]
    if not pts:
        return []
    xs = np.log2([p[0] for p in pts])
    ys = np.array([p[1] for p in pts])
    x0, x1 = math.floor(xs.min()), math.ceil(xs.max())
    y0, y1 = 5 * math.floor(ys.min() / 5), 5 * math.ceil(ys.max() / 5)
    x1, y1 = max(x1, x0 + 1), max(y1, y0 + 5)

    def to_px(b, p):
        return m + (math.log2(b) - x0) / (x1 - x0) * (w - 2 * m), h - m - (p - y0) / (y1 - y0) * (h - 2 * m)

    for gx in range(x0, x1 + 1):  # one grid line per doubling of bytes
        px, _ = to_px(2.0**gx, y0)
        _line(canvas, px, m, px, h - m, (220, 220, 220))
    for gy in range(y0, y1 + 1, 5):  # one per 5 dB
        _, py = to_px(2.0**x0, gy)
        _line(canvas, m, py, w - m, py, (220, 220, 220))
    palette = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75)]
    legend = []
    for i, (name, c) in enumerate(curves.items()):
        col = palette[i % len(palette)]
        legend.append(f"{name}: rgb{col}")
        c = sorted(p for p in c if math.isfinite(p[1]))
        for (b0, p0), (b1, p1) in zip(c, c[1:], strict=False):
            _line(canvas, *to_px(b0, p0), *to_px(b1, p1), col)
        for b, p in c:
            px, py = to_px(b, p)
            canvas[int(py) - 3 : int(py) + 4, int(px) - 3 : int(px) + 4] = col
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(imagecodecs.png_encode(canvas))
    os.replace(tmp, path)
    legend.append(f"x: bytes/Gaussian, 2^{x0} to 2^{x1}, grid per doubling; y: PSNR {y0}-{y1} dB, grid 5 dB")
    return legend


# ---------------------------------------------------------------------------------------------


def load(path: Path, views: int, size: int):
    """(scene, cameras, background grey level) as described in the module docstring."""
    scene = read_scene(path)
    cams_file, fit_file = path.parent / "cameras.json", path.parent / "fit.json"
    if not cams_file.is_file():
        return scene, synthesize_views(scene, views, size, size), 0.0
    cams = load_cameras(cams_file)
    fit = json.loads(fit_file.read_text()) if fit_file.is_file() else {}
    test = set(fit.get("test_names") or [])
    if test and any(c.name in test for c in cams):
        cams = [c for c in cams if c.name in test]
    cams = cams[:: max(1, len(cams) // views)][:views]
    return scene, cams, float(fit.get("background", 0.0))


def bench_scene(name: str, scene: GaussianScene, cams, bg: float, rows: list, curves: dict) -> dict:
    """Adds the scene's table rows and RD curve; returns its Done-when numbers."""
    n = scene.num_gaussians

    def renders(s):
        return _renders(s, cams, bg)

    ref = renders(scene)

    def add(label, nbytes, groups, img, enc_s, dec_s, count):
        p, s = quality(ref, img)
        rows.append([name, label, count, nbytes / n, groups, p, s, enc_s, dec_s])
        return p

    t = time.perf_counter()
    ply = ply_bytes(scene)
    add("PLY", len(ply), "", ref, time.perf_counter() - t, 0.0, n)
    t = time.perf_counter()
    z = zstandard.ZstdCompressor(level=19).compress(ply)
    enc_s = time.perf_counter() - t
    t = time.perf_counter()
    zstandard.ZstdDecompressor().decompress(z)
    add("PLY+zstd19", len(z), "", ref, enc_s, time.perf_counter() - t, n)
    t = time.perf_counter()
    spz_size, spz_dec = spz_style(scene)
    spz_psnr = add("SPZ-style", spz_size, "", renders(spz_dec), time.perf_counter() - t, 0.0, n)
    curve = []
    points = [(k, QUALITY[k].attributes) for k in ("high", "low")] + [
        (f"lam={lam}", QUALITY["high"].attributes.with_lambda(lam)) for lam in LAMBDAS
    ]
    summary = {"sh": scene.sh_degree, "spz_bpg": spz_size / n, "spz_psnr": spz_psnr}
    for label, params in points:
        t = time.perf_counter()
        enc = encode_attributes(scene, params)
        enc_s = time.perf_counter() - t
        t = time.perf_counter()
        decode_attributes(enc.chunks, enc.section)
        dec_s = time.perf_counter() - t
        meta_b = len(msgpack.packb(enc.section.to_dict(), use_bin_type=True))
        groups = (
            " ".join(f"{g[:2]}{len(enc.chunks.get(g, b'')) / n:.2f}" for g in GROUPS) + f" me{meta_b / n:.2f}"
        )
        p = add(label, enc.num_bytes, groups, renders(enc.decoded), enc_s, dec_s, len(enc.kept))
        curve.append((enc.num_bytes / n, p))
        if label in QUALITY:
            summary[label] = (enc.num_bytes / n, p)
    curves[name] = curve
    curves.setdefault("_spz", []).append((spz_size / n, spz_psnr))
    # Bytes our codec needs at the SPZ-style PSNR (log-linear interpolation on the sweep).
    c = sorted((p, b) for b, p in curve)
    ratio = float("nan")
    for (p0, b0), (p1, b1) in zip(c, c[1:], strict=False):
        if p0 <= spz_psnr <= p1 and p1 > p0:
            b = math.exp(math.log(b0) + (spz_psnr - p0) / (p1 - p0) * (math.log(b1) - math.log(b0)))
            ratio = b / (spz_size / n)
    rows.append([name, "gspc / SPZ-style bytes at equal PSNR", "", ratio, "", spz_psnr, float("nan"), 0, 0])
    summary["ratio"] = ratio
    return summary


def main(
    scenes: list[Path] = typer.Argument(None),
    fit: Path = typer.Option(
        ROOT.parent / "fits" / "lego200_20k" / "point_cloud.ply", help="full-precision fit"
    ),
    views: int = 8,
    size: int = 256,
    synthetic: bool = True,
    out: Path = ROOT / "bench" / "codec.md",
) -> None:
    torch.set_num_threads(1)
    items = []
    paths = scenes or [fit, SHARED / "donut" / "fused.ply", *sorted((SHARED / "statues").glob("*.sog"))[:2]]
    for p in paths:
        if p.exists():
            items.append((p.parent.name + "/" + p.name, *load(p, views, size)))
    if synthetic:
        s = synthetic_sh3()
        items.append(("synthetic-sh3", s, synthesize_views(s, views, size, size), 0.0))
    rows, curves, summaries = [], {}, {}
    for name, scene, cams, bg in items:
        print(f"{name}: {scene.num_gaussians} Gaussians, SH {scene.sh_degree}", file=sys.stderr)
        summaries[name] = bench_scene(name, scene, cams, bg, rows, curves)
        summaries[name]["views"] = f"{len(cams)} at {cams[0].width}x{cams[0].height}, background {bg:g}"
    spz = curves.pop("_spz")
    legend = plot_rd(curves, out.with_name("codec_rd.png"))
    cmd = "python tools/bench_codec.py " + " ".join(sys.argv[1:])
    lines = [
        "# Attribute codec: rate and render quality",
        "",
        f"Made by `{cmd.strip()}` (one CPU thread). PSNR/SSIM of the decoded scene's renders against the",
        "original scene's renders (8-bit). Views: a scene's own cameras.json (its held-out test views where",
        "fit.json names them) at their resolution and fit.json's background, else synthesised views at",
        f"{size}x{size} on black. Groups: bytes per input Gaussian per chunk (PO positions, OP opacity,",
        "SC scales, RO rotations, SH DC then SH rest, me meta).",
        "",
        "## Done-when checks",
        "",
        "Full-precision scenes decide the checks. SOG statues were already quantised by their own encoder",
        "(their rates flatter any codec) and the synthetic scene is a stand-in: both are listed apart.",
        "",
        "| scene | kind | views | SH | SPZ-style B/G @ PSNR | gspc/SPZ bytes at equal PSNR (<= 0.5) "
        "| low B/G (<= 10 at SH 3) | high PSNR dB (>= 40) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, sm in summaries.items():
        kind = (
            "SOG, pre-quantised" if name.endswith(".sog") else "synthetic" if "synthetic" in name else "full"
        )
        lines.append(
            f"| {name} | {kind} | {sm['views']} | {sm['sh']} | {sm['spz_bpg']:.2f} @ {sm['spz_psnr']:.2f} "
            f"| {sm['ratio']:.3f} | {sm['low'][0]:.2f} ({sm['low'][1]:.2f} dB) | {sm['high'][1]:.2f} "
            f"({sm['high'][0]:.2f} B/G) |"
        )
    lines += [
        "",
        "## All rate points",
        "",
        "| scene | codec | kept | B/Gaussian | groups | PSNR dB | SSIM | enc s | dec s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.3f} | {r[4]} | {r[5]:.2f} | {r[6]:.4f} "
            f"| {r[7]:.2f} | {r[8]:.2f} |"
        )
    lines += ["", "codec_rd.png legend: " + "; ".join(legend), f"SPZ-style points (B/G, PSNR): {spz}", ""]
    tmp = out.with_suffix(".tmp")
    tmp.write_text("\n".join(lines))
    os.replace(tmp, out)
    print("\n".join(lines))


if __name__ == "__main__":
    typer.run(main)
