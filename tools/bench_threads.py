"""Threads and workers on a busy machine: the same commands with GSPC_THREADS 1 and 2 and --workers 1, 2 and
4, while other processes keep every core busy, side by side in one run (bench/threads.md).

    python tools/bench_threads.py [--busy 2] [--scene examples/lego] [--tiled /work/district/district_1000000]

Each row is a fresh ``gspc`` process; ``--busy`` processes spin on the CPU throughout (at the same nice
level), as other users' jobs would. The example's encode and decode (one block: threads inside its renders and
kernels) and a tiled scene's attribute path (``--no-side-info``: its tiles on worker processes) are timed.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SPIN = "while True: pass"


def timed(args: list[str], threads: int, log) -> float:
    env = dict(os.environ, GSPC_THREADS=str(threads))
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "gspc.cli", *args], env=env, stdout=log, stderr=log, check=True)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--busy", type=int, default=os.cpu_count() or 2, help="spinning processes (default: cores)"
    )
    ap.add_argument("--scene", type=Path, default=REPO / "examples" / "lego")
    ap.add_argument("--tiled", type=Path, default=None, help="a folder with point_cloud.ply and cameras.json")
    ap.add_argument("--tile-size", type=int, default=1 << 16)
    ap.add_argument("-o", "--out", type=Path, default=None)
    args = ap.parse_args()
    spinners = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(args.busy)]
    rows = []
    try:
        with tempfile.TemporaryDirectory() as tmp, open(Path(tmp) / "log", "wb") as log:
            ply, cams = args.scene / "point_cloud.ply", args.scene / "cameras.json"
            coded = Path(tmp) / "example.gspc"
            base = ["--cameras", str(cams), "--background", "1", "1", "1"]
            for threads in (1, 2):
                enc = timed(["encode", str(ply), "-o", str(coded), *base], threads, log)
                dec = timed(["decode", str(coded), "-o", str(Path(tmp) / "d.ply")], threads, log)
                rows.append(("example, one block", f"GSPC_THREADS={threads}", enc, dec))
            if args.tiled is not None:
                ply, cams = args.tiled / "point_cloud.ply", args.tiled / "cameras.json"
                tiled = Path(tmp) / "tiled.gspc"
                for workers in (1, 2, 4):
                    w = ["--workers", str(workers)]
                    enc = timed(
                        ["encode", str(ply), "-o", str(tiled), "--cameras", str(cams), "--no-side-info",
                         "--tile-size", str(args.tile_size), *w], 1, log,
                    )  # fmt: skip
                    dec = timed(["decode", str(tiled), "-o", str(Path(tmp) / "t.ply"), *w], 1, log)
                    rows.append(
                        (f"{args.tiled.name}, tiles of {args.tile_size:,}", f"--workers {workers}", enc, dec)
                    )
    finally:
        for p in spinners:
            p.kill()
    text = [
        f"Machine: {platform.node()}, {os.cpu_count()} CPUs, {args.busy} other processes spinning.",
        "",
        "| scene | setting | encode wall s | decode wall s |",
        "|---|---|---:|---:|",
        *(f"| {a} | {b} | {c:.1f} | {d:.1f} |" for a, b, c, d in rows),
    ]
    report = "\n".join(text) + "\n"
    if args.out:
        args.out.write_text(report)
    print(report)


if __name__ == "__main__":
    main()
