"""On a machine with a CUDA GPU: run the CUDA tests, then encode and decode a scale scene on the GPU (the full
pipeline: side information, the encoder's check, restoration, refinement), scored at held-out views, and
write the GPU rows for bench/scale.md (to bench/scale_gpu.md).

    python tools/make_scale_scenes.py -o /work/scale --sizes 1000000     # the scene (see that tool)
    python tools/bench_gpu.py [--scenes /work/scale] [--sizes 1000000] [--per-copy 8] \
        [--tests torch,gsplat] [--decoders torch,gsplat,cpu] [--encode-with torch|gsplat] \
        [--gsplat-path DIR] [--keep DIR | --coded DIR] [--deadline SECONDS] [--logs DIR] \
        [--out bench/scale_gpu.md]

Cameras as tools/bench_scale_pipeline.py (``--per-copy`` close-ups of each copy, every 4th held out and
scored against the original's renders), so the rows compare with bench/scale_pipeline.md's CPU rows.
Steps: (1) ``pytest tests/test_gpu.py`` (slow tests included), its summary line recorded, for each of
``--tests``: torch (gsplat not importable unless installed) and gsplat (``--gsplat-path``: a folder holding
gsplat whose kernels are prebuilt or built); (2) per size, the default encode on the GPU (or the file an
earlier run kept, ``--coded``), then its default decode for each of ``--decoders``: the GPU with gspc's torch
renderer, the GPU with gsplat, the CPU with every core, side by side on one machine. Every command is a fresh
``gspc`` process from this checkout; its wall and CPU seconds, peak resident memory and peak GPU memory
(torch's max_memory_allocated) are recorded, with the renderer its summary names. ``--deadline`` bounds the
whole run: a step still running then is stopped and its row says so, with its last progress line. Each row
is also appended to LOGS/rows.jsonl as it ends, with each command's log beside it. Without CUDA it measures
nothing and writes nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
# A decode that does not refine renders nothing, and its summary names no renderer.
NOT_RENDERED = "none (nothing rendered)"
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


class Clock:
    """The run's deadline: how long a step may still take."""

    def __init__(self, seconds: float | None):
        self.end = None if seconds is None else time.monotonic() + seconds

    def left(self) -> float | None:
        return None if self.end is None else max(0.0, self.end - time.monotonic())


def child_env(threads: int, gsplat_path: str | None) -> dict:
    """The environment of a gspc child: this checkout first, gsplat's folder only where asked for."""
    paths = [str(REPO)] + ([gsplat_path] if gsplat_path else [])
    paths += [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    env = dict(os.environ, GSPC_THREADS=str(threads), PYTHONPATH=os.pathsep.join(paths))
    env["COLUMNS"] = "400"  # the summary's facts on one line, for the renderer's name
    return env


def measure(args: list[str], env: dict, clock: Clock, log_path: Path) -> dict:
    """Run ``gspc ARGS``; wall s, CPU s, peak RSS MB, peak GPU MB, renderer, and whether the deadline
    stopped it (then its last progress line). Its output goes to ``log_path``."""
    with tempfile.TemporaryDirectory() as tmp, open(log_path, "wb") as log_file:
        peak_file = Path(tmp) / "peaks.json"
        env = dict(env, GSPC_BENCH_PEAK=str(peak_file))
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            [sys.executable, "-c", CHILD, *args], env=env, stdout=log_file, stderr=log_file
        )
        stopped = False
        while True:  # wait4 for the child's own CPU time; polled, so that the deadline can stop it
            pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if clock.left() == 0.0:
                proc.kill()
                stopped = True
                _, status, ru = os.wait4(proc.pid, 0)
                break
            time.sleep(0.2)
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t0
        peaks = json.loads(peak_file.read_text()) if peak_file.exists() else {}
    log = log_path.read_text("utf-8", "replace")
    if not stopped and proc.returncode:
        raise SystemExit(f"gspc {' '.join(args)} failed:\n{log[-2000:]}")
    renderer = re.search(r"^renderer: (.*)$", log, re.M)
    lines = [line for line in log.splitlines() if line.strip()]
    return {
        "wall": wall,
        "cpu": ru.ru_utime + ru.ru_stime,
        "rss_mb": peaks.get("rss_kb", 0) / 1024.0,
        "gpu_mb": peaks.get("gpu_mb"),
        "renderer": renderer[1].strip() if renderer else NOT_RENDERED,
        "stopped": lines[-1][:160] if stopped and lines else ("" if not stopped else "(no output)"),
        "log": log,
    }


