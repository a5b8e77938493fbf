"""Time gspc's torch renderer on a GPU at several walk sizes (gspc/render/rasterize.py WalkSizes), side by
side in one process, on a scale scene's close-up views; gsplat beside them where it is importable.

    python tools/bench_gpu_walk.py --scene /work/scale/scale_1000000 [--views 3] [--repeats 2] \
        [--budgets 19,21,23,25] [--gsplat] [--out bench/gpu_walk.md] [--device cuda]

Each configuration renders the same views (tools/bench_scale_pipeline.py's close-ups, 400x300): a no-grad
forward, and a forward and backward of a weighted sum of the image (refinement's case). Times are wall
seconds per view after one warm-up round, synchronised, the median of ``--repeats`` rounds; the largest
pixel difference is against the first configuration (CPU_WALK's sizes, what the GPU used before). The
composite's own forward time (the walk, without projection and tile lists) is timed apart. ``--device cpu``
is the tool's dry run (the walk on the CPU; tests/test_gpu.py).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

import gspc.render.api as api
import gspc.render.rasterize as rast
from gspc.device import synchronize
from gspc.io import read_scene
from gspc.render import render
from gspc.scene import ATTRIBUTE_NAMES

REPO = Path(__file__).resolve().parent.parent


def configurations(budgets: list[int]) -> list[tuple[str, rast.WalkSizes | None]]:
    """(label, sizes) pairs: the CPU's sizes first (the reference), then each budget with one-kernel scans;
    sizes None means gsplat."""
    out = [("CPU_WALK (2^19, looped scans)", rast.CPU_WALK)]
    for b in budgets:
        sizes = rast.WalkSizes(1 << b, rast.GPU_WALK.scan_loop_from)
        mark = " = GPU_WALK" if sizes == rast.GPU_WALK else ""
        out.append((f"2^{b}, one-kernel scans{mark}", sizes))
    return out


def time_view(scene, cam, weights, backend: str, device: torch.device) -> tuple[float, float, torch.Tensor]:
    """(forward s, forward + backward s, image) of one view."""
    synchronize(device)
    t0 = time.perf_counter()
    with torch.no_grad():
        image = render(scene, cam, backend=backend).image
    synchronize(device)
    t1 = time.perf_counter()
    s = scene.detach()
    for name in ATTRIBUTE_NAMES:
        getattr(s, name).requires_grad_(True)
    (render(s, cam, backend=backend).image * weights).sum().backward()
    synchronize(device)
    return t1 - t0, time.perf_counter() - t1, image


def main() -> None:
    from bench_scale_pipeline import closeup_cameras

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--scene", type=Path, required=True, help="a scale scene folder (tools/make_scale_scenes.py)"
    )
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument(
        "--budgets", default="19,21,23,25", help="log2 step budgets to time with one-kernel scans"
    )
    ap.add_argument("--gsplat", action="store_true", help="also time gsplat (backend 'gsplat')")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "gpu_walk.md")
    ap.add_argument("--device", default="cuda")
    args = ap.parse_args()
    device = torch.device(args.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise SystemExit("bench_gpu_walk: no CUDA GPU here: nothing measured, nothing written")
    meta = json.loads((args.scene / "scene.json").read_text())
    cams = closeup_cameras(meta, 1)
    cams = [cams[round(i * (len(cams) - 1) / max(1, args.views - 1))] for i in range(args.views)]
    scene = read_scene(args.scene / "point_cloud.ply").to(device)
    g = torch.Generator().manual_seed(0)
    weights = [torch.rand(c.height, c.width, 3, generator=g).to(device) for c in cams]
    configs = configurations([int(b) for b in args.budgets.split(",") if b])
    if args.gsplat:
        configs.append(("gsplat", None))

    walk_seconds: list[float] = []
    composite = api.composite

    def timed_composite(*a, **k):  # the walk's forward alone (the backward runs inside autograd)
        synchronize(device)
        t = time.perf_counter()
        out = composite(*a, **k)
        synchronize(device)
        walk_seconds.append(time.perf_counter() - t)
        return out

    api.composite = timed_composite
    rows, reference = [], None
    for label, sizes in configs:
        backend = "gsplat" if sizes is None else "torch"
        if sizes is not None:
            rast.GPU_WALK = rast.CPU_WALK = sizes  # this process's walk, whatever the device
        fwd, both, walk, images = [], [], [], []
        for rnd in range(args.repeats + 1):
            walk_seconds.clear()
            times = [time_view(scene, c, w, backend, device) for c, w in zip(cams, weights)]
            if rnd == 0:
                images = [t[2].float().cpu() for t in times]
                continue  # warm-up
            fwd.append(sum(t[0] for t in times) / len(cams))
            both.append(sum(t[1] for t in times) / len(cams))
            # composite runs once per forward: the no-grad one and the one before the backward
            walk.append(sum(walk_seconds) / (2 * len(cams)) if walk_seconds else float("nan"))
        if reference is None:
            reference = images
        diff = max(float((a - b).abs().max()) for a, b in zip(images, reference))
        row = {
            "config": label,
            "forward_s": statistics.median(fwd),
            "forward_backward_s": statistics.median(both),
            "walk_forward_s": statistics.median(walk) if sizes is not None else float("nan"),
            "max_diff": diff,
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
    api.composite = composite

    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "no GPU"
    base = rows[0]["forward_backward_s"]
    lines = [
        "# gspc's torch renderer on a GPU: walk sizes side by side",
        "",
        f"Command: `python {' '.join(sys.argv)}`",
        "",
        f"Machine: {name}, {os.cpu_count()} vCPUs, Python {platform.python_version()}, "
        f"torch {torch.__version__}. "
        f"Scene: {args.scene.name}, {scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}; "
        f"{len(cams)} close-up views at {cams[0].width}x{cams[0].height}; median of {args.repeats} rounds "
        "after a warm-up.",
        "",
        "| walk sizes | forward s/view | forward+backward s/view | the walk's forward s/view "
        "| fwd+bwd speed-up | largest pixel difference vs the first row |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['config']} | {r['forward_s']:.3f} | {r['forward_backward_s']:.3f} | "
            f"{r['walk_forward_s']:.3f} | {base / r['forward_backward_s']:.1f}x | {r['max_diff']:.2e} |"
        )
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
