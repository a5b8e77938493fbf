"""The real scenes that the large synthetic workloads are built from (tools/make_scale_scenes.py,
tools/make_district.py), normalised to a common size and orientation, and similarity transforms of them.

The assets: the five captured statues (../shared/data/statues/*.sog, SH degree 0), the trained donut
(../shared/data/donut/fused.ply, SH degree 0), the lego fit (examples/lego/point_cloud.ply, SH degree 3) and,
where one is given, a fitted capture such as the bird (tools/fit_scene.py; its room is cropped away).
Each is centred on its robust box (gspc.views.robust_bounds) and scaled so the box's longest side is 1, with
z up (the statues' SOG files are y-down). A :class:`Placement` turns, scales and moves a copy; a turned
copy's SH rest turns with it (tools/sh_rotation.py), so its view-dependent colour follows the copy.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from sh_rotation import rotate_sh_rest

from gspc.io import read_scene
from gspc.io.camera_files import load_cameras
from gspc.scene import make_scene, num_sh_rest, sh_degree_from_rest
from gspc.views import robust_bounds

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
if not DATA.exists():
    DATA = Path("/work/shared/data")
STATUES = ["angel.sog", "angel-kneeling.sog", "angel-with-candlestick.sog", "massa.sog", "trumpet.sog"]
LEGO = REPO / "examples" / "lego" / "point_cloud.ply"
# A fitted capture keeps the Gaussians within this many times its cameras' mean distance from the point
# they look at: the object on its table, not the room the cameras stand in.
CAPTURE_CROP = 0.5


def asset_paths() -> list[Path]:
    """The standard assets in the order they are cycled."""
    return [DATA / "statues" / s for s in STATUES] + [DATA / "donut" / "fused.ply", LEGO]


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


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit (w, x, y, z) quaternion."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def axis_angle(axis, angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrix and (w, x, y, z) quaternion of ``angle`` radians about a unit ``axis``."""
    a = np.asarray(axis, dtype=np.float64)
    q = np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * a])
    return quat_matrix(q), q


