"""Hostile-input sweep of the CLI (issues 15 and 26); writes its tally to bench/robustness.md.

    python tools/fuzz_inputs.py

Runs every case of tools/hostile_cases.py through the CLI in-process, as tests/test_hostile.py does: bad
option values and environment, bad camera files and poses, .gspc files with mutated header fields or side
information that asks too much, files crafted at each size-bounded limit of gspc/limits.py and just past it
(tools/amplification_cases.py), SOG and SPZ scenes, and outputs that are devices, folders or sockets. A clean
outcome is the one the case expects: a refusal (exit 1, one ``error:`` line, no output, no warning) or, at a
limit's edge, success; and no file other than the case's output is created, changed or removed. Per
category it records the slowest case and the largest peak of Python and numpy allocations (tracemalloc) of
one case; then the peak of decoding each hostile .gspc file through the Python API.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections import Counter, defaultdict
from pathlib import Path

import torch
from hostile_cases import (
    amplification_cases,
    camera_cases,
    camera_input_cases,
    environment_cases,
    gspc_cases,
    gspc_files,
    option_cases,
    outcome,
    output_cases,
    scene_value_cases,
    snapshot,
    sog_cases,
    touched,
)
from scenes import random_scene
from sog_files import make_sog
from typer.testing import CliRunner

from gspc.cli import app
from gspc.errors import GspcError
from gspc.io import write_ply
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode

ROOT = Path(__file__).resolve().parents[1]


def sweep(tmp: Path) -> tuple[dict, list[str], dict]:
    scene = tmp / "scene.ply"
    write_ply(random_scene(300, sh_degree=1, seed=0), scene)
    base = tmp / "base.gspc"
    encode(scene, base, opts=EncodeOptions(lam=200, synth_views=6, max_side=48, check_iterations=0))
    cases = [
        *option_cases(scene, base, tmp),
        *camera_cases(scene, tmp),
        *scene_value_cases(scene, tmp),
        *gspc_cases(base, tmp),
        *sog_cases(tmp, make_sog),
        *amplification_cases(base, tmp),
        *output_cases(scene, base, tmp),
        *environment_cases(scene),
        *camera_input_cases(scene, tmp),
    ]
    runner = CliRunner()
    tally: dict[str, Counter] = defaultdict(Counter)
    slowest: dict[str, tuple[float, str]] = defaultdict(lambda: (0.0, ""))
    largest: dict[str, tuple[int, str]] = defaultdict(lambda: (0, ""))
    bad = []
    tracemalloc.start()
    for case in cases:
        if case.output is not None and case.output.is_file():
            case.output.unlink()
        before = snapshot(tmp)
        tracemalloc.reset_peak()
        base_mem = tracemalloc.get_traced_memory()[0]
        t0 = time.perf_counter()
        res = runner.invoke(app, case.args, env=case.env)
        seconds = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1] - base_mem
        slowest[case.category] = max(slowest[case.category], (seconds, case.name))
        largest[case.category] = max(largest[case.category], (peak, case.name))
        got = outcome(case, res.exit_code, res.output)
        extra = touched(before, snapshot(tmp), case.output)
        clean = got == case.expect and not extra
        tally[case.category][f"{got}{'' if clean else ' (not expected)'}"] += 1
        if not clean:
            why = f"touched {extra[:3]}" if got == case.expect else f"{got}: {res.output.strip()[-200:]!r}"
            bad.append(f"{case.category}: {case.name}: expected {case.expect}, {why}")
        torch.set_num_threads(1)  # a GSPC_THREADS case may have changed it
    # Memory of the Python API's decode on each hostile header or side-information file.
    worst = {"peak": 0, "name": "", "size": 0}
    for _, name, path in gspc_files(base, tmp):
        tracemalloc.reset_peak()
        before_mem = tracemalloc.get_traced_memory()[0]
        try:
            decode(path, tmp / "mem.ply", DecodeOptions(restore=False, refine=False))
        except GspcError:
            pass
        peak = tracemalloc.get_traced_memory()[1] - before_mem
        if peak > worst["peak"]:
            worst = {"peak": peak, "name": name, "size": path.stat().st_size}
    tracemalloc.stop()
    peaks = process_peaks([c for c in cases if c.category.startswith("work:")])
    return tally, bad, {"slowest": slowest, "largest": largest, "memory": worst, "peaks": peaks}


PROBE = """
import sys, time
def hwm():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
from gspc.cli import app
import gspc.pipeline, gspc.io  # the imports every such command makes, before the baseline
base = hwm()
t0 = time.perf_counter()
try:
    app(sys.argv[1:])
except SystemExit as e:
    code = e.code
