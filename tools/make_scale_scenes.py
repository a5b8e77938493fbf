"""Build the scale workload: scenes of about 100k, 300k, 1M and 3M Gaussians from real scenes, with cameras.

    python tools/make_scale_scenes.py [-o /work/scale] [--sizes 100000,300000,1000000,3000000] [--views 24]

Nothing is synthesised: the assets are the five captured statues (../shared/data/statues/*.sog), the
trained donut (../shared/data/donut/fused.ply) and the lego fit (examples/lego/point_cloud.ply). Each
scene is whole copies of them, cycled in that order, then one to three more chosen so the count passes
the size by the least (copies are never cut, so counts land a little above it), placed side by side on a
square grid in the x-y plane.
Every copy keeps all of its own Gaussians; only a similarity transform moves it:

- each asset is centred on its robust box (gspc.cameras.robust_bounds) and scaled so the box's longest
  side is 1 (positions times s, log-scales plus log s; tools/scale_assets.py), so a donut sits beside a
  statue at the same size;
- the statues' SOG files are y-down; they are turned +90 degrees about x (a rotation of means and
  quaternions), which puts their vertical along z like the lego's and the donut's but stands them on their
  heads, as the workload bench/scale.md measured (tools/make_district.py stands them upright);
- copies of the SH-degree-0 assets (statues, donut) turn about z by the golden angle per copy, so no two
  copies of an asset share a voxel grid; the lego (SH degree 3) only moves, as in the workload
  bench/scale.md measured (tools/sh_rotation.py can turn its SH rest; tools/make_district.py does);
- the scene has SH degree 3 (the lego's); the other assets get zero SH rest, which the codec codes as
  "no view-dependent colour" (README, attribute codec). ``--sh-degree 0`` drops the lego's SH rest
  instead (its view-dependent colour is lost), for comparison with SH-degree-0 scenes.

Each size is written as OUT/scale_<N>/point_cloud.ply with OUT/scale_<N>/cameras.json: ``--views``
cameras at 400x300 on a sphere around the whole grid (gspc.cameras.synthesize_views, z up), and
OUT/scale_<N>/scene.json listing the copies. Outputs stay outside the repository (large files).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch
from scale_assets import Asset, Placement, asset_paths, axis_angle, load_asset, plan

SPACING = 1.5  # grid pitch in units of an asset's longest side: a gap between neighbours


def build(assets: list[Asset], target: int, sh_degree: int = 3):
    """The combined scene (gspc GaussianScene, float32) and a record of its copies."""
    from gspc.scene import make_scene

    copies = plan(assets, target)
    side = math.ceil(math.sqrt(len(copies)))
    golden = math.pi * (3.0 - math.sqrt(5.0))
    parts, record = [], []
    for k, i in enumerate(copies):
        row, col = divmod(k, side)
        centre = np.array([(col - (side - 1) / 2) * SPACING, (row - (side - 1) / 2) * SPACING])
        yaw = (golden * k) % (2 * math.pi)
        turned = yaw if assets[i].sh_degree == 0 else 0.0
        R, q = axis_angle((0.0, 0.0, 1.0), turned)
        parts.append(assets[i].placed(Placement(R, q, np.array([centre[0], centre[1], 0.0]))))
        record.append(
            {"asset": assets[i].name, "gaussians": assets[i].n, "centre": centre.tolist(), "yaw": turned}
        )
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    scene = make_scene(**cat, sh_degree=sh_degree)
    return scene, record


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", default="/work/scale", help="output folder (outside the repository)")
    ap.add_argument("--sizes", default="100000,300000,1000000,3000000")
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--sh-degree", type=int, default=3, choices=(0, 3))
    args = ap.parse_args()
    from gspc.io.cameras_json import save_cameras_json
    from gspc.io.ply import write_ply
    from gspc.views import synthesize_views

    torch.set_num_threads(1)
    missing = [str(p) for p in asset_paths() if not p.exists()]
    if missing:
        sys.exit(f"make_scale_scenes: missing assets: {', '.join(missing)}")
    assets = [load_asset(p, args.sh_degree, upright=False) for p in asset_paths()]
    for a in assets:
        print(f"{a.name}: {a.n:,} Gaussians, SH degree {a.sh_degree}", flush=True)
    for target in (int(s) for s in args.sizes.split(",")):
        t0 = time.perf_counter()
        scene, record = build(assets, target, args.sh_degree)
        folder = Path(args.out) / f"scale_{target}"
        os.makedirs(folder, exist_ok=True)
        write_ply(scene, folder / "point_cloud.ply")
        cams = synthesize_views(scene, args.views, width=400, height=300, up=(0.0, 0.0, 1.0))
        save_cameras_json(cams, folder / "cameras.json")
        summary = {
            "target": target,
            "gaussians": scene.num_gaussians,
            "sh_degree": args.sh_degree,
            "copies": record,
            "views": args.views,
            "command": "python tools/make_scale_scenes.py " + " ".join(sys.argv[1:]),
        }
        (folder / "scene.json").write_text(json.dumps(summary, indent=1))
        print(
            f"{folder}: {scene.num_gaussians:,} Gaussians in {len(record)} copies, "
            f"{time.perf_counter() - t0:.1f} s",
            flush=True,
        )


if __name__ == "__main__":
    main()