def run_tests(env: dict, clock: Clock, log_path: Path) -> str:
    """tests/test_gpu.py with its slow tests but this tool's own dry run (a CPU test); its pytest summary
    line."""
    own = "not gpu_bench_runs_its_steps_on_the_cpu"
    try:
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "pytest",
                "-q",
                "-rs",
                "-p",
                "no:cacheprovider",
                "-k",
                own,
                "tests/test_gpu.py",
            ],
            cwd=REPO,
            env=env,
            capture_output=True,
            text=True,
            timeout=clock.left(),
        )
    except subprocess.TimeoutExpired:
        return "stopped at the deadline"
    log_path.write_text(proc.stdout + proc.stderr)
    lines = proc.stdout.strip().splitlines()
    return lines[-1] if lines else f"pytest exited {proc.returncode} with no output"


def _iterations(log: str) -> str:
    """The refinement's iterations as its closing progress line states them (gspc/progress.py)."""
    done = [
        line.split("refine: done, ", 1)[1].split(" ")[0]
        for line in log.splitlines()
        if "refine: done, " in line
    ]
    return done[-1] if done else "0"


def _check(log: str) -> str:
    text = " ".join(log.split())
    m = re.search(r"check: (at \d+ unsent views: .*?same bytes on attributes [\d.]+ dB)", text)
    return m.group(1) if m else "-"


def run_size(folder: Path, tmp: Path, args, clock: Clock, logs: Path, record) -> None:
    import torch
    from bench_scale_pipeline import closeup_cameras

    from gspc.io import read_scene
    from gspc.io.cameras_json import save_cameras_json
    from gspc.metrics import mean_psnr
    from gspc.reconstruct import render_images
    from gspc.views import split_test_views

    meta = json.loads((folder / "scene.json").read_text())
    cams = closeup_cameras(meta, args.per_copy)
    train, test = split_test_views(cams, every=4)
    eval_cams = [cams[i] for i in test]
    save_cameras_json([cams[i] for i in train], tmp / "train.json")

    # The torch renderer (the file's rules) scores every row alike, whatever decoded it; on the GPU where
    # there is one, so that a CPU run on a GPU machine is not held up by its scoring.
    scorer = "cuda" if torch.cuda.is_available() else "cpu"

    def score(ply: Path, reference=None) -> tuple[float, list]:
        scene = read_scene(ply).to(scorer)
        images = [im.cpu() for im in render_images(scene, eval_cams, (0.0, 0.0, 0.0), backend="torch")]
        return (mean_psnr(images, reference) if reference is not None else math.nan), images

    _, reference = score(folder / "point_cloud.ply")
    if torch.cuda.is_available():
        torch.cuda.empty_cache()
    n = meta["gaussians"]
    base = {"n": n, "train": len(train), "eval": len(eval_cams)}
    plain = child_env(args.threads, None)
    coded = (args.coded or args.keep or tmp) / f"scale_{n}.gspc"
    if args.coded is None:
        enc = measure(
            [
                "encode",
                str(folder / "point_cloud.ply"),
                "-o",
                str(coded),
                "--cameras",
                str(tmp / "train.json"),
            ]
            + ["--device", args.device],
            child_env(args.threads, args.gsplat_path if args.encode_with == "gsplat" else None),
            clock,
            logs / f"encode_{n}.log",
        )
        size = coded.stat().st_size if coded.exists() else 0
        record(
            {
                **base,
                "step": "encode",
                "device": args.device,
                "bytes": size,
                "check": _check(enc["log"]),
                **enc,
            }
        )
        if enc["stopped"]:
            return
    envs = {
        "torch": (args.device, plain),
        "gsplat": (args.device, child_env(args.threads, args.gsplat_path)),
        "cpu": ("cpu", plain),
    }
    for label in args.decoders.split(","):
        device, env = envs[label]
        out = tmp / "decoded.ply"
        dec = measure(
            ["decode", str(coded), "-o", str(out), "--device", device],
            env,
            clock,
            logs / f"decode_{n}_{label}.log",
        )
        psnr = score(out, reference)[0] if not dec["stopped"] else math.nan
        record(
            {
                **base,
                "step": "decode",
                "device": device,
                "iterations": _iterations(dec["log"]),
                "psnr": psnr,
                **dec,
            }
        )
        if clock.left() == 0.0:
            return


