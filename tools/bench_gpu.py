"""On a machine with a CUDA GPU: run the CUDA tests, then decode the scale scenes on the GPU beside the CPU,
and write the GPU column for bench/scale.md (to bench/scale_gpu.md).

    python tools/make_scale_scenes.py -o /work/scale --sizes 1000000     # the scene (see that tool)
    python tools/bench_gpu.py [--scenes /work/scale] [--sizes 1000000] [--out bench/scale_gpu.md]

Steps: (1) ``pytest tests/test_gpu.py`` (slow tests included), its summary line recorded; (2) per size,
encode once on the CPU without side information (as bench/scale.md) and once with it on the GPU, then decode
the first with ``--no-refine`` and the second with restoration and refinement (the presets' iterations),
each on the CPU and on the GPU, interleaved. Every command is a fresh ``gspc`` process from this checkout;
its wall and CPU seconds, peak resident memory and peak GPU memory (torch's max_memory_allocated) are
recorded, with the renderer its summary names. Without CUDA it measures nothing and writes nothing.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
# The child writes its own peaks at exit: resident memory (VmHWM, which wait4 would mix with the parent's)
# and the GPU memory torch allocated.
CHILD = """import atexit, json, os, re, sys
from gspc.cli import app


def peaks():
    with open("/proc/self/status") as f:
        info = {"rss_kb": int(re.search(r"VmHWM:\\s+(\\d+)", f.read()).group(1))}
    import torch
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        info["gpu_mb"] = torch.cuda.max_memory_allocated() / 2**20
    with open(os.environ["GSPC_BENCH_PEAK"], "w") as f:
        json.dump(info, f)


atexit.register(peaks)
sys.argv[0] = "gspc"
app()
"""


def measure(args: list[str], threads: int) -> dict:
    """Run ``gspc ARGS`` from this checkout; wall s, CPU s, peak RSS MB, peak GPU MB, renderer."""
    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryFile() as log_file:
        peak_file = Path(tmp) / "peaks.json"
        env = dict(
            os.environ, GSPC_THREADS=str(threads), PYTHONPATH=str(REPO), GSPC_BENCH_PEAK=str(peak_file)
        )
        env["COLUMNS"] = "400"  # the summary's facts on one line, for the renderer's name
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-c", CHILD, *args], env=env, stdout=log_file, stderr=log_file
        )
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        log_file.seek(0)
        log = log_file.read().decode("utf-8", "replace")
        peaks = json.loads(peak_file.read_text()) if peak_file.exists() else {}
    if os.waitstatus_to_exitcode(status):
        raise SystemExit(f"gspc {' '.join(args)} failed:\n{log[-2000:]}")
    renderer = re.search(r"renderer: (.*?)(?:  |$)", log, re.M)
    return {
        "wall": wall,
        "cpu": ru.ru_utime + ru.ru_stime,
        "rss_mb": peaks.get("rss_kb", 0) / 1024.0,
        "gpu_mb": peaks.get("gpu_mb"),
        "renderer": renderer[1].strip() if renderer else "?",
    }


def run_tests() -> str:
    """tests/test_gpu.py with its slow tests; its pytest summary line."""
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-rs", "tests/test_gpu.py"],
        cwd=REPO,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
        capture_output=True,
        text=True,
    )
    lines = proc.stdout.strip().splitlines()
    return lines[-1] if lines else f"pytest exited {proc.returncode} with no output"


def run_size(folder: Path, tmp: Path, threads: int) -> list[dict]:
    scene, cams = str(folder / "point_cloud.ply"), str(folder / "cameras.json")
    n = json.loads((folder / "scene.json").read_text())["gaussians"]
    plain, side, out = tmp / "plain.gspc", tmp / "side.gspc", str(tmp / "decoded.ply")
    rows = []

    def row(step: str, device: str, args: list[str]) -> None:
        rows.append({"n": n, "step": step, "device": device, **measure(args + ["--device", device], threads)})
        print(json.dumps(rows[-1]), flush=True)

    row(
        "encode --no-side-info",
        "cpu",
        ["encode", scene, "-o", str(plain), "--cameras", cams, "--no-side-info"],
    )
    row("encode (side information, check)", "cuda", ["encode", scene, "-o", str(side), "--cameras", cams])
    for device in ("cpu", "cuda"):  # interleaved: the same machine state for both
        row("decode --no-refine", device, ["decode", str(plain), "-o", out, "--no-refine"])
    for device in ("cuda", "cpu"):
        row("decode (restore, refine)", device, ["decode", str(side), "-o", out])
    return rows


def table(rows: list[dict]) -> list[str]:
    lines = [
        "| Gaussians | step | device | wall s | CPU s | peak RSS MB | peak GPU MB | renderer |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        gpu = "-" if r["gpu_mb"] is None else f"{r['gpu_mb']:.0f}"
        lines.append(
            f"| {r['n']:,} | {r['step']} | {r['device']} | {r['wall']:.1f} | {r['cpu']:.1f} | "
            f"{r['rss_mb']:.0f} | {gpu} | {r['renderer']} |"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="/work/scale")
    ap.add_argument("--out", default="bench/scale_gpu.md")
    ap.add_argument("--sizes", default="1000000")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="GSPC_THREADS of every run")
    args = ap.parse_args()
    import torch

    if not torch.cuda.is_available():
        raise SystemExit("bench_gpu: no CUDA GPU here: nothing measured, nothing written")
    tests = run_tests()
    print(f"tests/test_gpu.py: {tests}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in args.sizes.split(","):
            rows += run_size(Path(args.scenes) / f"scale_{s}", Path(tmp), args.threads)
    try:  # the installed distribution, without importing it (the runs' own probe says whether it works)
        gsplat_version = importlib.metadata.version("gsplat")
    except importlib.metadata.PackageNotFoundError:
        gsplat_version = "not installed"
    lines = [
        "# Scale on a GPU: the scale scenes decoded on a CUDA GPU beside the CPU",
        "",
        f"Command: `python tools/bench_gpu.py --scenes {args.scenes} --sizes {args.sizes}`",
        "",
        f"Machine: {torch.cuda.get_device_name()}, CUDA {torch.version.cuda}, {os.cpu_count()} vCPUs, "
        f"Python {platform.python_version()}, torch {torch.__version__}, gsplat {gsplat_version}, "
        f"GSPC_THREADS={args.threads}. Load average at the start of the write: {os.getloadavg()[0]:.1f}.",
        "",
        f"CUDA tests (`pytest tests/test_gpu.py`): {tests}",
        "",
        "Workload: bench/scale.md's scenes (`tools/make_scale_scenes.py`). `encode --no-side-info` runs on "
        "the CPU and its file is decoded with `--no-refine` (bench/scale.md's path: only the attribute "
        "codec, which runs on the CPU on every device); `encode` with side information runs on the GPU and "
        "its file is decoded with restoration and refinement (the presets' iterations for the size). "
        "Renderer: what the run's summary names.",
        "",
        *table(rows),
        "",
    ]
    Path(args.out).write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
