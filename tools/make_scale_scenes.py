"""Build the scale workload: scenes of about 100k, 300k, 1M and 3M Gaussians from real scenes, with cameras.

    python tools/make_scale_scenes.py [-o /work/scale] [--sizes 100000,300000,1000000,3000000] [--views 24]

Nothing is synthesised: the assets are the five captured statues (../shared/data/statues/*.sog), the
trained donut (../shared/data/donut/fused.ply) and the lego fit (examples/lego/point_cloud.ply). Each
scene is whole copies of them, cycled in that order, then one to three more chosen so the count passes
the size by the least (copies are never cut, so counts land a little above it), placed side by side on a
square grid in the x-y plane.
Every copy keeps all of its own Gaussians; only a similarity transform moves it:

- each asset is centred on its robust box (gspc.cameras.robust_bounds) and scaled so the box's longest
  side is 1 (positions times s, log-scales plus log s), so a donut sits beside a statue at the same size;
- the statues are stored y-up; they are turned z-up (a rotation of means and quaternions) like the
  lego and the donut;
- copies of the SH-degree-0 assets (statues, donut) turn about z by the golden angle per copy, so no two
  copies of an asset share a voxel grid; the lego (SH degree 3) only moves, since rotating it would need
  its SH coefficients rotated too;
- the scene has SH degree 3 (the lego's); the other assets get zero SH rest, which the codec codes as
  "no view-dependent colour" (README, attribute codec). ``--sh-degree 0`` drops the lego's SH rest
  instead (its view-dependent colour is lost), for comparison with SH-degree-0 scenes.

Each size is written as OUT/scale_<N>/point_cloud.ply with OUT/scale_<N>/cameras.json: ``--views``
cameras at 400x300 on a sphere around the whole grid (gspc.cameras.synthesize_views, z up), and
OUT/scale_<N>/scene.json listing the copies. Outputs stay outside the repository (large files).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
if not DATA.exists():
    DATA = Path("/work/shared/data")
STATUES = ["angel.sog", "angel-kneeling.sog", "angel-with-candlestick.sog", "massa.sog", "trumpet.sog"]
SPACING = 1.5  # grid pitch in units of an asset's longest side: a gap between neighbours


def asset_paths() -> list[Path]:
    """The assets in the order they are cycled."""
    return [DATA / "statues" / s for s in STATUES] + [
        DATA / "donut" / "fused.ply",
        REPO / "examples" / "lego" / "point_cloud.ply",
    ]


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (w, x, y, z) quaternions; a (4,), b (N, 4)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b.T
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        1,
    )


def axis_angle(axis: tuple[float, float, float], angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrix and (w, x, y, z) quaternion of ``angle`` radians about a unit ``axis``."""
    a = np.asarray(axis, dtype=np.float64)
    q = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * a])
    w, x, y, z = q
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    return R, q


class Asset:
    """One real scene, normalised (centred, longest robust side 1, z up), as float64 numpy arrays."""

    def __init__(self, path: Path, sh_degree: int = 3):
        from gspc.io import read_scene
        from gspc.scene import num_sh_rest
        from gspc.views import robust_bounds

        scene = read_scene(path)
        self.name, self.n, self.sh_degree = path.name, scene.num_gaussians, scene.sh_degree
        lo, hi = robust_bounds(scene)
        s = 1.0 / float(np.max(hi - lo))
        means = (scene.means.double().numpy() - (lo + hi) / 2) * s
        quats = scene.quats.double().numpy()
        if path.suffix == ".sog":  # y-up capture -> z-up: +90 degrees about x takes y to z
            R, q = axis_angle((1.0, 0.0, 0.0), math.pi / 2)
            means, quats = means @ R.T, quat_mul(q, quats)
        self.means, self.quats = means, quats
        self.log_scales = scene.log_scales.double().numpy() + math.log(s)
        self.opacities = scene.opacities.double().numpy()
        self.sh_dc = scene.sh_dc.double().numpy()
        rest = np.zeros((self.n, num_sh_rest(sh_degree), 3))
        k = min(rest.shape[1], scene.sh_rest.shape[1])
        rest[:, :k] = scene.sh_rest[:, :k].double().numpy()
        self.sh_rest = rest

    def placed(self, centre: np.ndarray, yaw: float) -> dict[str, np.ndarray]:
        """This asset moved to ``centre`` (x, y) and turned ``yaw`` about z (SH degree 0 assets only)."""
        means, quats = self.means, self.quats
        if self.sh_degree == 0 and yaw:
            R, q = axis_angle((0.0, 0.0, 1.0), yaw)
            means, quats = means @ R.T, quat_mul(q, quats)
        return {
            "means": means + np.array([centre[0], centre[1], 0.0]),
            "quats": quats,
            "log_scales": self.log_scales,
            "opacities": self.opacities,
            "sh_dc": self.sh_dc,
            "sh_rest": self.sh_rest,
        }


def plan(assets: list[Asset], target: int) -> list[int]:
    """Asset index of each copy: cycle through the assets while more than two of the largest still fit,
    then finish with the one to three copies whose sum passes ``target`` by the least."""
    copies, total = [], 0
    largest = max(a.n for a in assets)
    while target - total > 2 * largest:
        i = len(copies) % len(assets)
        copies.append(i)
        total += assets[i].n
    rest = target - total
    tails = [c for k in (1, 2, 3) for c in itertools.combinations_with_replacement(range(len(assets)), k)]
    best = min(
        tails, key=lambda c: (sum(assets[i].n for i in c) < rest, abs(sum(assets[i].n for i in c) - rest))
    )
    return copies + list(best)


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
        parts.append(assets[i].placed(centre, yaw))
        turned = yaw if assets[i].sh_degree == 0 else 0.0
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
    assets = [Asset(p, args.sh_degree) for p in asset_paths()]
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
