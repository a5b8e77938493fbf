"""Benchmark the torch renderer: forward and forward+backward seconds and peak memory, before and after.

    git archive BASE gspc | tar -x -C /tmp/gspc_before      # the renderer to compare against
    python tools/bench_render.py --before /tmp/gspc_before [--out bench/render.md] [--repeats 5]

Each (Gaussians, resolution) case runs in fresh subprocesses so its peak RSS is its own: the code under
``--before`` (put first on PYTHONPATH) and this checkout alternate, ``--repeats`` rounds of each, so both
see the same machine load. A last table times this checkout's 100k 400x300 case on 1 and 2 threads.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np
import torch

# (Gaussians, width, height, camera distance); the last case fills the frame, as real scenes do.
CASES = [(20_000, 256, 256, 3.0), (20_000, 400, 300, 3.0), (20_000, 800, 600, 3.0), (100_000, 256, 256, 3.0),
         (100_000, 400, 300, 3.0), (100_000, 800, 600, 3.0), (100_000, 400, 300, 1.5),
         (300_000, 400, 300, 3.0), (1_000_000, 400, 300, 3.0)]  # fmt: skip
THREADS_CASE = (100_000, 400, 300, 3.0)
PER_PROCESS = 3  # calls per subprocess in a side-by-side round; the median is that round's figure
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def bench_scene(n: int, seed: int = 0):
    """Gaussians in the unit cube, scales ~1e-2, random rotations/opacities, SH degree 3."""
    from gspc.scene import make_scene, num_sh_rest

    g = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 3, generator=g) - 0.5
    quats = torch.randn(n, 4, generator=g)
    log_scales = math.log(1e-2) + 0.5 * torch.randn(n, 3, generator=g)
    opacities = torch.randn(n, generator=g) * 1.5
    sh_dc = torch.randn(n, 3, generator=g) * 0.8
    sh_rest = torch.randn(n, num_sh_rest(3), 3, generator=g) * 0.1
    return make_scene(means, quats, log_scales, opacities, sh_dc, sh_rest, 3)


def bench_camera(width: int, height: int, dist: float = 3.0):
    """Looking at the cube from ``dist`` units, horizontal field of view ~53 degrees."""
    from gspc.cameras import Camera

    a = 0.4  # a slight rotation about y so the view is not axis-aligned
    w2c = np.eye(4)
    w2c[:3, :3] = [[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]]
    w2c[2, 3] = dist
    f = float(width)
    return Camera(w2c, np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]]), width, height)


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_case(n: int, width: int, height: int, dist: float, repeats: int, threads: int = 1) -> dict:
    from gspc.render import render
    from gspc.render.project import project
    from gspc.render.rasterize import bin_tiles

    torch.set_num_threads(threads)
    scene, cam = bench_scene(n), bench_camera(width, height, dist)
    with torch.no_grad():
        p = project(
            scene.means, scene.quats, scene.log_scales, scene.opacities, scene.sh_dc, scene.sh_rest, cam, 3
        )
        order = torch.sort(p.depths, stable=True).indices
        order = order[p.drawn[order]]
        pairs = len(bin_tiles(p.means2d[order], p.extents[order], width, height).gauss)
    for t in scene.tensors().values():
        t.requires_grad_(True)
    # One untimed call: compiled kernels load (or compile) on first use, once per process.
    render(scene, cam, backend="torch").image.sum().backward()
    base = _rss_mb()
    runs = {"fwd": [], "both": [], "fwd_cpu": [], "both_cpu": []}
    for i in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        with torch.no_grad():
            r = render(scene, cam, backend="torch")
        runs["fwd"].append(time.perf_counter() - t0)
        runs["fwd_cpu"].append(time.process_time() - c0)
        if i == 0:
            fwd_peak, mean_alpha = _rss_mb() - base, float(r.alpha.mean())
        t0, c0 = time.perf_counter(), time.process_time()
        r = render(scene, cam, backend="torch")
        (r.image.sum() + r.depth.sum()).backward()
        runs["both"].append(time.perf_counter() - t0)
        runs["both_cpu"].append(time.process_time() - c0)
        if i == 0:
            both_peak = _rss_mb() - base
    res = {
        "n": n,
        "w": width,
        "h": height,
        "dist": dist,
        "visible": int(p.drawn.sum()),
        "pairs": pairs,
        "alpha": mean_alpha,
    }
    res.update({k: float(np.median(v)) for k, v in runs.items()})
    return res | {"fwd_mb": fwd_peak, "both_mb": both_peak}


def fit_scene_case(folder: str, every: int, repeats: int) -> None:
    """A tools/fit_scene.py fit, every ``every``-th of its cameras: forward+backward CPU s per render with the
    compiled compositor and the torch walk, alternating in this process; prints a Markdown table."""
    from functools import partial

    from gspc.io import read_scene
    from gspc.io.camera_files import load_cameras
    from gspc.render import api, rasterize

    torch.set_num_threads(1)
    scene = read_scene(os.path.join(folder, "point_cloud.ply"))
    for t in scene.tensors().values():
        t.requires_grad_(True)
    cams = load_cameras(os.path.join(folder, "cameras.json"))[::every]
    composite = rasterize.composite

    def per_render(kernel: str) -> float:
        api.composite = partial(composite, kernel=kernel)
        c0 = time.process_time()
        for cam in cams:
            api.render(scene, cam).image.sum().backward()
        return (time.process_time() - c0) / len(cams)

    per_render("compiled"), per_render("torch")  # compile / warm up
    runs = {"compiled": [], "torch": []}
    for _ in range(repeats):
        for k in runs:
            runs[k].append(per_render(k))
    # Depth complexity: Gaussian-tile pairs in the tile lists per pixel (what compositing walks).
    pairs, bin_tiles = [], rasterize.bin_tiles

    def counted(*args, **kwargs):
        pairs.append(bin_tiles(*args, **kwargs))
        return pairs[-1]

    rasterize.bin_tiles = counted
    with torch.no_grad():
        for cam in cams:
            api.render(scene, cam)
    rasterize.bin_tiles, api.composite = bin_tiles, composite
    per_pixel = np.mean([int(b.count.sum()) for b in pairs]) / (cams[0].width * cams[0].height)
    compiled, walk = np.median(runs["compiled"]), np.median(runs["torch"])
    print("| scene | views | pairs per pixel | compiled fwd+bwd CPU s | torch walk fwd+bwd CPU s |")
    print("|---|---|---|---|---|")
    name, size = os.path.basename(folder), f"{cams[0].width}x{cams[0].height}"
    print(f"| {name} | {len(cams)} ({size}) | {per_pixel:.1f} | {compiled:.3f} | {walk:.3f} |")


def _case(spec: str, repeats: int, threads: int, path: str) -> dict:
    """One case in a fresh subprocess with ``path`` first on PYTHONPATH (the gspc it imports)."""
    cmd = [sys.executable, __file__, "--case", spec, "--repeats", str(repeats), "--threads", str(threads)]
    env = dict(os.environ, PYTHONPATH=path)
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout
    return json.loads(out.splitlines()[-1])


def _side_by_side(spec: str, repeats: int, paths: dict[str, str], threads: dict[str, int]) -> dict:
    """``repeats`` alternating rounds, one subprocess per variant and round (each the median of
    PER_PROCESS calls); the medians of the rounds per variant, and the largest peak MB."""
    runs: dict[str, list[dict]] = {k: [] for k in paths}
    for _ in range(repeats):
        for k in paths:
            runs[k].append(_case(spec, PER_PROCESS, threads[k], paths[k]))
    res = {}
    for k, rs in runs.items():
        res[k] = dict(rs[0])
        for key in ("fwd", "both", "fwd_cpu", "both_cpu"):
            res[k][key] = float(np.median([r[key] for r in rs]))
        for key in ("fwd_mb", "both_mb"):
            res[k][key] = max(r[key] for r in rs)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench/render.md")
    ap.add_argument("--repeats", type=int, default=3, help="alternating rounds per case")
    ap.add_argument("--before", required=False, help="folder holding the gspc package to compare against")
    ap.add_argument("--max-n", type=int, default=10**9, help="skip cases with more Gaussians")
    ap.add_argument("--fit", help="instead: a fit_scene.py folder, compiled vs torch compositor (Markdown)")
    ap.add_argument("--every", type=int, default=20, help="with --fit: every n-th view")
    ap.add_argument("--case", help=argparse.SUPPRESS)  # "n,w,h,dist": run one case, print JSON
    ap.add_argument("--threads", type=int, default=1, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.fit:
        fit_scene_case(args.fit, args.every, args.repeats)
        return
    if args.case:
        n, w, h, dist = args.case.split(",")
        print(json.dumps(run_case(int(n), int(w), int(h), float(dist), args.repeats, args.threads)))
        return
    paths = {"after": REPO}
    if args.before:
        paths = {"before": os.path.abspath(args.before), "after": REPO}
    rows = []
    for n, w, h, dist in CASES:
        if n > args.max_n:
            continue
        res = _side_by_side(f"{n},{w},{h},{dist}", args.repeats, paths, {k: 1 for k in paths})
        print(json.dumps(res), flush=True)
        rows.append(res)
    threads = _side_by_side(
        ",".join(map(str, THREADS_CASE)), args.repeats, {"1": REPO, "2": REPO}, {"1": 1, "2": 2}
    )
    print(json.dumps(threads), flush=True)
    before = "before" in paths
    cols = ["fwd", "both", "fwd_cpu", "both_cpu", "fwd_mb", "both_mb"]
    names = ["fwd s", "fwd+bwd s", "fwd CPU s", "fwd+bwd CPU s", "fwd peak MB", "fwd+bwd peak MB"]
    head = "| N | image | camera distance | drawn | tile pairs | mean alpha |"
    for c in names:
        head += f" {c} before | {c} after |" if before else f" {c} |"
    lines = [
        "# CPU renderer speed (one thread), before and after",
        "",
        f"Command: `python tools/bench_render.py --before {args.before or '-'} --repeats {args.repeats}`"
        + (" with `--before` a `git archive` of the base commit's `gspc/`" if before else ""),
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} vCPUs (AMD EPYC), torch {torch.__version__}, "
        f"one torch thread (`torch.set_num_threads(1)`) unless stated. No GPU. Load average when the run "
        f"started: {os.getloadavg()[0]:.2f} (other processes on the machine: see the reading below); wall "
        "times carry their load, CPU seconds (this process's user + system time) less so, though shared "
        "cores and caches still inflate them. Before and after ran alternately, one subprocess per round, "
        "so both saw the same load. Each process renders once untimed first (compiled kernels load then).",
        "",
        "Scene: N Gaussians uniform in the unit cube, log-scales log(0.01) + 0.5 randn, random rotations, "
        "opacity logits 1.5 randn, SH degree 3; focal = image width; camera 3 units from the centre (the "
        "cube covers ~1/3 of the width) or 1.5 units (the cube fills the frame, as a real scene does). "
        f"Seconds are medians over {args.repeats} rounds of each round's median of {PER_PROCESS} calls (a "
        "fresh process per round and variant; each call a no-grad forward, then forward + backward); "
        "peak MB is the growth of the process's max RSS during those calls (largest "
        "round).",
        "",
        head,
        "|---|---|---|---|---|---|" + "---|" * (len(cols) * (2 if before else 1)),
    ]
    for res in rows:
        r = res["after"]
        line = (
            f"| {r['n']:,} | {r['w']}x{r['h']} | {r['dist']:g} | {r['visible']:,} | {r['pairs']:,} | "
            f"{r['alpha']:.2f} |"
        )
        for c in cols:
            fmt = ".0f" if c.endswith("mb") else ".3f"
            vals = [res["before"][c], r[c]] if before else [r[c]]
            line += "".join(f" {v:{fmt}} |" for v in vals)
        lines.append(line)
    lines += [
        "",
        f"Threads (this checkout, {THREADS_CASE[0]:,} Gaussians at {THREADS_CASE[1]}x{THREADS_CASE[2]}, "
        "medians of the same alternating rounds):",
        "",
        "| torch threads | fwd s | fwd+bwd s | fwd CPU s | fwd+bwd CPU s |",
        "|---|---|---|---|---|",
    ]
    for k, r in threads.items():
        lines.append(f"| {k} | {r['fwd']:.3f} | {r['both']:.3f} | {r['fwd_cpu']:.3f} | {r['both_cpu']:.3f} |")
    text = "\n".join(lines) + "\n"
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(args.out) or ".", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, args.out)
    print(text)


if __name__ == "__main__":
    main()
