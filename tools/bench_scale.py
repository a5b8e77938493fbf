"""Benchmark the attribute-only path at scale: encode --no-side-info and decode --no-refine, 100k to 3M.

    python tools/make_scale_scenes.py -o /work/scale      # the scenes (see that tool)
    python tools/bench_scale.py [--scenes /work/scale] [--out bench/scale.md] [--sizes ...]

Each command runs as its own subprocess of ``gspc`` from this checkout with GSPC_THREADS=1; its wall
seconds, CPU seconds (user + system, from os.wait4) and peak resident memory (the VmHWM the child reports at
exit) are recorded. Encoded files go to a temporary folder and are deleted.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
# The child writes its own peak RSS (VmHWM) at exit: the ru_maxrss that wait4 reports for a child counts
# the parent's RSS at the fork too (Linux keeps it across exec), which hid the child's peak behind a parent
# holding scenes (bench/scale_pipeline.md's 300k column once repeated its parent's 1481 MB).
CLI = """import atexit, os, re, sys
from gspc.cli import app


def peak():
    with open("/proc/self/status") as f:
        kb = re.search(r"VmHWM:\\s+(\\d+)", f.read()).group(1)
    with open(os.environ["GSPC_BENCH_PEAK"], "w") as f:
        f.write(kb)


atexit.register(peak)
sys.argv[0] = "gspc"
app()
"""


def measure(args: list[str], code: Path = REPO) -> dict:
    """Run ``gspc ARGS`` on one thread with the gspc package under ``code`` (default: this checkout); wall s,
    CPU s, peak RSS MB and its stderr."""
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryFile() as err:
        peak_file = Path(tmp) / "peak_kb"
        env = dict(os.environ, GSPC_THREADS="1", PYTHONPATH=str(code), GSPC_BENCH_PEAK=str(peak_file))
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", CLI, *args], env=env, stdout=err, stderr=err, cwd="/")
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        log = err.read().decode("utf-8", "replace")
        peak_kb = int(peak_file.read_text()) if peak_file.exists() else ru.ru_maxrss  # (not Linux)
    if proc.returncode:
        raise SystemExit(f"gspc {' '.join(args)} failed ({proc.returncode}):\n{log[-2000:]}")
    return {"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "peak_mb": peak_kb / 1024.0, "log": log}


def run_size(folder: Path, tmp: Path, code: Path = REPO) -> dict:
    meta = json.loads((folder / "scene.json").read_text())
    coded, decoded = tmp / "scene.gspc", tmp / "decoded.ply"
    enc = measure(
        [
            "encode",
            str(folder / "point_cloud.ply"),
            "-o",
            str(coded),
            "--cameras",
            str(folder / "cameras.json"),
        ]
        + ["--no-side-info"],
        code,
    )
    size = coded.stat().st_size
    dec = measure(["decode", str(coded), "-o", str(decoded), "--no-refine"], code)
    from gspc.io.ply import load_plydata

    kept = len(load_plydata(decoded)["vertex"])
    coded.unlink()
    decoded.unlink()
    return {"n": meta["gaussians"], "copies": len(meta["copies"]), "bytes": size, "kept": kept, "enc": enc,
            "dec": dec}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="/work/scale")
    ap.add_argument("--out", default="bench/scale.md")
    ap.add_argument("--sizes", default="100000,300000,1000000,3000000")
    ap.add_argument(
        "--code", type=Path, default=REPO, help="the gspc package tree to measure (a checkout's root)"
    )
    args = ap.parse_args()
    load = os.getloadavg()[0]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in args.sizes.split(","):
            res = run_size(Path(args.scenes) / f"scale_{s}", Path(tmp), args.code)
            brief = {k: v for k, v in res.items() if k not in ("enc", "dec")}
            for part in ("enc", "dec"):
                brief |= {f"{part}_{k}": v for k, v in res[part].items() if k != "log"}
            print(json.dumps(brief), flush=True)
            rows.append(res)
    table = [
        "| Gaussians | copies | kept | .gspc bytes | B/G | encode s | encode CPU s | encode peak MB "
        "| decode s | decode CPU s | decode peak MB | encode CPU us/G | decode CPU us/G |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        e, d = r["enc"], r["dec"]
        table.append(
            f"| {r['n']:,} | {r['copies']} | {r['kept']:,} | {r['bytes']:,} | {r['bytes'] / r['n']:.2f} | "
            f"{e['wall']:.1f} | {e['cpu']:.1f} | {e['peak_mb']:.0f} | {d['wall']:.1f} | {d['cpu']:.1f} | "
            f"{d['peak_mb']:.0f} | {1e6 * e['cpu'] / r['n']:.1f} | {1e6 * d['cpu'] / r['n']:.1f} |"
        )
    import torch

    lines = [
        "# Scale: the attribute-only path from 100k to 3M Gaussians (CPU, one thread)",
        "",
        f"Command: `python tools/make_scale_scenes.py -o {args.scenes}` then "
        f"`python tools/bench_scale.py --scenes {args.scenes} --sizes {args.sizes}"
        + ("`" if args.code == REPO else f" --code {args.code}`"),
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} vCPUs, Python {platform.python_version()}, "
        f"torch {torch.__version__}, GSPC_THREADS=1 (one torch thread). No GPU was lent to this work: "
        f"there are no GPU figures here. Load average at the start: {load:.1f} (other jobs make wall "
        "seconds noisy; CPU seconds, user + system of the gspc process, less so).",
        "",
        "Workload (`tools/make_scale_scenes.py`): whole copies of real scenes (the five captured statues, "
        "the trained donut, the lego fit), each normalised to a unit box, placed side by side on a grid, "
        "SH degree 3 (the lego's; the others carry zero SH rest); 24 cameras at 400x300 around the grid. "
        "Per size: `gspc encode point_cloud.ply -o scene.gspc --cameras cameras.json --no-side-info` and "
        "`gspc decode scene.gspc -o decoded.ply --no-refine`, each a fresh process; peak MB is that "
        "process's own peak resident memory (VmHWM). Kept: Gaussians in the decoded PLY (the encoder "
        "drops those no view sees or with opacity under 1/255).",
        "",
        *table,
        "",
    ]
    text = "\n".join(lines)
    Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
