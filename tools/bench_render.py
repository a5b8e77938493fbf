"""Benchmark the CPU renderer: its work (tile pairs, pixel visits) and seconds per render, before and after.

    git archive BASE gspc | tar -x -C /tmp/gspc_before      # the renderer to compare against
    python tools/bench_render.py --before /tmp/gspc_before [--after DIR] [--out bench/render.md] \\
        [--repeats 3] [--scene examples/lego/point_cloud.ply:examples/lego/cameras.json] [--scene statue.sog]

Cases: synthetic scenes (CASES) and real ones (``--scene PLY_OR_SOG[:CAMERAS_JSON]``; without cameras,
gspc.views.synthesize_views). Each case runs in fresh subprocesses, the variants alternating for
``--repeats`` rounds so that all see the same machine load: "before" (the gspc under ``--before``, first on
PYTHONPATH) and "after" (the one under ``--after``, default this checkout); ``--box`` adds "box" (after with
box tile lists instead of the exact ellipse test). Times are CPU seconds of one thread per render (mean
over a case's views; the median of a round's calls, then of the rounds): a no-grad forward, and a forward
and backward of the image's sum (refinement's case: a loss of the image alone). The "after" process also
counts the work: pairs in the tile lists, pairs walked before their tile stopped, and pixel visits (the
pixels of each walked pair's rows that its alpha >= 1/255 ellipse reaches: what a render must evaluate
whatever its kernel); and every variant saves its images, so the table gives the largest difference from
"before". A last table times the after code on 1 and 2 threads (wall seconds).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from functools import partial

import numpy as np
import torch

# (Gaussians, width, height, camera distance); 1.5 fills the frame, as real scenes do.
CASES = [(20_000, 256, 256, 3.0), (20_000, 400, 300, 3.0), (20_000, 800, 600, 3.0), (100_000, 256, 256, 3.0),
         (100_000, 400, 300, 3.0), (100_000, 800, 600, 3.0), (100_000, 400, 300, 1.5),
         (300_000, 400, 300, 3.0), (1_000_000, 400, 300, 3.0)]  # fmt: skip
THREADS_CASES = [(100_000, 400, 300, 3.0), (100_000, 400, 300, 1.5)]
PER_PROCESS = 3  # calls per subprocess in a side-by-side round; the median is that round's figure
SYNTH_VIEWS, SYNTH_SIZE, SCENE_VIEWS = 60, 320, 6  # real scenes without cameras: 6 of 60 views at 320x320
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


def load_case(spec: dict):
    """(name, scene, cameras) of a case spec: {"n", "w", "h", "dist"} or {"scene", "cameras"}."""
    if "n" in spec:
        return (
            f"{spec['n']:,} synthetic, distance {spec['dist']:g},",
            bench_scene(spec["n"]),
            [bench_camera(spec["w"], spec["h"], spec["dist"])],
        )
    from gspc.io import read_scene
    from gspc.io.camera_files import load_cameras
    from gspc.views import synthesize_views

    scene = read_scene(spec["scene"])
    if spec.get("cameras"):
        cams = load_cameras(spec["cameras"])
    else:
        cams = synthesize_views(scene, SYNTH_VIEWS, width=SYNTH_SIZE, height=SYNTH_SIZE)
    cams = cams[:: max(1, len(cams) // SCENE_VIEWS)][:SCENE_VIEWS]
    name = os.path.basename(os.path.dirname(spec["scene"])) if spec["scene"].endswith(".ply") else ""
    return (name or os.path.basename(spec["scene"])), scene, cams


def count_work(scene, cams) -> dict:
    """Summed over the views: pixels, tile pairs, pairs walked, pixel visits."""
    from gspc.render.project import project
    from gspc.render.rasterize import walk_counts

    sums = dict.fromkeys(("pixels", "pairs", "walked", "visits"), 0)
    for cam in cams:
        with torch.no_grad():
            p = project(*(scene.tensors()[k] for k in _ATTRS), cam, scene.sh_degree)
        args = (p.means2d, p.conics, p.opacities, torch.cat([p.colors, p.depths[:, None]], 1), p.depths)
        counts = walk_counts(*args, p.extents, cam.width, cam.height)
        for k in sums:
            sums[k] += getattr(counts, k)
    return sums


_ATTRS = ("means", "quats", "log_scales", "opacities", "sh_dc", "sh_rest")


def run_case(spec: dict, repeats: int, threads: int, variant: str, images: str | None) -> dict:
    """Time one case in this process: per render (mean over the views) a no-grad forward and a forward +
    backward, ``repeats`` times; CPU seconds, or wall seconds for the variant "wall"."""
    from gspc.render import api, rasterize

    torch.set_num_threads(threads)
    if variant == "box":  # this checkout with the box tile lists (the exact tile test off)
        rasterize.bin_tiles = partial(rasterize.bin_tiles, exact=False)
    name, scene, cams = load_case(spec)
    for t in scene.tensors().values():
        t.requires_grad_(True)
    clock = time.perf_counter if variant == "wall" else time.process_time
    with torch.no_grad():  # one untimed pass: compiled kernels load (or compile) on first use
        first = [api.render(scene, cam, backend="torch").image.numpy() for cam in cams]
    if images:
        np.savez(images, *first)
    runs = {"fwd": [], "both": []}
    for _ in range(repeats):
        t0 = clock()
        with torch.no_grad():
            for cam in cams:
                api.render(scene, cam, backend="torch")
        runs["fwd"].append((clock() - t0) / len(cams))
        t0 = clock()
        for cam in cams:
            api.render(scene, cam, backend="torch").image.sum().backward()
        runs["both"].append((clock() - t0) / len(cams))
    res = {"name": name, "views": len(cams), "size": f"{cams[0].width}x{cams[0].height}"}
    res |= {"gaussians": scene.num_gaussians} | {k: float(np.median(v)) for k, v in runs.items()}
    if variant == "after":
        res |= count_work(scene, cams)
    return res


def _case(spec: dict, threads: int, variant: str, path: str, images: str | None) -> dict:
    """One case in a fresh subprocess with ``path`` first on PYTHONPATH (the gspc it imports)."""
    cmd = [sys.executable, __file__, "--case", json.dumps(spec), "--variant", variant]
    cmd += ["--repeats", str(PER_PROCESS), "--threads", str(threads)]
    cmd += ["--images", images] if images else []
    env = dict(os.environ, PYTHONPATH=path)
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout
    return json.loads(out.splitlines()[-1])


def _max_diff(a: str, b: str) -> float:
    with np.load(a) as x, np.load(b) as y:
        return max(float(np.abs(x[k].astype(np.float64) - y[k]).max()) for k in x.files)


def side_by_side(spec: dict, repeats: int, variants: dict[str, tuple[str, int, str]], tmp: str) -> dict:
    """``repeats`` alternating rounds, one subprocess per variant (path, threads, run_case's variant) and
    round; per variant the medians of the rounds, plus the largest image difference from the first one."""
    runs: dict[str, list[dict]] = {k: [] for k in variants}
    for r in range(repeats):
        for k, (path, threads, mode) in variants.items():
            images = os.path.join(tmp, f"{k}.npz") if r == 0 else None
            runs[k].append(_case(spec, threads, mode, path, images))
    res = {}
    for k, rs in runs.items():
        res[k] = dict(rs[0]) | {key: float(np.median([r[key] for r in rs])) for key in ("fwd", "both")}
    first = next(iter(variants))
    for k in variants:
        res[k]["max_diff"] = _max_diff(os.path.join(tmp, f"{first}.npz"), os.path.join(tmp, f"{k}.npz"))
    return res


def _scene_spec(arg: str) -> dict:
    path, _, cams = arg.partition(":")
    return {"scene": path, "cameras": cams or None}


def _work_columns(r: dict) -> str:
    return " | ".join(f"{r[k] / r['pixels']:.2f}" for k in ("pairs", "walked", "visits"))


def _table(rows: list[dict], variants: list[str]) -> list[str]:
    """Seconds per render and ns per pixel visit (whole render / visits; backward = fwd+bwd - fwd) of each
    variant; the work is the same for all (the tile lists and the rules do not change between them)."""
    names = " / ".join(variants)
    head = (
        f"| case | Gaussians | views | pairs/px | walked pairs/px | visits/px | fwd s {names} "
        f"| fwd+bwd s {names} | ns/visit fwd | ns/visit bwd | after/before fwd | after/before bwd "
        "| after/before fwd+bwd | max image diff |"
    )
    lines = [head, "|---" * 14 + "|"]
    for res in rows:
        a, b = res["after"], res[variants[0]]
        visits = a["visits"] / a["views"]
        fwd = " / ".join(f"{res[k]['fwd']:.4f}" for k in variants)
        both = " / ".join(f"{res[k]['both']:.4f}" for k in variants)
        nsf = " / ".join(f"{res[k]['fwd'] / visits * 1e9:.1f}" for k in variants)
        nsb = " / ".join(f"{(res[k]['both'] - res[k]['fwd']) / visits * 1e9:.1f}" for k in variants)
        bwd_ratio = (a["both"] - a["fwd"]) / (b["both"] - b["fwd"])
        lines.append(
            f"| {a['name']} {a['size']} | {a['gaussians']:,} | {a['views']} | {_work_columns(a)} | {fwd} | "
            f"{both} | {nsf} | {nsb} | {a['fwd'] / b['fwd']:.2f} | {bwd_ratio:.2f} | "
            f"{a['both'] / b['both']:.2f} | {a['max_diff']:.1e} |"
        )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench/render.md")
    ap.add_argument("--repeats", type=int, default=3, help="alternating rounds per case")
    ap.add_argument("--before", help="folder holding the gspc package to compare against")
    ap.add_argument("--after", default=REPO, help="folder holding the gspc package measured as after")
    ap.add_argument("--box", action="store_true", help="also time after with box tile lists")
    ap.add_argument("--max-n", type=int, default=10**9, help="skip synthetic cases with more Gaussians")
    ap.add_argument("--scene", action="append", default=[], help="PLY_OR_SOG[:CAMERAS_JSON], repeatable")
    ap.add_argument("--no-threads", action="store_true", help="skip the 1 vs 2 threads table")
    ap.add_argument("--case", help=argparse.SUPPRESS)  # JSON case spec: run it here, print JSON
    ap.add_argument("--variant", default="after", help=argparse.SUPPRESS)
    ap.add_argument("--threads", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument("--images", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case:
        spec = json.loads(args.case)
        print(json.dumps(run_case(spec, args.repeats, args.threads, args.variant, args.images)))
        return
    after = os.path.abspath(args.after)
    variants = ({"box": (after, 1, "box")} if args.box else {}) | {"after": (after, 1, "after")}
    if args.before:
        variants = {"before": (os.path.abspath(args.before), 1, "before")} | variants
    specs = [{"n": n, "w": w, "h": h, "dist": d} for n, w, h, d in CASES if n <= args.max_n]
    specs += [_scene_spec(s) for s in args.scene]
    load = os.getloadavg()[0]
    rows, threads = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for spec in specs:
            rows.append(side_by_side(spec, args.repeats, variants, tmp))
            print(json.dumps(rows[-1]), flush=True)
        if not args.no_threads:
            for n, w, h, d in THREADS_CASES:
                spec = {"n": n, "w": w, "h": h, "dist": d}
                pair = {"1": (after, 1, "wall"), "2": (after, 2, "wall")}
                threads.append(side_by_side(spec, args.repeats, pair, tmp))
                print(json.dumps(threads[-1]), flush=True)
    names = list(variants)
    lines = [
        "# CPU renderer: work and seconds per render (one thread), before and after",
        "",
        f"Command: `python tools/bench_render.py --before {args.before or '-'} --after {args.after} "
        f"--repeats {args.repeats} --max-n {args.max_n}"
        + "".join(f" --scene {s}" for s in args.scene)
        + (" --no-threads" if args.no_threads else "")
        + "`",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} vCPUs, torch {torch.__version__}, one thread "
        f"(`torch.set_num_threads(1)`) unless stated; no GPU. Load average at the start: {load:.2f} (the "
        "machine is shared: see the reading). Seconds are CPU seconds of this process per render, the mean "
        f"over a case's views; the median over {args.repeats} rounds of each round's median of "
        f"{PER_PROCESS} calls, a fresh process per round and variant, variants alternating. Variants: "
        + ", ".join(names)
        + " (tools/bench_render.py's docstring); fwd+bwd: a forward and the backward of the image's sum. "
        "Work columns: per pixel, counted by gspc.render.rasterize.walk_counts in the after process (the "
        "same tile lists and rules in every variant); ns/visit = seconds / pixel visits, the backward's "
        "= (fwd+bwd - fwd) / visits. Max image diff: the largest |variant - before| of any pixel and "
        "channel over the views' forward images.",
        "",
        *_table(rows, names),
    ]
    if threads:
        lines += [
            "",
            "Threads (this checkout; wall seconds, both processes alternating on the same machine):",
            "",
            "| case | fwd s 1 thread | fwd s 2 threads | fwd+bwd s 1 thread | fwd+bwd s 2 threads |",
            "|---|---|---|---|---|",
        ]
        for res in threads:
            one, two = res["1"], res["2"]
            lines.append(
                f"| {one['name']} {one['size']} | {one['fwd']:.4f} | {two['fwd']:.4f} | {one['both']:.4f} | "
                f"{two['both']:.4f} |"
            )
    text = "\n".join(lines) + "\n"
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    fd, tmp_out = tempfile.mkstemp(dir=os.path.dirname(args.out) or ".", suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp_out, args.out)
    print(text)


if __name__ == "__main__":
    main()