print("PROBE", code, hwm() - base, time.perf_counter() - t0)
"""


def process_peaks(cases: list) -> list[dict]:
    """Each case in a fresh process: the resident-memory high-water mark it adds over the interpreter with
    gspc imported (VmHWM, so Rust and torch allocations count too), and its wall time."""
    out = []
    for case in cases:
        if case.output is not None and case.output.is_file():
            case.output.unlink()
        env = {**os.environ, "GSPC_THREADS": "1", "PYTHONPATH": str(ROOT)}
        res = subprocess.run(
            [sys.executable, "-c", PROBE, *case.args], capture_output=True, text=True, env=env, timeout=600
        )
        line = next((x for x in res.stdout.splitlines() if x.startswith("PROBE")), "PROBE ? 0 0")
        _, code, peak, seconds = line.split()
        size = next((Path(a).stat().st_size for a in case.args[1:2] if Path(a).is_file()), 0)
        out.append({"case": case, "exit": code, "peak": int(peak), "seconds": float(seconds), "size": size})
    return out


def peak_table(rows: list[dict]) -> list[str]:
    lines = [
        "| case | file bytes | exit | added peak RSS | bound 256 MB + 64 x bytes | wall time |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        bound = 256e6 + 64 * r["size"]
        lines.append(
            f"| {r['case'].category.removeprefix('work: ')}: {r['case'].name} | {r['size']:,} | "
            f"{r['exit']} | {r['peak'] / 1e6:.0f} MB | {bound / 1e6:.0f} MB | {r['seconds']:.1f} s |"
        )
    return lines


def report(tally: dict, bad: list[str], extra: dict, seconds: float) -> str:
    lines = [
        "# Robustness against hostile inputs",
        "",
        f"Command: `python tools/fuzz_inputs.py` ({seconds:.0f} s; one torch thread; a 2-vCPU VM shared with "
        f"other jobs, so times are loose upper bounds; {platform.python_implementation()} "
        f"{platform.python_version()}, torch {torch.__version__}). Cases come from "
        "`tools/hostile_cases.py` (the generator `tests/test_hostile.py` runs; the files at each "
        "size-bounded limit from `tools/amplification_cases.py`); each goes through the CLI in-process and "
        "must end as it expects: refused (exit status 1, one `error:` line last, no warning, no `internal "
        "error` or traceback, no output file) "
        "or, for a file at a limit's edge and input gspc reads, succeeded; in both cases no file other than "
        "the case's output may be created, changed or removed. The limits are in `gspc/limits.py` and spec "
        "10.10.",
        "",
        "Worst memory is the largest peak of one case's Python and numpy allocations (tracemalloc; torch's "
        "own tensors are not traced: they matter only in the refinement case, which renders 300 Gaussians).",
        "",
        "| category | cases | outcome | slowest case | worst memory |",
        "|---|---:|---|---|---|",
    ]
    total = clean = 0
    for cat, counts in tally.items():
        n = sum(counts.values())
        total += n
        clean += sum(v for k, v in counts.items() if "not expected" not in k)
        summary = ", ".join(f"{k}: {v}" for k, v in counts.most_common())
        sec, sname = extra["slowest"][cat]
        mem, mname = extra["largest"][cat]
        lines.append(f"| {cat} | {n} | {summary} | {sec:.2f} s ({sname}) | {mem / 2**20:.1f} MiB ({mname}) |")
    m = extra["memory"]
    lines += [
        f"| **all** | **{total}** | **{clean} clean, {total - clean} not** | | |",
        "",
        "Decoding every hostile header and side-information file through `gspc.decode` (tracemalloc) peaked "
        f"at {m['peak']:,} bytes ({m['name']}, a {m['size']:,}-byte file): each is refused before what it "
        "asks for is allocated.",
    ]
    if extra.get("peaks"):
        lines += [
            "",
            "## Work asked for by files at each size-bounded limit",
            "",
            "Each case of the `work:` categories again, alone in a fresh process (`GSPC_THREADS=1`): the "
            "resident memory it adds to the interpreter with gspc imported (the VmHWM high-water mark, so "
            "the entropy coder's and torch's own allocations count), its wall time, and the issue-26 target "
            "for its file. Cases one step past a limit exit 1 at once; the decode cases run with "
            "`--no-restore --no-refine` except the refinement one.",
            "",
            *peak_table(extra["peaks"]),
        ]
    if bad:
        lines += ["", "Not clean:", ""] + [f"- {b}" for b in bad]
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "robustness.md")
    args = ap.parse_args()
    os.environ.setdefault("GSPC_THREADS", "1")
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        tally, bad, extra = sweep(Path(d))
    text = report(tally, bad, extra, time.perf_counter() - t0)
    args.out.write_text(text)
    print(text)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
