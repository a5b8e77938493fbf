"""Benchmark the full pipeline at scale: default encode and decode, and decode iterations against quality.

    python tools/make_scale_scenes.py -o /work/scale      # the scenes (see that tool)
    python tools/bench_scale_pipeline.py [--scenes /work/scale] [--sizes 1000000,300000,100000] \
        [--out bench/scale_pipeline.md]

Cameras: the scale scenes' own cameras frame the whole grid, where every copy is a few dozen pixels wide
and the codec alone measures 50 dB: no residual is worth sending and the default pipeline is the
attribute path (bench/scale.md). A user photographs objects from up close, so here each copy gets
``--per-copy`` cameras at 400x300 about 2.5 box sides from its centre (azimuths by the golden angle,
25 degrees up), and neighbours show at the edges.

Per size: every 4th camera is held out (never carries side information; quality is scored there, against
the original's renders); `gspc encode` with the rest and no other option (the default low preset: side
information, the encoder's check, the iterations it writes); then `gspc decode` at the file's
iterations, at none, at half (``--twice``: and at twice) as many, and with ``--time-budget`` set to half
the default decode's time. Each command is its own subprocess on one thread (tools/bench_scale.py's
``measure``: wall and CPU seconds, peak RSS).
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from bench_scale import measure

from gspc.cameras import Camera
from gspc.format import container
from gspc.format.chunks import SIDE
from gspc.format.header import FileHeader
from gspc.io import read_scene
from gspc.io.cameras_json import save_cameras_json
from gspc.metrics import mean_psnr
from gspc.reconstruct import render_images
from gspc.views import look_at, split_test_views


def _psnr(ply: Path, cams, reference) -> float:
    return mean_psnr(render_images(read_scene(ply), cams, (0.0, 0.0, 0.0)), reference)


def _file_facts(path: Path) -> tuple[int, bool]:
    """(the decoder's default iterations, whether side information was sent) from a .gspc file."""
    c = container.read(path)
    header = FileHeader.from_dict(c.header)
    return header.side_info.refine_iterations, any(ch.type == SIDE for ch in c.chunks)


def closeup_cameras(meta: dict, per_copy: int, width: int = 400, height: int = 300) -> list[Camera]:
    """``per_copy`` cameras looking at each copy's centre from 2.5 unit-box sides (tools/make_scale_scenes.py
    places unit-box copies at ``centre`` in the z = 0 plane, z up)."""
    fx = 0.5 * width / math.tan(math.radians(50.0) / 2)
    K = np.array([[fx, 0.0, width / 2], [0.0, fx, height / 2], [0.0, 0.0, 1.0]])
    golden = math.pi * (3.0 - math.sqrt(5.0))
    cams, k = [], 0
    for c, copy in enumerate(meta["copies"]):
        target = np.array([copy["centre"][0], copy["centre"][1], 0.0])
        for _ in range(per_copy):
            a, up = golden * k, math.radians(25.0)
            d = np.array([math.cos(a) * math.cos(up), math.sin(a) * math.cos(up), math.sin(up)])
            w2c = look_at(target + 2.5 * d, target, np.array([0.0, 0.0, 1.0]))
            cams.append(Camera(w2c, K.copy(), width, height, f"copy{c:03d}_{k:04d}"))
            k += 1
    return cams


def _check_line(log: str) -> str:
    """The encoder's check as its summary states it (gspc/encoder/policy.py), line wrapping undone."""
    text = " ".join(log.split())
    m = re.search(
        r"check: (at \d+ unsent views: coded [\d.]+ dB, refined [\d.]+ dB, "
        r"same bytes on attributes [\d.]+ dB)",
        text,
    )
    return m.group(1) if m else "did not run"


def _decode_row(
    coded: Path, tmp: Path, label: str, args: list[str], eval_cams, reference
) -> tuple[str, float]:
    """One decode of ``coded`` as a table row, and its wall seconds."""
    out = tmp / "decoded.ply"
    dec = measure(["decode", str(coded), "-o", str(out)] + args)
    # Progress lines on stderr (gspc/progress.py) close the refinement: "refine: done, N/N in ...".
    ran = next(
        (
            line.split("refine: done, ", 1)[1].split("/")[0]
            for line in dec["log"].splitlines()
            if "refine: done, " in line
        ),
        "0",
    )
    p = _psnr(out, eval_cams, reference)
    row = f"| {label} | {ran} | {p:.2f} | {dec['wall']:.0f} | {dec['cpu']:.0f} | {dec['peak_mb']:.0f} |"
    print(row, flush=True)
    return row, dec["wall"]


def _encode(folder: Path, tmp: Path, name: str, args: list[str]) -> tuple[Path, dict, int, bool, str]:
    coded = tmp / name
    enc = measure(
        ["encode", str(folder / "point_cloud.ply"), "-o", str(coded), "--cameras", str(tmp / "train.json")]
        + args
    )
    its, sent = _file_facts(coded)
    return coded, enc, its, sent, _check_line(enc["log"])


def run_size(folder: Path, tmp: Path, extra: list[str], twice: bool, per_copy: int, lines: list[str]) -> None:
    cams = closeup_cameras(json.loads((folder / "scene.json").read_text()), per_copy)
    train, test = split_test_views(cams, every=4)
    eval_cams = [cams[i] for i in test]
    save_cameras_json([cams[i] for i in train], tmp / "train.json")
    scene = read_scene(folder / "point_cloud.ply")
    n = scene.num_gaussians
    reference = render_images(scene, eval_cams, (0.0, 0.0, 0.0))
    del scene
    coded, enc, its, sent, check = _encode(folder, tmp, "default.gspc", extra)
    size = coded.stat().st_size
    print(f"{n}: encode {enc['wall']:.0f} s, {size} B, iterations {its}, side {sent}, {check}", flush=True)
    head = [
        "| decode | iterations run | PSNR vs original | decode s | decode CPU s | peak MB |",
        "|---|---|---|---|---|---|",
    ]
    default_row, default_wall = _decode_row(coded, tmp, "default (the file's)", [], eval_cams, reference)
    lines += [
        f"### {n:,} Gaussians ({folder.name})",
        "",
        f"Default encode (low preset, {len(train)} cameras): {enc['wall']:.0f} s wall, "
        f"{enc['cpu']:.0f} CPU s, peak {enc['peak_mb']:.0f} MB; {size:,} B ({size / n:.2f} B/G); side "
        f"information {'sent' if sent else 'not sent'}; the check: {check}; the file's refinement: {its} "
        f"iterations. Scored at {len(eval_cams)} held-out views ({eval_cams[0].width}x"
        f"{eval_cams[0].height}) against the original's renders.",
        "",
        *head,
        default_row,
    ]
    counts = [0, its // 2] + ([2 * its] if twice else [])
    if not sent:
        # The side-information path's speed against error all the same: the check off keeps the residuals.
        coded, enc, its, sent, _ = _encode(folder, tmp, "forced.gspc", extra + ["--check-iterations", "0"])
        size = coded.stat().st_size
        lines += [
            "",
            f"The same with `--check-iterations 0` (no check: side information kept): encode "
            f"{enc['wall']:.0f} s wall, {size:,} B ({size / n:.2f} B/G); the file's refinement: {its} "
            "iterations.",
            "",
            *head,
        ]
        if not sent:
            lines += ["(no residual worth sending at any view)", ""]
            return
        counts.insert(2, its)
    wall_at_its = default_wall
    for k in counts:
        row, wall = _decode_row(
            coded, tmp, f"--iterations {k}", ["--iterations", str(k)], eval_cams, reference
        )
        lines.append(row)
        if k == its:
            wall_at_its = wall
    budget = round(wall_at_its / 2)
    lines.append(
        _decode_row(
            coded, tmp, f"--time-budget {budget}", ["--time-budget", str(budget)], eval_cams, reference
        )[0]
    )
    lines.append("")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=Path, default=Path("/work/scale"))
    ap.add_argument("--sizes", default="1000000,300000,100000")
    ap.add_argument("--out", type=Path, default=Path("bench/scale_pipeline.md"))
    ap.add_argument("--encode-args", default="", help="extra encode options (for a quick smoke run)")
    ap.add_argument("--twice", action="store_true", help="also decode at twice the file's iterations")
    ap.add_argument("--per-copy", type=int, default=3, help="close-up cameras per copy")
    args = ap.parse_args()
    torch.set_num_threads(1)
    lines = [
        "# Scale: the full pipeline (side information, check, refinement) at 100k to 1M Gaussians",
        "",
        f"Command: `python {' '.join(sys.argv)}`",
        "",
        f"Machine: {platform.machine()}, Python {platform.python_version()}, torch {torch.__version__}, "
        "GSPC_THREADS=1 (one torch thread) in every gspc process. No GPU. Scenes: tools/make_scale_scenes.py "
        "(bench/scale.md).",
        "",
    ]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        for s in args.sizes.split(","):
            folder = args.scenes / f"scale_{s}"
            run_size(folder, Path(d), args.encode_args.split(), args.twice, args.per_copy, lines)
            args.out.write_text("\n".join(lines) + "\n")
    lines.append(f"Benchmark time: {time.perf_counter() - t0:.0f} s.")
    args.out.write_text("\n".join(lines) + "\n")
    print(json.dumps({"wrote": str(args.out)}))


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
