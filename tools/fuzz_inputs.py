"""Hostile-input sweep of the CLI (issues 15 and 26); writes its tally to bench/robustness.md.

    python tools/fuzz_inputs.py [--real-dir DIR]

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
    read_value_cases,
    scene_value_cases,
    snapshot,
    sog_cases,
    touched,
    unrestored_cases,
)
from scenes import random_scene
from sog_files import make_sog
from typer.testing import CliRunner

from gspc.cli import app
from gspc.errors import GspcError
from gspc.io import write_ply
from gspc.limits import (
    DECODE_MEMORY_BASE,
    DECODE_MEMORY_PER_FILE_BYTE,
    DECODE_MEMORY_PER_PIXEL,
    decode_memory_bound,
)
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode

ROOT = Path(__file__).resolve().parents[1]
MEMORY_RULE = (
    f"{DECODE_MEMORY_BASE >> 30} GiB + {DECODE_MEMORY_PER_FILE_BYTE} B per file byte + "
    f"{DECODE_MEMORY_PER_PIXEL} B per view pixel"
)


def sweep(tmp: Path) -> tuple[dict, list[str], dict]:
    scene = tmp / "scene.ply"
    write_ply(random_scene(300, sh_degree=1, seed=0), scene)
    base = tmp / "base.gspc"
    # The uniform codec (versions 1-3), as tests/test_hostile.py's: tools/amplification_cases.py builds its
    # payloads for that layout.
    opts = EncodeOptions(lam=200, synth_views=6, max_side=48, check_iterations=0, precision=False)
    encode(scene, base, opts=opts)
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
        *read_value_cases(scene, tmp),
        *unrestored_cases(base, tmp),
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
            opts = DecodeOptions(restore="(restoring)" in name, refine=False, restorer="none")
            decode(path, tmp / "mem.ply", opts)
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
print("PROBE", code, hwm() - base, time.perf_counter() - t0, hwm())
"""


def run_probe(args: list[str]) -> dict:
    """``gspc ARGS`` in a fresh process: exit status, the resident-memory high-water mark it adds over the
    interpreter with gspc imported and the process's own (VmHWM, so Rust and torch allocations count), and
    its wall time."""
    env = {**os.environ, "GSPC_THREADS": "1", "PYTHONPATH": str(ROOT)}
    res = subprocess.run(
        [sys.executable, "-c", PROBE, *args], capture_output=True, text=True, env=env, timeout=3600
    )
    line = next((x for x in res.stdout.splitlines() if x.startswith("PROBE")), "PROBE ? 0 0 0")
    _, code, peak, seconds, process = line.split()
    return {"exit": code, "peak": int(peak), "seconds": float(seconds), "process": int(process)}


def gspc_pixels(path: Path) -> int | None:
    """The pixels of a .gspc file's side-information views (None: not a .gspc file gspc reads)."""
    from gspc.format import container
    from gspc.format.header import FileHeader
    from gspc.format.side_chunk import read_side_views

    try:
        data = path.read_bytes()
        c = container.unpack(data)
        legacy = FileHeader.from_dict(c.header).side_info.legacy_views
        return sum(v.camera.pixels for v in read_side_views(legacy, c.chunks, len(data)).views)
    except GspcError:
        return 0  # refused before anything is rendered
    except OSError:
        return None


def process_peaks(cases: list) -> list[dict]:
    """Each case in a fresh process: the resident-memory high-water mark it adds over the interpreter with
    gspc imported (VmHWM, so Rust and torch allocations count too), and its wall time."""
    out = []
    for case in cases:
        if case.output is not None and case.output.is_file():
            case.output.unlink()
        path = Path(case.args[1])
        size = path.stat().st_size if path.is_file() else 0
        pixels = gspc_pixels(path) if case.args[0] == "decode" else None
        out.append({"case": case, "size": size, "pixels": pixels, **run_probe(case.args)})
    return out


