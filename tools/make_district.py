"""Build a district: tens of millions of Gaussians from real scans laid out on a street grid, with cameras.

    python tools/make_district.py -o /work/district --gaussians 10000000 [--seed 0] [--views 48]
        [--size 400x300] [--bird FIT/point_cloud.ply] [--no-backdrop]

The copies are whole real scenes (tools/scale_assets.py): the five captured statues, the donut, the lego fit
and, with ``--bird``, a fitted capture (the bird of tools/README.md), cycled to just past the size and
shuffled. Nothing is cut and no two copies are alike:

- the district is a grid of blocks between streets; a block holds 3 x 2 lots, a lot one house, a house
  two to five copies on the four spots of its lot, a copy on an occupied spot stacked on the one below;
- each copy turns about the up axis by its own angle, tilts a little about its own horizontal axis, scales
  by its own factor (0.5-3, less where its footprint would leave its spot), moves by its own jitter within
  its spot and gets its own small colour shift (SH DC); a turned copy's SH rest turns with it
  (tools/sh_rotation.py), so the lego's view-dependent colour follows it;
- with the backdrop (the default), flat ground Gaussians (streets, pavements, grass around) and a dome of
  large sky Gaussians make the scene unbounded like a capture.

The PLY (INRIA layout, SH degree 3) is streamed copy by copy after a header with the final count, so
memory holds the assets and one copy, never the scene. The same arguments give the same bytes.

Cameras (cameras.json, INRIA layout): two thirds at street level on the streets, each looking at a house,
one third aerial (two overviews of the whole district, the rest oblique views of single
blocks). The share of the Gaussians some camera sees (gspc.visibility.visible_mask, on an even sample of
rows; occlusion ignored), and the share of the copies' Gaussians in each view, is printed and kept in
scene.json, which also lists every copy: its asset, its rows and its transform.
Outputs stay outside the repository (large files).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from ply_stream import write_ply_parts
from scale_assets import Asset, Placement, asset_paths, axis_angle, load_asset, load_capture, plan, quat_mul
from sh_rotation import sphere_directions

from gspc.cameras import Camera
from gspc.errors import GspcError
from gspc.io.cameras_json import save_cameras_json
from gspc.limits import MAX_CAMERA_SIDE
from gspc.scene import SH_C0, GaussianScene, make_scene
from gspc.views import look_at
from gspc.visibility import visible_mask

# Lengths are in units of a normalised asset's longest side (tools/scale_assets.py).
SPOT = 2.0  # pitch of a lot's 2 x 2 spots: a copy's footprint stays within its spot
LOT = 4.4  # pitch of the lots in a block
BLOCK_LOTS = (3, 2)  # lots per block along x and y
STREET = 4.0  # width of a street
HOUSE_SIZES = (2, 5)  # copies per house, inclusive
STACK = 3  # copies per spot at most
SCALES = (0.5, 3.0)  # a copy's scale, log-uniform
TILT_DEG = 6.0  # largest tilt off the vertical
JITTER = 0.12  # largest move within a spot, a fraction of SPOT
TINT = 0.04  # standard deviation of a copy's colour shift, per channel (RGB units)
GROUND_PITCH = 0.5
GROUND_MARGIN = 2 * STREET  # grass around the district
SKY_GAUSSIANS = 2000
SKY_RADIUS = 3.0  # times the ground's half diagonal
EYE_HEIGHT = 0.8
STREET_FOV, AERIAL_FOV = 70.0, 60.0  # horizontal fields of view, degrees
SAMPLE_ROWS = 200_000  # rows sampled for the visible share
SH_DEGREE = 3


@dataclass
class Copy:
    asset: int
    placement: Placement
    block: int
    house: int


@dataclass
class District:
    copies: list[Copy]
    blocks: tuple[int, int]  # blocks along x and y
    block_lo: np.ndarray  # (B, 2) lower corner of each block's lots
    streets_x: np.ndarray  # x of the centre lines of the streets that run along y
    streets_y: np.ndarray  # y of the centre lines of the streets that run along x
    lo: np.ndarray  # (2,) corner of the district, outer streets included
    hi: np.ndarray

    @property
    def block_size(self) -> np.ndarray:
        return np.array(BLOCK_LOTS, np.float64) * LOT

    @property
    def radius(self) -> float:
        return float(np.linalg.norm(self.hi - self.lo) / 2)


def _turn(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A copy's own rotation: a turn about the up axis, then a small tilt about a horizontal axis."""
    R_yaw, q_yaw = axis_angle((0.0, 0.0, 1.0), rng.uniform(0.0, 2 * math.pi))
    a = rng.uniform(0.0, 2 * math.pi)
    R_tilt, q_tilt = axis_angle((math.cos(a), math.sin(a), 0.0), math.radians(rng.uniform(0.0, TILT_DEG)))
    return R_tilt @ R_yaw, quat_mul(q_tilt, q_yaw[None])[0]


