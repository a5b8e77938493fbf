"""Benchmark the full pipeline at scale: default encode and decode, and decode iterations against quality.

    python tools/make_scale_scenes.py -o /work/scale      # the scenes (see that tool)
    python tools/bench_scale_pipeline.py [--scenes /work/scale] [--sizes 1000000,300000,100000] \
        [--code before=/tmp/gspc_before --code after=.] [--sweep] [--out bench/scale_pipeline.md]

Cameras: the scale scenes' own cameras frame the whole grid, where every copy is a few dozen pixels wide
and the codec alone measures 50 dB: no residual is worth sending and the default pipeline is the
attribute path (bench/scale.md). A user photographs objects from up close, so here each copy gets
``--per-copy`` cameras at 400x300 about 2.5 box sides from its centre (azimuths by the golden angle,
25 degrees up), and neighbours show at the edges.

Per size: every 4th camera is held out (never carries side information; quality is scored there, against
the original's renders). For each ``--code`` (a folder holding a ``gspc`` package, e.g. an older commit's
``git archive``; default this checkout), side by side: `gspc encode` with the rest and no other option (the
default low preset: side information, the encoder's check, the iterations it writes) and its default
`gspc decode`; where the check sent none, the side-information path with the check off
(``--check-iterations 0``), decoded at the file's iterations (``--sweep``: also at none, at half, and with
``--time-budget`` half that decode's time). Last, the attribute codec alone given the bytes that the last
code's file with side information (its default one, or else the forced one) spends on attributes and side
information (``--no-side-info --target-size``): the comparison "at equal bytes". Each command is its own
subprocess on one thread (tools/bench_scale.py's ``measure``: wall and CPU seconds, peak RSS).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from bench_scale import REPO, measure

from gspc.cameras import Camera
from gspc.format import container
from gspc.format.chunks import ATTRIBUTE_TYPES, SIDE
from gspc.format.header import FileHeader
from gspc.io import read_scene
from gspc.io.cameras_json import save_cameras_json
from gspc.metrics import mean_psnr
from gspc.reconstruct import render_images
from gspc.views import look_at, split_test_views


def _psnr(ply: Path, cams, reference) -> float:
    return mean_psnr(render_images(read_scene(ply), cams, (0.0, 0.0, 0.0)), reference)


def _file_facts(path: Path) -> tuple[int, bool, int]:
    """(the decoder's default iterations, whether side information was sent, attribute + SIDE payload bytes)
    from a .gspc file."""
    c = container.read(path)
    header = FileHeader.from_dict(c.header)
    payload = sum(len(ch.payload) for ch in c.chunks if ch.type in ATTRIBUTE_TYPES or ch.type == SIDE)
    return header.side_info.refine_iterations, any(ch.type == SIDE for ch in c.chunks), payload


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
        r"check: (at \d+ unsent views: coded [\d.]+ dB, refined [\d.]+ dB"
        r"(?: after \d+ of \d+ iterations \(decided there\))?, same bytes on attributes [\d.]+ dB)",
        text,
    )
    return m.group(1) if m else "did not run"


@dataclass(frozen=True)
class Code:
    """One gspc package to run: a label for the tables and the folder holding its ``gspc`` package."""

    label: str
    root: Path


@dataclass(frozen=True)
class Scoring:
    """Where decodes are scored: held-out cameras and the original's renders there."""

    cameras: list
    reference: list


def _decode(coded: Path, tmp: Path, args: list[str], score: Scoring, code: Code) -> tuple[dict, str, float]:
    """One decode of ``coded``: its measurement, the iterations it ran and its PSNR."""
    out = tmp / "decoded.ply"
    dec = measure(["decode", str(coded), "-o", str(out)] + args, code.root)
    # Progress lines on stderr (gspc/progress.py) close the refinement: "refine: done, N/N in ...".
    ran = next(
        (
            line.split("refine: done, ", 1)[1].split("/")[0]
            for line in dec["log"].splitlines()
            if "refine: done, " in line
        ),
        "0",
    )
    return dec, ran, _psnr(out, score.cameras, score.reference)


def _encode(folder: Path, tmp: Path, name: str, args: list[str], code: Code) -> tuple[Path, dict]:
    coded = tmp / name
    enc = measure(
        ["encode", str(folder / "point_cloud.ply"), "-o", str(coded), "--cameras", str(tmp / "train.json")]
        + args,
        code.root,
    )
    return coded, enc


def _secs(m: dict) -> str:
    return f"{m['wall']:.0f} ({m['cpu']:.0f})"


def default_row(
    folder: Path, tmp: Path, extra: list[str], score: Scoring, code: Code
) -> tuple[str, bool, int]:
    """The default encode and decode under ``code``, as a table row; whether side information was sent and
    the file's attribute + side payload bytes."""
    coded, enc = _encode(folder, tmp, "default.gspc", extra, code)
    its, sent, payload = _file_facts(coded)
    size = coded.stat().st_size
    dec, ran, p = _decode(coded, tmp, [], score, code)
    row = (
        f"| {code.label} | {_secs(enc)} | {enc['peak_mb']:.0f} | {size:,} | "
        f"{'sent' if sent else 'not sent'} | "
        f"{_check_line(enc['log'])} | {its} | {ran} | {_secs(dec)} | {dec['peak_mb']:.0f} | {p:.2f} |"
    )
    print(row, flush=True)
    return row, sent, payload


def forced_rows(
    folder: Path, tmp: Path, extra: list[str], score: Scoring, code: Code, sweep: bool
) -> tuple[list[str], int]:
    """The side-information path with the check off (``--check-iterations 0``) under ``code``: decodes at
    the file's iterations (``sweep``: also none, half and a time budget of half that decode's wall time),
    as table rows, and the file's attribute + side payload bytes."""
    coded, enc = _encode(folder, tmp, "forced.gspc", extra + ["--check-iterations", "0"], code)
    its, sent, payload = _file_facts(coded)
    size = coded.stat().st_size
    if not sent:
        return [f"| {code.label} | {_secs(enc)} | {size:,} | (no residual worth sending) | | | |"], payload
    counts = [0, its // 2, its] if sweep else [its]
    rows, wall = [], 0.0
    for k in counts:
        dec, ran, p = _decode(coded, tmp, ["--iterations", str(k)], score, code)
        wall = dec["wall"]
        rows.append(
            f"| {code.label} | {_secs(enc)} | {size:,} | --iterations {k} | {ran} | {_secs(dec)} | "
            f"{dec['peak_mb']:.0f} | {p:.2f} |"
        )
    if sweep:
        budget = str(round(wall / 2))
        dec, ran, p = _decode(coded, tmp, ["--time-budget", budget], score, code)
        rows.append(
            f"| {code.label} | {_secs(enc)} | {size:,} | --time-budget {budget} | {ran} | {_secs(dec)} | "
            f"{dec['peak_mb']:.0f} | {p:.2f} |"
        )
    for r in rows:
        print(r, flush=True)
    return rows, payload


def attributes_alone(folder: Path, tmp: Path, payload: int, score: Scoring, code: Code) -> str:
    """The attribute codec alone given ``payload`` bytes (what a forced file spends on attributes and side
    information together): ``--no-side-info --target-size``, decoded."""
    coded, enc = _encode(folder, tmp, "alone.gspc", ["--no-side-info", "--target-size", str(payload)], code)
    _, _, spent = _file_facts(coded)
    dec, _, p = _decode(coded, tmp, [], score, code)
    return (
        f"The attribute codec alone at those bytes ({code.label}; `--no-side-info --target-size {payload}`): "
        f"{spent:,} B of attributes ({coded.stat().st_size:,} B file), encode {_secs(enc)} s, "
        f"{p:.2f} dB."
    )


def run_size(
    folder: Path, tmp: Path, extra: list[str], codes: list[Code], sweep: bool, per_copy: int, lines: list[str]
) -> None:
    cams = closeup_cameras(json.loads((folder / "scene.json").read_text()), per_copy)
    train, test = split_test_views(cams, every=4)
    eval_cams = [cams[i] for i in test]
    save_cameras_json([cams[i] for i in train], tmp / "train.json")
    scene = read_scene(folder / "point_cloud.ply")
    n = scene.num_gaussians
    score = Scoring(eval_cams, render_images(scene, eval_cams, (0.0, 0.0, 0.0)))
    del scene
    lines += [
        f"### {n:,} Gaussians ({folder.name})",
        "",
        f"{len(train)} cameras given to the encoder; scored at {len(eval_cams)} held-out views "
        f"({eval_cams[0].width}x{eval_cams[0].height}) against the original's renders. Seconds are wall "
        "(CPU).",
        "",
        "Default encode and decode (low preset, no option):",
        "",
        "| code | encode s | encode peak MB | bytes | side information | the check | file's iterations | "
        "decode iterations | decode s | decode peak MB | PSNR vs original |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    declined, payload = [], 0
    for c in codes:
        row, sent, payload = default_row(folder, tmp, extra, score, c)
        lines.append(row)
        if not sent:
            declined.append(c)
    if declined:
        lines += [
            "",
            "Where the check sent none, the same with `--check-iterations 0` (no check: side information "
            "kept):",
            "",
            "| code | encode s | bytes | decode | iterations run | decode s | decode peak MB | "
            "PSNR vs original |",
            "|---|---|---|---|---|---|---|---|",
        ]
    for c in declined:
        rows, forced_payload = forced_rows(folder, tmp, extra, score, c, sweep)
        lines += rows
        if c is codes[-1]:
            payload = forced_payload
    lines += ["", attributes_alone(folder, tmp, payload, score, codes[-1]), ""]


def _code(spec: str) -> Code:
    label, _, root = spec.partition("=")
    if not root or not (Path(root) / "gspc").is_dir():
        raise SystemExit(f"--code {spec!r}: expected LABEL=DIR with DIR/gspc a package")
    return Code(label, Path(root).resolve())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=Path, default=Path("/work/scale"))
    ap.add_argument("--sizes", default="1000000,300000,100000")
    ap.add_argument("--out", type=Path, default=Path("bench/scale_pipeline.md"))
    ap.add_argument("--encode-args", default="", help="extra encode options (for a quick smoke run)")
    ap.add_argument(
        "--code",
        action="append",
        type=_code,
        metavar="LABEL=DIR",
        help="a gspc package root to run, repeatable, side by side in the order given (default: this "
        "checkout)",
    )
    ap.add_argument(
        "--sweep", action="store_true", help="also decode forced files at 0 and half the iterations"
    )
    ap.add_argument("--per-copy", type=int, default=3, help="close-up cameras per copy")
    args = ap.parse_args()
    torch.set_num_threads(1)
    codes = args.code or [Code("this checkout", REPO)]
    lines = [
        "# Scale: the full pipeline (side information, check, refinement) at 100k to 1M Gaussians",
        "",
        f"Command: `python {' '.join(sys.argv)}`",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} CPUs, load average at the start "
        f"{os.getloadavg()[0]:.1f}, Python {platform.python_version()}, torch {torch.__version__}, "
        "GSPC_THREADS=1 (one torch thread) in every gspc process. No GPU. Scenes: tools/make_scale_scenes.py "
        "(bench/scale.md). Code: " + "; ".join(f"{c.label} = {c.root}" for c in codes) + ".",
        "",
    ]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        for s in args.sizes.split(","):
            folder = args.scenes / f"scale_{s}"
            run_size(folder, Path(d), args.encode_args.split(), codes, args.sweep, args.per_copy, lines)
            args.out.write_text("\n".join(lines) + "\n")
    lines.append(
        f"Benchmark time: {time.perf_counter() - t0:.0f} s; load average at the end {os.getloadavg()[0]:.1f}."
    )
    args.out.write_text("\n".join(lines) + "\n")
    print(json.dumps({"wrote": str(args.out)}))


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
