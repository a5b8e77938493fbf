"""Spatial tiles at scale: bytes, PSNR, seconds and peak memory of tiled files against one block, by size,
tile size and workers (bench/tiles.md).

    python tools/bench_tiles.py --scenes /work/district --sizes 1000000 --plan compare -o bench/tiles.md
    python tools/bench_tiles.py --scenes /work/district --sizes 1000000,3000000,10000000 --plan scale

Every run is a fresh ``gspc`` process (its own wall and CPU seconds, its peak resident memory, and the
largest of its worker processes'), on the district scenes tools/make_district.py builds (real scans laid out
as a district, with its cameras). PSNR is of the decoded attributes (``decode``: tiled files carry no side
information) against the original's renders at every eighth of the scene's cameras, in float (8-bit
rounding hides sub-level differences at these rates), by gspc's renderer on one thread. ``--plan compare``:
one block and tiles of several sizes at three lambdas each (bytes at equal PSNR off each one's own curve);
``--plan occlusion``: one block and the default tiles at ``--lams`` (8 and 11; ``--variants tiles``: the
tiles alone, to run again on another tree);
``--plan scale``: the default tiles at the low preset's lambda, 8, on 1 and 2 workers; ``--plan preset``:
the default tiles as the low preset codes them (each tile aimed at its fidelity, no ``--lambda``); ``--plan
side``: the preset with each tile's own side information (spec 10.15) against the attributes alone, both at
the preset and in the same bytes, every eighth camera held out of the encoder and scored (the others are
where side information may be sent, so scoring there would flatter it); ``--plan closeups``: the same
question on tools/make_scale_scenes.py's scenes (``--scenes /work/scale``) with the close-up cameras of
tools/bench_scale_pipeline.py, every fourth held out: one block with the scene's side information at
``--lam``, then in its bytes tiles of ``--tile-size`` each with their own (their neighbours drawn, and
alone) and the tiles' attributes alone; ``--plan fit``: the same on one scene folder (``--scenes``, with its
cameras.json: a fit of tools/fit_scene.py), every eighth camera held out. Results
are appended as JSON lines to ``--log`` as they come (a long run can be read while it runs) and the report
is written from all of them at the end.
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
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def _tree(root: int) -> list[int]:
    """``root`` and every process below it (from /proc)."""
    parents: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            parents.setdefault(ppid, []).append(int(d))
    out, todo = [], [root]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo += parents.get(pid, [])
    return out


def _sample(pid: int) -> tuple[int, float] | None:
    """(resident kB, CPU seconds) of one process, None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            rss = int(next(line for line in f if line.startswith("VmRSS")).split()[1])
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return rss, (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, StopIteration, IndexError, ValueError):
        return None


def run_gspc(args: list[str], log: Path, threads: int = 1) -> dict:
    """``gspc ARGS`` in a fresh process, sampled with its worker processes every fifth of a second: wall
    and CPU seconds (all its processes), the peak resident memory of all of them together and of the
    largest one (MB)."""
    with open(log, "ab") as out:
        env = dict(os.environ, GSPC_THREADS=str(threads), COLUMNS="300")
        env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "gspc.cli", *args], env=env, stdout=out, stderr=out)
        cpu: dict[int, float] = {}
        total = largest = 0
        while proc.poll() is None:
            samples = {p: _sample(p) for p in _tree(proc.pid)}
            samples = {p: s for p, s in samples.items() if s is not None}
            total = max(total, sum(s[0] for s in samples.values()))
            largest = max([largest, *(s[0] for s in samples.values())])
            cpu.update({p: s[1] for p, s in samples.items()})
            time.sleep(0.2)
        wall = time.perf_counter() - t0
        if proc.returncode:
            raise SystemExit(f"gspc {' '.join(args)} failed; see {log}")
    return {"wall": wall, "cpu": sum(cpu.values()), "rss_mb": total / 1024, "largest_mb": largest / 1024}


