"""The whole pipeline's time against its quality, before and after, side by side in one run.

    git archive BASE gspc | tar -x -C /tmp/gspc_before
    python tools/bench_speed.py --before /tmp/gspc_before [--after DIR] [--fit /work/fits/bird_q4_100k] \
        [--statue massa] [--out bench/speed.md]

Per scene: the default encode (low preset, the encoder's check as each version runs it) from the training
cameras, then the default decode, each a fresh `gspc` process on one thread (GSPC_THREADS=1), the code under
``--after`` (default: this checkout) and ``--before`` in turn, each first on PYTHONPATH. Wall and CPU seconds
per command, and the decode's stages as its report prints them; the decoded PLY scored by this checkout at
held-out views that never carry side information, against the original's renders and, for fits, against the
held-out photos.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from bench_setups import SHARED, Setup, fit_setup, score, synth_setup

from gspc.io import read_scene
from gspc.io.cameras_json import save_cameras_json
from gspc.reconstruct import render_images

REPO = Path(__file__).resolve().parents[1]
CLI = "import sys; from gspc.cli import app; sys.argv[0] = 'gspc'; app()"
# A row of the report's stage table ("│ refine │ 40.21 │").
STAGE_ROW = re.compile(r"^\W*([a-z][a-z ]*?)\s+\W\s+(\d+\.\d\d)\s*\W*$", re.MULTILINE)


def _run(code: Path, args: list[str]) -> tuple[float, float, str]:
    """(wall, CPU) seconds of one gspc command run with the package at ``code``, and its stages' seconds as
    its report prints them ("render 3.1, refine 40.2")."""
    env = {**os.environ, "GSPC_THREADS": "1", "PYTHONPATH": str(code)}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    # Run from the root directory: ``python -c`` puts the working folder first on sys.path, and a gspc tree
    # there would shadow the one on PYTHONPATH.
    run = subprocess.run(
        [sys.executable, "-c", CLI, *args], env=env, cwd="/", check=True, capture_output=True, text=True
    )
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    stages = ", ".join(f"{k} {float(v):.1f}" for k, v in STAGE_ROW.findall(run.stdout) if k != "total")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), stages


def bench(s: Setup, variants: dict[str, Path], tmp: Path) -> list[str]:
    cams = tmp / "train_cameras.json"
    save_cameras_json(s.train_cams, cams)
    ref = render_images(read_scene(s.scene_path), s.eval_cams, s.background)
    bg = [str(x) for x in s.background]
    side = str(max(max(c.width, c.height) for c in s.train_cams))
    rows = []
    for name, code in variants.items():
        gfile, ply = tmp / f"{name}.gspc", tmp / f"{name}.ply"
        enc = _run(code, ["encode", str(s.scene_path), "-o", str(gfile), "--cameras", str(cams),
                          "--max-side", side, "--background", *bg])  # fmt: skip
        dec = _run(code, ["decode", str(gfile), "-o", str(ply)])
        q = score(ply, s, ref)
        photo = f"{q['psnr_photo']:.2f}" if "psnr_photo" in q else "-"
        rows.append(
            f"| {s.name} | {name} | {gfile.stat().st_size:,} | {enc[0]:.0f} / {enc[1]:.0f} | "
            f"{dec[0]:.0f} / {dec[1]:.0f} | {dec[2]} | {q['psnr']:.2f} | {photo} |"
        )
        print(rows[-1], flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", type=Path, required=True, help="a gspc package tree to compare against")
    ap.add_argument("--after", type=Path, default=REPO, help="the gspc package tree measured as after")
    ap.add_argument("--fit", type=Path, action="append", default=[], help="a tools/fit_scene.py folder")
    ap.add_argument("--statue", action="append", default=[], help="a statue of ../shared/data/statues")
    ap.add_argument("--out", type=Path, default=None, help="append the table to this Markdown file")
    a = ap.parse_args()
    torch.set_num_threads(1)
    setups = [fit_setup(f) for f in a.fit]
    setups += [synth_setup(f"statue {n}", SHARED / "statues" / f"{n}.sog") for n in a.statue]
    variants = {"after": a.after.resolve(), "before": a.before.resolve()}
    lines = [
        f"Machine: {platform.machine()}, {os.cpu_count()} vCPUs, one thread per gspc process; load average "
        f"at the start {os.getloadavg()[0]:.1f}.",
        "",
        "| scene | code | bytes | encode s wall / CPU | decode s wall / CPU | decode stages s (its report) "
        "| PSNR vs original's renders | PSNR vs photos |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in setups:
        with tempfile.TemporaryDirectory() as tmp:
            lines += bench(s, variants, Path(tmp))
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        with open(a.out, "a") as f:
            f.write(text)


if __name__ == "__main__":
    main()