def peak_table(rows: list[dict]) -> list[str]:
    lines = [
        "| case | file bytes | view pixels | exit | added peak RSS | process peak RSS | bound | wall time |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if r["pixels"] is None:  # a scene file: issue 26's target for what reading it adds
            bound = f"{(256e6 + 64 * r['size']) / 1e6:.0f} MB added"
        else:  # a .gspc decode: the decoder's memory rule (gspc/limits.py)
            bound = f"{decode_memory_bound(r['size'], r['pixels']) / 1e6:.0f} MB"
        pixels = "" if r["pixels"] is None else f"{r['pixels']:,}"
        lines.append(
            f"| {r['case'].category.removeprefix('work: ')}: {r['case'].name} | {r['size']:,} | {pixels} | "
            f"{r['exit']} | {r['peak'] / 1e6:.0f} MB | {r['process'] / 1e6:.0f} MB | {bound} | "
            f"{r['seconds']:.1f} s |"
        )
    return lines


# Real files for "What real files ask of a decoder": (name, encode arguments after the scene). Each is encoded
# once into --real-dir (kept there: a rerun measures the same files) with the command shown in the table.
LEGO = ROOT / "examples" / "lego"
STATUES = ROOT.parent / "shared" / "data" / "statues"
LEGO_ARGS = ["--cameras", str(LEGO / "cameras.json"), "--background", "1", "1", "1"]
NO_CHECK = ["--check-iterations", "0"]  # the side information kept: the decoder restores and refines
REAL_FILES = [
    ("lego, low preset", LEGO / "point_cloud.ply", LEGO_ARGS),
    ("lego, high preset", LEGO / "point_cloud.ply", [*LEGO_ARGS, "--quality", "high"]),
    ("lego, lambda 40, no check", LEGO / "point_cloud.ply", [*LEGO_ARGS, "--lambda", "40", *NO_CHECK]),
    ("lego, lambda 1000, no check", LEGO / "point_cloud.ply", [*LEGO_ARGS, "--lambda", "1000", *NO_CHECK]),
    ("massa, low preset", STATUES / "massa.sog", []),
    ("massa, lambda 40, no check", STATUES / "massa.sog", ["--lambda", "40", *NO_CHECK]),
]


def _shown(arg: str) -> str:
    """A command-line argument as the table shows it: paths relative to the repository."""
    return os.path.relpath(arg, ROOT) if os.path.isabs(arg) else arg


def real_rows(folder: Path) -> list[dict]:
    """Each real file (encoded into ``folder`` where absent), what it asks of a decoder (gspc/reconstruct.py
    decode_work), and its default decode (restorer on) in a fresh process."""
    from gspc.codec.attributes import decode_attributes
    from gspc.format import container
    from gspc.format.attribute_section import AttributeSection, attribute_chunks
    from gspc.format.header import FileHeader
    from gspc.format.side_chunk import read_side_views
    from gspc.reconstruct import decode_work, refine_iterations

    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for name, scene, args in REAL_FILES:
        if not scene.exists():
            continue
        path = folder / (name.replace(", ", "_").replace(" ", "_") + ".gspc")
        if not path.exists():
            run_probe(["encode", str(scene), "-o", str(path), *args])
        data = path.read_bytes()
        c = container.unpack(data)
        header = FileHeader.from_dict(c.header)
        side = read_side_views(header.side_info.legacy_views, c.chunks, len(data))
        chunks = attribute_chunks(c.chunks)
        decoded = decode_attributes(chunks, AttributeSection.from_dict(c.header["attributes"]))
        work = decode_work(decoded, [v.camera.to_camera() for v in side.views], side.images, len(data))
        runs = refine_iterations(header.side_info.refine_iterations, work, len(data)) if side.images else 0
        decode = run_probe(["decode", str(path), "-o", str(folder / "decoded.ply")])
        rows.append(
            {
                "name": name,
                "command": " ".join(["gspc encode", *(_shown(a) for a in [str(scene), *args])]),
                "size": len(data),
                "n": decoded.num_gaussians,
                "bits": 8 * sum(map(len, chunks.values())) / decoded.num_gaussians,
                "views": len(side.views),
                "pixels": sum(work.pixels),
                "pairs": max(work.pairs, default=0),
                "work": work.first + runs * work.heaviest,
                "runs": runs,
                "decode": decode,
            }
        )
    return rows


def real_table(rows: list[dict]) -> list[str]:
    lines = [
        "| file | bytes | Gaussians | coded bits per Gaussian | views (pixels per byte) | largest view's "
        "pairs per byte | work per byte (default iterations) | decode: process peak RSS / bound | decode "
        "wall time |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        bound = decode_memory_bound(r["size"], r["pixels"])
        lines.append(
            f"| {r['name']} | {r['size']:,} | {r['n']:,} | {r['bits']:.1f} | {r['views']} "
            f"({r['pixels'] / r['size']:.1f}) | {r['pairs'] / r['size']:.2f} | {r['work'] / r['size']:.0f} "
            f"({r['runs']}) | {r['decode']['process'] / 1e6:.0f} / {bound / 1e6:.0f} MB | "
            f"{r['decode']['seconds']:.0f} s |"
        )
    return lines


def report(tally: dict, bad: list[str], extra: dict, seconds: float) -> str:
    lines = [
        "# Robustness against hostile inputs",
        "",
        f"Command: `python tools/fuzz_inputs.py{' --real-dir DIR' if extra.get('real') else ''}` "
        f"({seconds:.0f} s; one torch thread; a 2-vCPU VM shared with "
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
        "own tensors are not traced: they matter in the decodes that render, restore and refine, whose "
        "whole processes' peaks the next section measures).",
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
            "resident memory it adds to the interpreter with gspc imported and the process's own peak (the "
            "VmHWM high-water mark, so the entropy coder's, torch's and the restorer's allocations count), "
            "its wall time, and its bound: for a .gspc decode the decoder's memory rule (gspc/limits.py, "
            f"{MEMORY_RULE}), for a scene file issue 26's target for what reading it adds (256 MB + 64 x "
            "bytes). Cases one step past a limit exit 1 before the work they ask for; the decode cases of "
            "the first four categories run with `--no-restore --no-refine`, the others as a user's `gspc "
            "decode` does (restorer on, the file's default refinement within its work budget).",
            "",
            *peak_table(extra["peaks"]),
        ]
    if extra.get("real"):
        lines += [
            "",
            "## What real files ask of a decoder",
            "",
            "The per-byte rules of the decoder's work (gspc/limits.py, spec 10.8 \"The decoder's work\") and "
            "the memory rule against real files: the example lego fit and the statue massa, at the presets "
            "and at coarser rates with the check off (the side information kept, so that the decoder "
            "restores and refines). Work per byte is the first renders, the restoration and the default "
            "refinement together, in the units of the rule (a Gaussian, a pair or a pixel rendered once; a "
            "pixel restored, 8), against its budget of 4096 per byte; pairs are the largest view's (the "
            "budget: 32 per byte). Each default decode ran alone in a fresh process. The files: "
            + "; ".join(f"{r['name']}: `{r['command']}`" for r in extra["real"])
            + ".",
            "",
            *real_table(extra["real"]),
        ]
    if bad:
        lines += ["", "Not clean:", ""] + [f"- {b}" for b in bad]
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "robustness.md")
    ap.add_argument(
        "--real-dir",
        type=Path,
        help="encode the real files here (once) and measure what they ask of a decoder",
    )
    args = ap.parse_args()
    os.environ.setdefault("GSPC_THREADS", "1")
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        tally, bad, extra = sweep(Path(d))
    if args.real_dir is not None:
        extra["real"] = real_rows(args.real_dir)
    text = report(tally, bad, extra, time.perf_counter() - t0)
    args.out.write_text(text)
    print(text)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