def psnr(original: Path, decoded: Path, cameras: Path, every: int = 8) -> float:
    """Mean PSNR (float renders) of ``decoded`` against ``original`` at every ``every``-th camera."""
    import torch

    from gspc.io import read_scene
    from gspc.io.camera_files import load_cameras
    from gspc.metrics import mse
    from gspc.reconstruct import render_images
    from gspc.views import limit_size

    torch.set_num_threads(1)
    cams = limit_size(load_cameras(cameras), 400)[::every]
    a = render_images(read_scene(original), cams, (0.0, 0.0, 0.0))
    b = render_images(read_scene(decoded), cams, (0.0, 0.0, 0.0))
    return float(np.mean([-10 * math.log10(max(float(mse(x, y)), 1e-12)) for x, y in zip(a, b)]))


HELD_OUT_EVERY = 8  # --plan side: every eighth camera held out of the encoder, and scored


def held_out_cameras(scene_dir: Path, work: Path) -> Path:
    """The scene's cameras less every HELD_OUT_EVERY-th (those the PSNR scores), as a file for --cameras."""
    cams = json.loads((scene_dir / "cameras.json").read_text())
    out = work / f"{scene_dir.name}-train-cameras.json"
    out.write_text(json.dumps([c for k, c in enumerate(cams) if k % HELD_OUT_EVERY]))
    return out


def one(
    scene_dir: Path,
    work: Path,
    log: Path,
    variant: str,
    lam: float | None,
    tile_size: int,
    workers: int,
    side: bool = False,
    target: int | None = None,
) -> dict:
    """Encode, decode and score one variant (``lam`` None: as the preset codes it; ``side``: with side
    information, the scored cameras held out; ``target``: in at most that many bytes); its row."""
    ply, cams = scene_dir / "point_cloud.ply", scene_dir / "cameras.json"
    name = variant.replace(" ", "_").replace(",", "").replace("'", "")
    out = work / f"{scene_dir.name}-{name}-{'preset' if lam is None else f'{lam:g}'}-{workers}.gspc"
    dec = out.with_suffix(".ply")
    rate = [] if lam is None else ["--lambda", str(lam)]
    rate += [] if target is None else ["--target-size", str(target)]
    train = held_out_cameras(scene_dir, work) if variant.startswith("held out") else cams
    common = ["--cameras", str(train), *rate, "--workers", str(workers)]
    common += [] if side else ["--no-side-info"]
    enc = run_gspc(["encode", str(ply), "-o", str(out), "--tile-size", str(tile_size), *common], log)
    dcd = run_gspc(["decode", str(out), "-o", str(dec), "--workers", str(workers)], log)
    row = {
        "scene": scene_dir.name,
        "gaussians": int(json.loads((scene_dir / "scene.json").read_text())["gaussians"]),
        "variant": variant,
        "tile_size": tile_size,
        "lambda": "the preset's" if lam is None else lam,
        "workers": workers,
        "bytes": out.stat().st_size,
        "psnr": psnr(ply, dec, cams, HELD_OUT_EVERY),
        "encode": enc,
        "decode": dcd,
    }
    dec.unlink()
    return row


@dataclass(frozen=True)
class HeldOutScene:
    """A scene, its cameras and which of them are held out of the encoder (every ``every``-th)."""

    name: str
    ply: Path
    cams: list
    every: int


def closeup_scene(folder: Path) -> HeldOutScene:
    """``--plan closeups``: a scale scene with the close-up cameras, every fourth held out."""
    from bench_scale_pipeline import closeup_cameras

    meta = json.loads((folder / "scene.json").read_text())
    cams = next(c for c in (closeup_cameras(meta, k) for k in range(1, 64)) if len(c) >= 112)
    return HeldOutScene(folder.name, folder / "point_cloud.ply", cams, 4)


def fit_scene(folder: Path) -> HeldOutScene:
    """``--plan fit``: a scene folder (point_cloud.ply and cameras.json, tools/fit_scene.py's), every eighth
    camera held out, at 400 pixels."""
    from gspc.io.camera_files import load_cameras
    from gspc.views import limit_size

    cams = limit_size(load_cameras(folder / "cameras.json"), 400)
    return HeldOutScene(folder.name, folder / "point_cloud.ply", cams, 8)


