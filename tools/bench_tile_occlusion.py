"""What other tiles hide of each tile, and how much of it the tiles' opaque depths recover (bench/tiles.md,
"What other tiles hide").

    python tools/bench_tile_occlusion.py --scene /work/district/district_1000000 --cameras 12

Per tile of the default size: the blending weight each Gaussian takes over the views (the precision
measure's ``weight``, gspc/encoder/significance.py) at evenly spaced cameras, measured three ways: the tile
alone (what a tile's encoder saw without occlusion), the whole scene (the truth), and the tile alone with
what the other tiles hide (gspc/encoder/occlusion.py, as the encoder now measures). Printed as a markdown
table: each measure's sum over the tile against the whole scene's, and the Gaussians the whole scene all but
hides (under 1/1000 of their weight alone) and how many of those the occlusion maps find (under 1/10).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from gspc.encoder.occlusion import Occluders, map_cell, opaque_depths, scene_views
from gspc.encoder.significance import evenly_spaced, significance
from gspc.encoder.tiles import plan_tiles
from gspc.io import read_scene
from gspc.io.camera_files import load_cameras
from gspc.presets import quality_preset


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, required=True, help="a folder with point_cloud.ply, cameras.json")
    ap.add_argument("--cameras", type=int, default=12, help="evenly spaced cameras measured")
    ap.add_argument("--tile-size", type=int, default=1 << 18)
    args = ap.parse_args()
    torch.set_num_threads(1)
    scene = read_scene(args.scene / "point_cloud.ply")
    cams = evenly_spaced(load_cameras(args.scene / "cameras.json"), args.cameras)
    means = scene.means.detach().numpy().astype(np.float64)
    log_scales = scene.log_scales.detach().numpy().astype(np.float64)
    bits = quality_preset("low").attributes.position_precision
    plan = plan_tiles(means, log_scales, bits, args.tile_size)
    t0 = time.perf_counter()
    whole = significance(scene, cams).weight
    whole_s = time.perf_counter() - t0
    views = scene_views(cams)
    occ = Occluders(views, map_cell(views))
    t0 = time.perf_counter()
    for k, rows in enumerate(plan.rows):
        occ.fold(k, opaque_depths(scene.subset(rows), views, occ.cell))
    depth_s = time.perf_counter() - t0
    print(
        f"{scene.num_gaussians:,} Gaussians, {len(plan.rows)} tiles, {len(cams)} cameras (maps at "
        f"1/{occ.cell}); whole-scene measure {whole_s:.0f} s, the tiles' opaque depths {depth_s:.0f} s\n"
    )
    print("| tile | Gaussians | alone / whole | with occlusion / whole | all but hidden | of those found |")
    print("|---:|---:|---:|---:|---:|---:|")
    for k, rows in enumerate(plan.rows):
        tile = scene.subset(rows)
        alone = significance(tile, cams).weight
        seen = significance(tile, cams, occlusion=occ.others(k)).weight
        w = whole[rows]
        hidden = (alone > 0) & (w < 1e-3 * alone)
        found = hidden & (seen < 0.1 * alone)
        share = hidden.sum() / max(1, (alone > 0).sum())
        print(
            f"| {k} | {len(rows):,} | {alone.sum() / w.sum():.3f} | {seen.sum() / w.sum():.3f} | "
            f"{hidden.sum():,} ({share:.2%}) | {found.sum():,} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
