"""Hostile-input sweep of the CLI (issue 15); writes its tally to bench/robustness.md.

    python tools/fuzz_inputs.py

Runs every case of tests/hostile.py (bad option values, bad camera files, .gspc files with mutated header
fields or side information that asks too much, SOG archives with oversized members) through the CLI
in-process, as tests/test_hostile.py does, and counts the outcomes per category. A clean outcome is exit 1
with one ``error:`` line and no output file; ``internal error``, a traceback, exit 0 or a leftover output
are failures. Also records the peak memory (tracemalloc) of decoding each hostile .gspc file.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tracemalloc
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import torch  # noqa: E402
from hostile import (  # noqa: E402
    camera_cases,
    gspc_cases,
    gspc_files,
    option_cases,
    scene_value_cases,
    sog_cases,
)
from scenes import random_scene  # noqa: E402
from sog_files import make_sog  # noqa: E402
from typer.testing import CliRunner  # noqa: E402

from gspc.cli import app  # noqa: E402
from gspc.errors import GspcError  # noqa: E402
from gspc.io import write_ply  # noqa: E402
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode  # noqa: E402


def outcome(case, res) -> str:
    text = res.output
    lines = text.strip().splitlines() or [""]
    if "Traceback" in text or "internal error" in text:
        return "internal error"
    if res.exit_code == 0:
        return "accepted"
    if res.exit_code != 1 or not lines[-1].startswith("error:"):
        return "not one error line"
    if case.output is not None and case.output.exists():
        return "output left behind"
    return "refused (one error line)"


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
    ]
    runner = CliRunner()
    tally: dict[str, Counter] = defaultdict(Counter)
    slowest: dict[str, float] = defaultdict(float)
    bad = []
    for case in cases:
        if case.output is not None and case.output.is_file():
            case.output.unlink()
        t0 = time.perf_counter()
        res = runner.invoke(app, case.args)
        slowest[case.category] = max(slowest[case.category], time.perf_counter() - t0)
        got = outcome(case, res)
        tally[case.category][got] += 1
        if got != "refused (one error line)":
            bad.append(f"{case.category}: {case.name}: {got}: {res.output.strip()[-200:]!r}")
    # Memory of the Python API's decode on each hostile file.
    worst = {"peak": 0, "ratio": 0.0, "name": ""}
    tracemalloc.start()
    for _, name, path in gspc_files(base, tmp):
        tracemalloc.reset_peak()
        before = tracemalloc.get_traced_memory()[0]
        try:
            decode(path, tmp / "mem.ply", DecodeOptions(restore=False, refine=False))
        except GspcError:
            pass
        peak = tracemalloc.get_traced_memory()[1] - before
        if peak > worst["peak"]:
            worst = {
                "peak": peak,
                "ratio": peak / path.stat().st_size,
                "name": name,
                "size": path.stat().st_size,
            }
    tracemalloc.stop()
    return tally, bad, {"slowest": slowest, "memory": worst}


def report(tally: dict, bad: list[str], extra: dict, seconds: float) -> str:
    lines = [
        "# Robustness against hostile inputs",
        "",
        f"Command: `python tools/fuzz_inputs.py` ({seconds:.1f} s on one core). Cases come from "
        "`tests/hostile.py` (the same generator `tests/test_hostile.py` runs); each goes through the CLI "
        "in-process and must end in exit status 1 with one `error:` line last, no `internal error`, no "
        "traceback and no output file. The stated limits are in `gspc/limits.py`.",
        "",
        "| category | cases | outcome | slowest case |",
        "|---|---:|---|---:|",
    ]
    total = 0
    for cat, counts in tally.items():
        n = sum(counts.values())
        total += n
        summary = ", ".join(f"{k}: {v}" for k, v in counts.most_common())
        lines.append(f"| {cat} | {n} | {summary} | {extra['slowest'][cat] * 1e3:.0f} ms |")
    clean = sum(c["refused (one error line)"] for c in tally.values())
    m = extra["memory"]
    lines += [
        f"| **all** | **{total}** | **{clean} clean, {total - clean} not** | |",
        "",
        "Memory: decoding every hostile .gspc file through `gspc.decode` (tracemalloc, Python and numpy "
        f"allocations) peaked at {m['peak']:,} bytes ({m['name']}, a {m.get('size', 0):,}-byte file): "
        "each is refused before what it asks for is allocated.",
    ]
    if bad:
        lines += ["", "Not clean:", ""] + [f"- {b}" for b in bad]
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "robustness.md")
    args = ap.parse_args()
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