def held_out_rows(
    scene: HeldOutScene,
    work: Path,
    lam: float,
    workers: int,
    tile_size: int,
    only: str = "",
    earlier: Sequence[dict] = (),
) -> list[dict]:
    """One block with the scene's side information at ``lam``, then in its bytes tiles each with their own
    (their neighbours drawn, and alone), the tiles' attributes alone and the tiles' own sent unchecked, each
    encoded with the scene's cameras but those it holds out and scored there against the original's renders
    (float PSNR). ``only``: the variants whose name holds it (or, with |, any of them). ``earlier``: rows
    already measured. Every row after the first is coded in the bytes of the one-block row, where the log
    holds one, else of this run's first row."""
    import torch

    from gspc.io import read_scene
    from gspc.io.cameras_json import save_cameras_json
    from gspc.metrics import mse
    from gspc.reconstruct import render_images
    from gspc.views import split_test_views

    torch.set_num_threads(1)
    name, ply, cams = scene.name, scene.ply, scene.cams
    train, test = split_test_views(cams, every=scene.every)
    given = work / f"{name}-given.json"
    save_cameras_json([cams[i] for i in train], given)
    held = [cams[i] for i in test]
    original = read_scene(ply)
    reference = render_images(original, held, (0.0, 0.0, 0.0))
    common = ["--cameras", str(given), "--lambda", f"{lam:g}"]
    tiled = ["--workers", str(workers), "--tile-size", str(tile_size)]
    unchecked = ["--check-iterations", "0"]
    drawn, alone = ["--tile-neighbours"], ["--no-tile-neighbours"]
    variants = [
        ("one block, the scene's side information", ["--tile-size", "0"]),
        ("tiles, each its own side information, neighbours drawn", [*tiled, *drawn]),
        ("tiles, each its own side information, alone", [*tiled, *alone]),
        ("tiles, attributes alone", [*tiled, "--no-side-info"]),
        # What refinement per tile does where it runs: the checks' verdicts set aside.
        ("tiles, each its own side information unchecked, neighbours drawn", [*tiled, *unchecked, *drawn]),
        ("tiles, each its own side information unchecked, alone", [*tiled, *unchecked, *alone]),
        # Side information shared by spans of four tiles (spec 10.17), in the lead's bytes and at the rate.
        ("tiles, spans' side information in one block's bytes", [*tiled, "--span-size", str(4 * tile_size)]),
        ("tiles, spans' shared side information, at the rate", [*tiled, "--span-size", str(4 * tile_size)]),
    ]
    rows: list[dict] = []
    lead = variants[0][0]
    first = [r for r in earlier if r["scene"] == name and r["lambda"] == lam and r["variant"] == lead]
    for variant, args in variants:
        if not any(o in variant for o in only.split("|")):
            continue
        slug = variant.replace(",", "").replace("'", "").replace(" ", "_")
        out = work / f"{name}-{lam:g}-{tile_size}-{slug}.gspc"
        at_bytes = variant != lead and not variant.endswith("at the rate")
        if at_bytes and (first or rows):  # in the lead's bytes (the log's), else this run's first's
            args = [*args, "--target-size", str((first + rows)[0]["bytes"])]
        log = work / f"{out.stem}.log"
        log.unlink(missing_ok=True)
        enc = run_gspc(["encode", str(ply), "-o", str(out), *common, *args], log)
        side = _summary_line(log.read_text(), "side info")
        workers_arg = args[:2] if args[0] == "--workers" else []
        dec = run_gspc(["decode", str(out), "-o", str(out.with_suffix(".ply")), *workers_arg], log)
        images = render_images(read_scene(out.with_suffix(".ply")), held, (0.0, 0.0, 0.0))
        p = float(
            np.mean([-10 * math.log10(max(float(mse(a, b)), 1e-12)) for a, b in zip(images, reference)])
        )
        rows.append({"scene": name, "gaussians": original.num_gaussians, "variant": variant,
                     "tile_size": 0 if args[:2] == ["--tile-size", "0"] else tile_size, "lambda": lam,
                     "workers": workers, "bytes": out.stat().st_size, "psnr": p, "side info": side,
                     "encode": enc, "decode": dec})  # fmt: skip
        print(json.dumps(rows[-1]), flush=True)
    return rows


