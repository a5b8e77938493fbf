"""Start-up time of gspc's light entry points, two source trees side by side (e.g. before and after a change).

    git worktree add /tmp/gspc-before 3867a1b
    python tools/bench_startup.py --before /tmp/gspc-before --after . -o bench/startup.md

Each entry point runs in a fresh interpreter with PYTHONPATH set to the tree, alternating trees, and the
median wall time of the repeats is reported with the ratio; which heavy modules each run imported is listed
too. The .gspc file for `info` is made by the --after tree (no side information).
"""

from __future__ import annotations

import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import typer

PROBE = (
    "import sys\n{body}\n"
    "print('HEAVY:' + ','.join(m for m in ('torch', 'gspc.pipeline') if m in sys.modules))"
)
CLI = (
    "from gspc.cli import app\nsys.argv = ['gspc', *{args!r}]\ntry:\n    app()\nexcept SystemExit:\n    pass"
)
MAKE = """
import torch
from gspc.io import write_ply
from gspc.pipeline import EncodeOptions, encode
from gspc.scene import GaussianScene
g = torch.Generator().manual_seed(0)
n = 2000
r = lambda *shape: torch.randn(*shape, generator=g)
s = GaussianScene(r(n, 3), r(n, 4), r(n, 3) - 4, r(n), r(n, 3), torch.zeros(n, 0, 3), 0)
write_ply(s, {ply!r})
encode({ply!r}, {out!r}, opts=EncodeOptions(side_info=False, synth_views=8))
"""


def run_once(tree: Path, code: str, cwd: Path) -> tuple[float, str]:
    # ``python -c`` puts the working folder first on sys.path: run where no gspc tree lies.
    env = {**os.environ, "PYTHONPATH": str(tree.resolve())}
    t0 = time.perf_counter()
    res = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=cwd, capture_output=True, text=True, check=True
    )
    return time.perf_counter() - t0, res.stdout.rsplit("HEAVY:", 1)[-1].strip() or "none"


def main(
    before: Path = typer.Option(..., help="source tree before the change"),
    after: Path = typer.Option(Path("."), help="source tree after the change"),
    repeats: int = typer.Option(7),
    out: Path | None = typer.Option(None, "-o", help="Markdown table to write"),
) -> None:
    tmp = Path(tempfile.mkdtemp())
    ply, gspc_file = tmp / "s.ply", tmp / "s.gspc"
    subprocess.run(
        [sys.executable, "-c", MAKE.format(ply=str(ply), out=str(gspc_file))],
        env={**os.environ, "PYTHONPATH": str(after.resolve())},
        cwd=tmp,
        check=True,
    )
    entries = {
        "`import gspc.format.container`": PROBE.format(body="import gspc.format.container"),
        "`gspc --help`": PROBE.format(body=CLI.format(args=["--help"])),
        "`gspc info FILE.gspc`": PROBE.format(body=CLI.format(args=["info", str(gspc_file)])),
        "`python -c pass` (interpreter alone)": PROBE.format(body="pass"),
    }
    rows = []
    for name, code in entries.items():
        times: dict[str, list[float]] = {"before": [], "after": []}
        heavy = {}
        for _ in range(repeats):
            for label, tree in (("before", before), ("after", after)):
                t, h = run_once(tree, code, tmp)
                times[label].append(t)
                heavy[label] = h
        b, a = statistics.median(times["before"]), statistics.median(times["after"])
        rows.append(f"| {name} | {b:.3f} | {heavy['before']} | {a:.3f} | {heavy['after']} | {b / a:.1f}x |")
        print(rows[-1], flush=True)
    text = "\n".join(
        [
            "# Start-up time of the light entry points",
            "",
            f"Command: `python tools/bench_startup.py --before {before} --after {after} --repeats {repeats}`",
            "",
            f"Machine: {platform.machine()}, {os.cpu_count()} vCPUs, Python {platform.python_version()}; "
            "each run a fresh interpreter, the two trees alternating; median wall seconds of the repeats. "
            "The machine ran other jobs meanwhile: compare the columns, not the absolute seconds.",
            "",
            "| entry point | before s | heavy imports | after s | heavy imports | before / after |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    if out:
        out.write_text(text)
    print(text)


if __name__ == "__main__":
    typer.run(main)