def layout(assets: list[Asset], order: list[int], rng: np.random.Generator) -> District:
    """Place the copies ``order`` (asset indices) house by house on lots spread evenly over a square-ish grid
    of blocks."""
    houses, k = [], 0
    while k < len(order):
        size = int(rng.integers(HOUSE_SIZES[0], HOUSE_SIZES[1] + 1))
        houses.append(order[k : k + size])
        k += size
    per_block = BLOCK_LOTS[0] * BLOCK_LOTS[1]
    gx = math.ceil(math.sqrt(math.ceil(len(houses) / per_block)))
    gy = math.ceil(math.ceil(len(houses) / per_block) / gx)
    n_blocks, n_lots = gx * gy, gx * gy * per_block
    pitch = np.array(BLOCK_LOTS, np.float64) * LOT + STREET
    span = np.array([gx, gy]) * pitch - STREET  # the blocks' extent, streets between them
    origin = -span / 2
    block_lo = np.array([origin + pitch * (b % gx, b // gx) for b in range(n_blocks)])
    spots = np.array([(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)]) * SPOT
    copies = []
    for h, members in enumerate(houses):
        block, lot = divmod(h * n_lots // len(houses), per_block)  # the houses spread over every block
        lot_centre = block_lo[block] + (np.array(divmod(lot, BLOCK_LOTS[1])) + 0.5) * LOT
        height, used = np.zeros(len(spots)), np.zeros(len(spots), int)
        for i in members:
            a = assets[i]
            free = np.flatnonzero(used < STACK)
            spot = int(free[rng.integers(len(free))])
            fit = (
                0.95 * SPOT / (2 * math.hypot(a.half[0], a.half[1]))
            )  # the footprint's radius within the spot
            scale = min(math.exp(rng.uniform(math.log(SCALES[0]), math.log(SCALES[1]))), fit)
            R, q = _turn(rng)
            xy = lot_centre + spots[spot] + rng.uniform(-JITTER, JITTER, 2) * SPOT
            z = height[spot] + scale * a.half[2]
            height[spot] += 2 * scale * a.half[2]
            used[spot] += 1
            tint = rng.normal(0.0, TINT, 3) / SH_C0
            copies.append(Copy(i, Placement(R, q, np.array([xy[0], xy[1], z]), scale, tint), block, h))
    streets_x = origin[0] - STREET / 2 + pitch[0] * np.arange(gx + 1)
    streets_y = origin[1] - STREET / 2 + pitch[1] * np.arange(gy + 1)
    lo, hi = origin - STREET, origin + span + STREET
    return District(copies, (gx, gy), block_lo, streets_x, streets_y, lo, hi)


def _flat(means, log_scales, opacity, colours, rng) -> GaussianScene:
    n = len(means)
    colours = np.clip(colours + rng.normal(0.0, 0.03, (n, 3)), 0.0, 1.0)
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    rest = torch.zeros(n, (SH_DEGREE + 1) ** 2 - 1, 3)
    return make_scene(means, quats, log_scales, np.full(n, opacity), (colours - 0.5) / SH_C0, rest, SH_DEGREE)


def ground(d: District, rng: np.random.Generator) -> GaussianScene:
    """Flat Gaussians on z = 0 over the district and a margin around it: asphalt on the streets, paving in
    the blocks, grass beyond the outer streets."""
    lo, hi = d.lo - GROUND_MARGIN, d.hi + GROUND_MARGIN
    xs = np.arange(lo[0], hi[0] + 1e-9, GROUND_PITCH)
    ys = np.arange(lo[1], hi[1] + 1e-9, GROUND_PITCH)
    gx, gy = np.meshgrid(xs, ys, indexing="xy")
    xy = np.stack([gx.ravel(), gy.ravel()], 1)
    colours = np.tile([0.32, 0.32, 0.34], (len(xy), 1))  # asphalt
    outside = ((xy < d.lo) | (xy > d.hi)).any(1)
    colours[outside] = (0.33, 0.45, 0.22)  # grass
    for b in d.block_lo:
        inside = ((xy >= b) & (xy <= b + d.block_size)).all(1)
        colours[inside] = (0.62, 0.58, 0.52)  # paving
    means = np.concatenate([xy, np.zeros((len(xy), 1))], 1)
    log_scales = np.tile(np.log([0.6 * GROUND_PITCH, 0.6 * GROUND_PITCH, 0.02]), (len(xy), 1))
    return _flat(means, log_scales, 4.0, colours, rng)


def sky(d: District, rng: np.random.Generator) -> GaussianScene:
    """A sphere of large Gaussians far around the district: sky above the horizon, pale there and blue at
    the zenith, and distant land below it, so every view beyond the ground meets something."""
    radius = SKY_RADIUS * (d.radius + GROUND_MARGIN)
    dirs = sphere_directions(SKY_GAUSSIANS)
    elevation = np.clip(dirs[:, 2:3], 0.0, 1.0)
    colours = (1 - elevation) * np.array([0.85, 0.89, 0.94]) + elevation * np.array([0.36, 0.55, 0.85])
    colours[dirs[:, 2] < -0.02] = (0.30, 0.36, 0.26)
    sigma = 0.8 * radius * math.sqrt(2 * math.pi / len(dirs))
    log_scales = np.full((len(dirs), 3), math.log(sigma))
    return _flat(dirs * radius, log_scales, 2.0, colours, rng)


def _camera(eye, target, fov_deg: float, size: tuple[int, int], name: str) -> Camera:
    w, h = size
    f = 0.5 * w / math.tan(math.radians(fov_deg) / 2)
    K = np.array([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]])
    return Camera(look_at(np.asarray(eye), np.asarray(target), np.array([0.0, 0.0, 1.0])), K, w, h, name)


def street_cameras(d: District, n: int, size, rng: np.random.Generator) -> list[Camera]:
    """``n`` cameras at eye height on the streets' centre lines, each looking at a house (a random one)
    from 3-9 units along the street nearest to it (along x and along y in turn), past it into the
    district beyond."""
    at = np.array([c.placement.offset[:2] for c in d.copies])
    house_of = np.array([c.house for c in d.copies])
    centres = np.array([at[house_of == h].mean(0) for h in np.unique(house_of)])
    cams = []
    for i in range(n):
        house = centres[int(rng.integers(len(centres)))]
        axis = i % 2  # 0: a street that runs along x (a line of constant y); 1: along y
        lines = d.streets_y if axis == 0 else d.streets_x
        line = lines[int(np.argmin(np.abs(lines - house[1 - axis])))]
        along = house[axis] + float(rng.choice([-1.0, 1.0])) * rng.uniform(3.0, 9.0)
        eye = np.array([along, line, EYE_HEIGHT]) if axis == 0 else np.array([line, along, EYE_HEIGHT])
        target = np.array([house[0], house[1], rng.uniform(0.8, 2.0)])
        cams.append(_camera(eye, target, STREET_FOV, size, f"street_{i:04d}"))
    return cams


def aerial_cameras(d: District, n: int, size, rng: np.random.Generator) -> list[Camera]:
    """``n`` aerial cameras: two overviews that frame the whole district from 60 degrees up, then oblique
    views of single blocks from around and above the district."""
    w, h = size
    half = math.atan(min(w, h) / w * math.tan(math.radians(AERIAL_FOV) / 2))  # the narrower half-angle
    reach = 1.05 * d.radius / math.sin(half)
    cams = []
    for i in range(n):
        if i < 2:
            a, up = math.pi / 4 + math.pi * i, math.radians(60.0)
            eye = reach * np.array([math.cos(a) * math.cos(up), math.sin(a) * math.cos(up), math.sin(up)])
            target = np.zeros(3)
        else:
            a = rng.uniform(0.0, 2 * math.pi)
            r = d.radius * rng.uniform(0.5, 1.1)
            eye = np.array([r * math.cos(a), r * math.sin(a), d.radius * rng.uniform(0.3, 0.8) + 3.0])
            b = d.block_lo[int(rng.integers(len(d.block_lo)))] + d.block_size / 2
            target = np.array([b[0], b[1], 1.0])
        cams.append(_camera(eye, target, AERIAL_FOV, size, f"aerial_{i:04d}"))
    return cams


def make_district(
    assets: list[Asset],
    target: int,
    folder: Path,
    seed: int = 0,
    views: int = 48,
    size: tuple[int, int] = (400, 300),
    backdrop: bool = True,
    command: str = "",
) -> dict:
    """Write ``folder``/point_cloud.ply, cameras.json and scene.json for a district of about ``target``
    Gaussians in copies of ``assets``; returns scene.json's content."""
    rng = np.random.default_rng(seed)
    order = [int(i) for i in rng.permutation(plan(assets, target))]
    d = layout(assets, order, rng)
    extras = [("ground", ground(d, rng)), ("sky", sky(d, rng))] if backdrop else []
    n_street = round(views * 2 / 3)
    cams = street_cameras(d, n_street, size, rng) + aerial_cameras(d, views - n_street, size, rng)
    count = sum(assets[c.asset].n for c in d.copies) + sum(s.num_gaussians for _, s in extras)
    stride = max(1, count // SAMPLE_ROWS)
    sample_means, sample_scales, sample_copy = [], [], []

    def parts():
        row = 0
        for c in d.copies:
            scene = make_scene(**assets[c.asset].placed(c.placement), sh_degree=SH_DEGREE)
            yield from _sampled(scene, row, True)
            row += scene.num_gaussians
        for _, scene in extras:
            yield from _sampled(scene, row, False)
            row += scene.num_gaussians

    def _sampled(scene: GaussianScene, row: int, is_copy: bool):
        pick = np.arange((-row) % stride, scene.num_gaussians, stride)
        sample_means.append(scene.means[pick].double().numpy())
        sample_scales.append(scene.log_scales[pick].double().numpy())
        sample_copy.append(np.full(len(pick), is_copy))
        yield scene

    os.makedirs(folder, exist_ok=True)
    write_ply_parts(folder / "point_cloud.ply", count, SH_DEGREE, parts())
    save_cameras_json(cams, folder / "cameras.json")
    means, scales = np.concatenate(sample_means), np.concatenate(sample_scales)
    is_copy = np.concatenate(sample_copy)
    seen = visible_mask(means, scales, cams)
    seen_street = visible_mask(means, scales, cams[:n_street])
    per_view = [float(visible_mask(means[is_copy], scales[is_copy], [c]).mean()) for c in cams]
    rows, record = 0, []
    for c in d.copies:
        p, a = c.placement, assets[c.asset]
        record.append(
            {
                "asset": a.name,
                "first_row": rows,
                "gaussians": a.n,
                "block": c.block,
                "house": c.house,
                "scale": p.scale,
                "quat_wxyz": p.quat.tolist(),
                "offset": p.offset.tolist(),
                "dc_shift": p.dc_shift.tolist(),
            }
        )
        rows += a.n
    backdrop_rows = []
    for name, scene in extras:
        backdrop_rows.append({"part": name, "first_row": rows, "gaussians": scene.num_gaussians})
        rows += scene.num_gaussians
    summary = {
        "target": target,
        "gaussians": count,
        "sh_degree": SH_DEGREE,
        "seed": seed,
        "transform": "x -> scale * R(quat_wxyz) x + offset, of the asset normalised by "
        "tools/scale_assets.py; log-scales + log(scale); SH DC + dc_shift; SH rest turned by R",
        "blocks": list(d.blocks),
        "extent": [d.lo.tolist(), d.hi.tolist()],
        "copies": record,
        "backdrop": backdrop_rows,
        "views": {"street": n_street, "aerial": views - n_street, "size": list(size)},
        "visible_share": {
            "all": float(seen.mean()),
            "copies": float(seen[is_copy].mean()),
            "copies_from_street": float(seen_street[is_copy].mean()),
            "copies_per_view_min": min(per_view),
            "copies_per_view_median": float(np.median(per_view)),
            "sampled_rows": int(len(seen)),
        },
        "command": command,
    }
    (folder / "scene.json").write_text(json.dumps(summary, indent=1))
    return summary


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size {text!r} is not WIDTHxHEIGHT (e.g. 400x300)") from None
    if not (0 < w <= MAX_CAMERA_SIDE and 0 < h <= MAX_CAMERA_SIDE):
        raise ValueError(f"--size {text}: each side must be in 1..{MAX_CAMERA_SIDE}")
    return w, h


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", default="/work/district", help="output folder (outside the repository)")
    ap.add_argument("--gaussians", type=int, default=10_000_000, help="the size: copies land just above it")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--views", type=int, default=48)
    ap.add_argument("--size", default="400x300", help="camera image size, WIDTHxHEIGHT")
    ap.add_argument("--bird", type=Path, help="a fitted capture's point_cloud.ply (tools/fit_scene.py)")
    ap.add_argument("--no-backdrop", action="store_true", help="no ground or sky Gaussians")
    args = ap.parse_args()
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    try:
        size = parse_size(args.size)
        if args.gaussians < 1 or args.views < 1:
            raise ValueError("--gaussians and --views must be at least 1")
        paths = asset_paths() + ([args.bird] if args.bird else [])
        missing = [str(p) for p in paths if not p.is_file()]
        if missing:
            raise ValueError(f"missing assets: {', '.join(missing)}")
        assets = [load_asset(p) for p in asset_paths()] + ([load_capture(args.bird)] if args.bird else [])
        folder = Path(args.out) / f"district_{args.gaussians}"
        command = "python tools/make_district.py " + " ".join(sys.argv[1:])
        s = make_district(
            assets, args.gaussians, folder, args.seed, args.views, size, not args.no_backdrop, command
        )
    except (GspcError, ValueError, OSError) as err:
        sys.exit(f"make_district: {err}")
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    size_gb = (folder / "point_cloud.ply").stat().st_size / 1e9
    v = s["visible_share"]
    blocks = "x".join(str(b) for b in s["blocks"])
    print(
        f"{folder}: {s['gaussians']:,} Gaussians in {len(s['copies'])} copies on {blocks} blocks, "
        f"{size_gb:.2f} GB, {time.perf_counter() - t0:.1f} s, peak RSS {rss:.0f} MB; visible share "
        f"{v['all']:.3f} (copies {v['copies']:.3f}, from the street {v['copies_from_street']:.3f}; "
        f"in one view: median {v['copies_per_view_median']:.3f}, least {v['copies_per_view_min']:.3f})",
        flush=True,
    )


if __name__ == "__main__":
    main()