def _summary_line(text: str, key: str) -> str:
    """The line ``key`` of a gspc summary (run with COLUMNS=300, so on one line), or "" where it has none."""
    m = re.search(rf"^{re.escape(key)}: (.*)$", text, re.M)
    return m.group(1).strip() if m else ""


def plan_rows(
    plan: str, sizes: list[int], workers: tuple[int, ...] = (1, 2), lams: tuple[float, ...] = (8.0, 11.0)
) -> list[tuple[int, str, float | None, int, int]]:
    """(size, variant, lambda, tile size, workers) of every run of a plan (``lams``: --plan occlusion's)."""
    rows = []
    if plan == "compare":
        for n in sizes:
            for lam in (6.0, 8.0, 11.0):
                rows.append((n, "one block", lam, 0, 1))
                for tile in (1 << 16, 1 << 18):
                    rows.append((n, f"tiles of {tile:,}", lam, tile, 2))
    elif plan == "occlusion":  # one block and the default tiles, at the low preset's rate and one coarser
        for n in sizes:
            for lam in lams:
                rows.append((n, "one block", lam, 0, 1))
                rows.append((n, f"tiles of {1 << 18:,}", lam, 1 << 18, 2))
    elif plan == "side":
        for n in sizes:
            for w in workers:
                rows.append((n, "held out, with each tile's side information", None, 1 << 18, w))
                rows.append((n, "held out, attributes in the same bytes", None, 1 << 18, w))
                rows.append((n, "held out, attributes at the preset", None, 1 << 18, w))
    elif plan == "preset":
        for n in sizes:
            for w in workers:
                rows.append((n, f"tiles of {1 << 18:,}, the low preset", None, 1 << 18, w))
    else:
        for n in sizes:
            for w in workers:
                rows.append((n, f"tiles of {1 << 18:,}", 8.0, 1 << 18, w))
    return rows


def _lam(x) -> str:
    return f"{x:g}" if isinstance(x, (int, float)) else str(x)