def table(rows: list[dict]) -> list[str]:
    lines = [
        "| Gaussians | step | device | wall s | CPU s | peak RSS MB | peak GPU MB | renderer | bytes / "
        "iterations | PSNR vs original (held-out) | the check / stopped |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        gpu = "-" if r.get("gpu_mb") is None else f"{r['gpu_mb']:.0f}"
        what = f"{r['bytes']:,} B" if r["step"] == "encode" else f"{r['iterations']} iterations"
        psnr = "-" if math.isnan(r.get("psnr", math.nan)) else f"{r['psnr']:.2f}"
        note = f"stopped at the deadline: {r['stopped']}" if r["stopped"] else r.get("check", "")
        lines.append(
            f"| {r['n']:,} | {r['step']} | {r['device']} | {r['wall']:.1f} | {r['cpu']:.1f} | "
            f"{r['rss_mb']:.0f} | {gpu} | {r['renderer']} | {what} | {psnr} | {note} |"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="/work/scale")
    ap.add_argument("--out", default="bench/scale_gpu.md")
    ap.add_argument("--sizes", default="1000000")
    ap.add_argument("--per-copy", type=int, default=8, help="close-up cameras per copy")
    ap.add_argument("--gsplat-path", help="a folder holding gsplat (kernels built), for the gsplat runs")
    ap.add_argument(
        "--decoders",
        default="torch",
        help="decodes to run, in order: torch (the GPU, gspc's renderer), "
        "gsplat (the GPU, gsplat), cpu (every core)",
    )
    ap.add_argument(
        "--tests", default="torch", help="run tests/test_gpu.py with: torch, gsplat, both or none"
    )
    ap.add_argument(
        "--encode-with",
        default="torch",
        choices=["torch", "gsplat"],
        help="the encode's renderer (gsplat: --gsplat-path)",
    )
    ap.add_argument("--keep", type=Path, help="keep each size's encoded file here (scale_N.gspc)")
    ap.add_argument("--coded", type=Path, help="decode the files an earlier --keep left here; no encode")
    ap.add_argument("--deadline", type=float, help="seconds the whole run may take")
    ap.add_argument("--logs", type=Path, help="where each command's log and rows.jsonl go")
    ap.add_argument("--device", default="cuda", help="cpu: the same steps on the CPU (a dry run of the tool)")
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="GSPC_THREADS of every run")
    args = ap.parse_args()
    import torch

    if args.device == "cuda" and not torch.cuda.is_available():
        raise SystemExit("bench_gpu: no CUDA GPU here: nothing measured, nothing written")
    clock = Clock(args.deadline)
    if args.keep is not None:  # made here: a missing folder stops the encode only at its write
        args.keep.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    logs = args.logs or Path(tempfile.mkdtemp(prefix="bench_gpu_"))
    logs.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []

    def record(row: dict) -> None:
        rows.append({k: v for k, v in row.items() if k != "log"})
        with open(logs / "rows.jsonl", "a") as f:
            f.write(json.dumps(rows[-1]) + "\n")
        print(json.dumps(rows[-1]), flush=True)

    tests = []
    for label in [t for t in args.tests.split(",") if t != "none"]:
        env = child_env(args.threads, args.gsplat_path if label == "gsplat" else None)
        tests.append((label, run_tests(env, clock, logs / f"tests_{label}.log")))
        print(f"tests/test_gpu.py ({label}): {tests[-1][1]}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for s in args.sizes.split(","):
            if clock.left() == 0.0:
                break
            run_size(Path(args.scenes) / f"scale_{s}", Path(tmp), args, clock, logs, record)
    gpu = f"{torch.cuda.get_device_name()}, CUDA {torch.version.cuda}" if args.device == "cuda" else "no GPU"
    lines = [
        "# Scale on a GPU: a scale scene encoded and decoded on a CUDA GPU",
        "",
        f"Command: `python {' '.join(sys.argv)}`",
        "",
        f"Machine: {gpu}, {os.cpu_count()} vCPUs, "
        f"Python {platform.python_version()}, torch {torch.__version__}, GSPC_THREADS={args.threads}. "
        f"Load average at the end: {os.getloadavg()[0]:.1f}. Run time {time.perf_counter() - t0:.0f} s.",
        "",
        *[f"CUDA tests (`pytest tests/test_gpu.py`, {label}): {line}" for label, line in tests],
        "",
        *table(rows),
        "",
    ]
    Path(args.out).write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