def turn_to(v: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The shortest rotation (matrix, quaternion) taking direction ``v`` to direction ``target``."""
    v, target = (np.asarray(u, np.float64) / np.linalg.norm(u) for u in (v, target))
    axis = np.cross(v, target)
    s, c = float(np.linalg.norm(axis)), float(np.dot(v, target))
    if s < 1e-12:  # parallel or opposite: any axis across v
        if c > 0:
            return axis_angle((1.0, 0.0, 0.0), 0.0)
        axis = np.cross(v, np.eye(3)[np.argmin(np.abs(v))])
        return axis_angle(axis / np.linalg.norm(axis), math.pi)
    return axis_angle(axis / s, math.atan2(s, c))


@dataclass
class Placement:
    """A similarity transform of a normalised asset: x -> scale * rotation @ x + offset, and ``dc_shift``
    added to every Gaussian's SH DC (a copy's own tint)."""

    rotation: np.ndarray  # (3, 3)
    quat: np.ndarray  # (4,) the same rotation as (w, x, y, z)
    offset: np.ndarray  # (3,) where the asset's centre goes
    scale: float = 1.0
    dc_shift: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class Asset:
    """One real scene, normalised (centred on its robust box, longest side 1, z up), as float64 arrays."""

    name: str
    means: np.ndarray  # (N, 3)
    quats: np.ndarray  # (N, 4)
    log_scales: np.ndarray  # (N, 3)
    opacities: np.ndarray  # (N,)
    sh_dc: np.ndarray  # (N, 3)
    sh_rest: np.ndarray  # (N, K, 3), zero beyond the source's own degree
    sh_degree: int  # the source's SH degree
    half: np.ndarray  # (3,) half-sides of the robust box after normalising

    @property
    def n(self) -> int:
        return len(self.means)

    def subset(self, index: np.ndarray) -> Asset:
        """The same asset with only the Gaussians ``index`` selects (a smaller asset for tests)."""
        pick = {k: getattr(self, k)[index] for k in ("means", "quats", "log_scales", "opacities", "sh_dc")}
        return Asset(self.name, **pick, sh_rest=self.sh_rest[index], sh_degree=self.sh_degree, half=self.half)

    def placed(self, p: Placement) -> dict[str, np.ndarray]:
        """Attribute arrays of a copy moved by ``p`` (make_scene's keywords). A turned copy's SH rest turns
        with it; an identity rotation, a unit scale and a zero shift leave those attributes untouched."""
        means, quats, rest = self.means, self.quats, self.sh_rest
        if not np.array_equal(p.rotation, np.eye(3)):
            means, quats = means @ p.rotation.T, quat_mul(p.quat, quats)
            if self.sh_degree > 0 and rest.shape[1]:  # the SH-degree-0 sources' rest is zero
                rest = rotate_sh_rest(rest, p.rotation, sh_degree_from_rest(rest.shape[1]))
        return {
            "means": (means * p.scale if p.scale != 1.0 else means) + p.offset,
            "quats": quats,
            "log_scales": self.log_scales + math.log(p.scale) if p.scale != 1.0 else self.log_scales,
            "opacities": self.opacities,
            "sh_dc": self.sh_dc + p.dc_shift if np.any(p.dc_shift) else self.sh_dc,
            "sh_rest": rest,
        }


def normalise(scene, name: str, sh_degree: int = 3, turn_x: float = 0.0) -> Asset:
    """``scene`` (a GaussianScene) centred on its robust box, scaled to a longest side of 1, then turned by
    ``turn_x`` radians about x; its SH rest padded with zeros or cut to ``sh_degree``."""
    lo, hi = robust_bounds(scene)
    s = 1.0 / float(np.max(hi - lo))
    means = (scene.means.double().numpy() - (lo + hi) / 2) * s
    quats = scene.quats.double().numpy()
    half = (hi - lo) * s / 2
    if turn_x:
        R, q = axis_angle((1.0, 0.0, 0.0), turn_x)
        means, quats = means @ R.T, quat_mul(q, quats)
        half = np.abs(R) @ half
    n = scene.num_gaussians
    rest = np.zeros((n, num_sh_rest(sh_degree), 3))
    k = min(rest.shape[1], scene.sh_rest.shape[1])
    rest[:, :k] = scene.sh_rest[:, :k].double().numpy()
    return Asset(
        name=name,
        means=means,
        quats=quats,
        log_scales=scene.log_scales.double().numpy() + math.log(s),
        opacities=scene.opacities.double().numpy(),
        sh_dc=scene.sh_dc.double().numpy(),
        sh_rest=rest,
        sh_degree=scene.sh_degree,
        half=half,
    )


def load_asset(path: Path, sh_degree: int = 3, upright: bool = True) -> Asset:
    """A standard asset from its file. The statues' SOG files are y-down: -90 degrees about x stands them
    upright; ``upright=False`` turns them +90 degrees, onto their heads, as tools/make_scale_scenes.py does
    (its files stay the ones bench/scale.md measured)."""
    turn = (-1.0 if upright else 1.0) * math.pi / 2 if path.suffix == ".sog" else 0.0
    return normalise(read_scene(path), path.name, sh_degree, turn)


def load_capture(path: Path, sh_degree: int = 3) -> Asset:
    """A fitted capture (tools/fit_scene.py's point_cloud.ply with its cameras.json beside it): turned so its
    cameras' mean up is z, and cropped to the Gaussians within CAPTURE_CROP of its cameras' mean distance
    from the point they look at (the object, without the room). Without cameras.json it is taken whole,
    as it stands."""
    from fit_scene import cameras_focus

    scene = read_scene(path)
    cams_path = path.parent / "cameras.json"
    if not cams_path.is_file():
        return normalise(scene, path.name, sh_degree)
    cams = load_cameras(cams_path)
    focus, radius = cameras_focus(cams)
    up = -np.mean([c.world_to_cam[1, :3] for c in cams], axis=0)  # OpenCV: image y points down
    keep = np.linalg.norm(scene.means.double().numpy() - focus, axis=1) <= CAPTURE_CROP * radius
    if not keep.any():
        keep[:] = True
    R, q = turn_to(up, np.array([0.0, 0.0, 1.0]))
    part = scene.subset(keep)
    rest = part.sh_rest.double().numpy()
    turned = make_scene(
        (part.means.double().numpy() - focus) @ R.T,
        quat_mul(q, part.quats.double().numpy()),
        part.log_scales,
        part.opacities,
        part.sh_dc,
        rotate_sh_rest(rest, R, part.sh_degree) if part.sh_degree else rest,
        part.sh_degree,
        dtype=torch.float64,
    )
    return normalise(turned, path.name, sh_degree)


def plan(assets: list, target: int) -> list[int]:
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