def equal_psnr_ratio(rows: list[dict], variant: str, base: str = "one block") -> float | None:
    """Bytes of ``variant`` over ``base``'s at ``variant``'s middle PSNR, off ``base``'s curve (log bytes
    linear in PSNR between its points); None where the PSNR lies outside it."""
    own = sorted((r["psnr"], r["bytes"]) for r in rows if r["variant"] == variant)
    ref = sorted((r["psnr"], r["bytes"]) for r in rows if r["variant"] == base)
    if len(own) < 2 or len(ref) < 2:
        return None
    p, b = own[len(own) // 2]
    for (p0, b0), (p1, b1) in zip(ref, ref[1:]):
        if p0 <= p <= p1 and p1 > p0:
            f = (p - p0) / (p1 - p0)
            return b / math.exp(math.log(b0) + f * (math.log(b1) - math.log(b0)))
    return None


def report(rows: list[dict], machine: str) -> str:
    lines = [
        "## Measured",
        "",
        f"Machine: {machine}. Every run a fresh process; workers as named, each on one thread.",
        "",
        "| scene | Gaussians | variant | lambda | workers | bytes | B/G | PSNR dB | encode wall s "
        "| encode CPU s | encode peak MB, all processes (largest) | decode wall s "
        "| decode peak MB, all processes (largest) |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        e, d = r["encode"], r["decode"]
        lines.append(
            f"| {r['scene']} | {r['gaussians']:,} | {r['variant']} | {_lam(r['lambda'])} | {r['workers']} | "
            f"{r['bytes']:,} | {r['bytes'] / r['gaussians']:.2f} | {r['psnr']:.2f} | {e['wall']:.0f} | "
            f"{e['cpu']:.0f} | {e['rss_mb']:.0f} ({e['largest_mb']:.0f}) | {d['wall']:.1f} | "
            f"{d['rss_mb']:.0f} ({d['largest_mb']:.0f}) |"
        )
    sides = [r for r in rows if r.get("side info")]
    if sides:
        lines += ["", "What each encoder's summary said of side information:"]
        for r in sides:
            lines.append(f"- {r['scene']}, {r['variant']}, lambda {_lam(r['lambda'])}: {r['side info']}")
    # Each scene's variants against its own one block (a scene without one, a scale run, has no ratio).
    ratios = []
    for scene in sorted({r["scene"] for r in rows}):
        own = [r for r in rows if r["scene"] == scene]
        for v in sorted({r["variant"] for r in own if r["variant"] != "one block"}):
            ratios.append((f"{scene}, {v}", equal_psnr_ratio(own, v)))
    if any(x is not None for _, x in ratios):
        lines += ["", "Bytes at equal PSNR against one block (each variant's middle point, off its curve):"]
        lines += [f"- {v}: {x:.4f}" for v, x in ratios if x is not None]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=Path, default=Path("/work/district"))
    ap.add_argument("--sizes", default="1000000")
    plans = ("compare", "occlusion", "scale", "preset", "side", "closeups", "fit")
    ap.add_argument("--plan", choices=plans, default="compare")
    ap.add_argument("--variants", default="", help="run only the variants whose name holds this (or, with |)")
    ap.add_argument("--lams", default="8,11", help="--plan occlusion: the lambdas")
    ap.add_argument("--lam", type=float, default=8.0, help="--plan closeups, fit: the rate")
    ap.add_argument("--tile-size", type=int, default=1 << 18, help="--plan closeups, fit: the tiles' size")
    ap.add_argument("--workers", default="1,2", help="--plan scale, preset: the worker counts to run")
    ap.add_argument("--work", type=Path, default=Path("/work/bench_tiles"))
    ap.add_argument("--log", type=Path, default=None, help="rows as JSON lines (default: WORK/rows.jsonl)")
    ap.add_argument("-o", "--out", type=Path, default=None, help="the report (default: print it)")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    log = args.log or args.work / "rows.jsonl"
    machine = f"{platform.node()}, {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f} at start"
    rows = [json.loads(x) for x in log.read_text().splitlines()] if log.exists() else []
    done = {(r["scene"], r["variant"], r["lambda"], r["workers"]) for r in rows}
    sizes, counts = [int(s) for s in args.sizes.split(",")], tuple(int(w) for w in args.workers.split(","))
    if args.plan in ("closeups", "fit"):  # tools/make_scale_scenes.py's scenes (scale_N), or scene folders
        folders = [args.scenes / f"scale_{n}" for n in sizes] if args.plan == "closeups" else [args.scenes]
        held_out = closeup_scene if args.plan == "closeups" else fit_scene
        for folder in folders:
            found = held_out_rows(
                held_out(folder), args.work, args.lam, counts[-1], args.tile_size, args.variants, list(rows)
            )
            for row in found:
                with open(log, "a") as f:
                    f.write(json.dumps(row) + "\n")
                rows.append(row)
        text = report(rows, machine)
        print(text)
        if args.out:
            args.out.write_text(text)
        return
    lams = tuple(float(x) for x in args.lams.split(","))
    for n, variant, lam, tile, workers in plan_rows(args.plan, sizes, counts, lams):
        scene_dir = args.scenes / f"district_{n}"
        if (scene_dir.name, variant, "the preset's" if lam is None else lam, workers) in done:
            continue
        if not any(o in variant for o in args.variants.split("|")):
            continue
        side = variant.endswith("side information")
        target = None
        if variant.endswith("same bytes"):  # the side-information row's bytes, spent on attributes alone
            own = [r for r in rows if r["scene"] == scene_dir.name]
            target = [r for r in own if r["variant"].endswith("side information")][-1]["bytes"]
        row = one(scene_dir, args.work, args.work / "gspc.log", variant, lam, tile, workers, side, target)
        rows.append(row)
        with open(log, "a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)
    text = report(rows, machine)
    if args.out:
        args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
