"""Views: cameras synthesised around scenes that come without any, the sampling of the views that carry
side information, and test splits; for any camera layout (objects or real captures)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from gspc.cameras import Camera, natural_key
from gspc.codec.positions import CORE_DISTANCES
from gspc.errors import InputError


def robust_bounds(scene, quantile: float = 0.002, min_opacity: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (lo, hi) holding the bulk of a scene's visible Gaussians.

    Gaussians beyond the scene's core (a background, far floaters) and below ``min_opacity`` are
    ignored (unless that leaves too few), and the rest weigh by opacity into per-axis ``quantile`` /
    ``1 - quantile`` quantiles, so sparse floaters do not stretch the box.
    """
    means = scene.means.detach().cpu().double().numpy().reshape(-1, 3)
    if len(means) == 0:
        raise InputError("scene has zero Gaussians")
    alpha = torch.sigmoid(scene.opacities.detach().cpu().double()).numpy().reshape(-1)  # no overflow warning
    # A capture's background shell and far floaters can be far more than `quantile` of the Gaussians: keep
    # only those within CORE_DISTANCES median distances of the median, the region the position codec keeps
    # uncontracted. Bounded objects lie wholly inside (statues reach 4.2).
    dist = np.sqrt(((means - np.median(means, axis=0)) ** 2).sum(1))
    core = dist <= CORE_DISTANCES * np.median(dist) if np.median(dist) > 0 else np.ones(len(means), bool)
    means, alpha = means[core], alpha[core]
    keep = alpha >= min_opacity
    if keep.sum() < max(1, 0.01 * len(means)):
        keep[:] = True
    means, alpha = means[keep], np.maximum(alpha[keep], 1e-6)
    lo, hi = np.empty(3), np.empty(3)
    for d in range(3):
        order = np.argsort(means[:, d], kind="stable")
        cw = np.cumsum(alpha[order])
        cw /= cw[-1]
        lo[d] = means[order[min(np.searchsorted(cw, quantile), len(cw) - 1)], d]
        hi[d] = means[order[min(np.searchsorted(cw, 1.0 - quantile), len(cw) - 1)], d]
    return lo, hi


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """World-to-camera (OpenCV axes) for a camera at ``eye`` looking at ``target``; image up ~ ``up``."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    fwd = target - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-6:
        # Looking along ``up``: borrow the world axis least aligned with the view direction.
        right = np.cross(fwd, np.eye(3)[np.argmin(np.abs(fwd))])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])  # rows: camera axes in world coordinates
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return w2c


def synthesize_views(
    scene,
    n: int,
    width: int = 512,
    height: int = 512,
    fov_deg: float = 50.0,
    margin: float = 1.25,
    up: Sequence[float] = (0.0, 0.0, 1.0),
) -> list[Camera]:
    """``n`` cameras on a Fibonacci sphere around the scene's robust box, all looking at its centre.

    ``fov_deg`` is the horizontal field of view. The distance makes the box's bounding sphere fit in
    the view with ``margin`` to spare (so every camera is outside the box); the sphere's poles lie
    along ``up``. Deterministic: the same scene and arguments give the same cameras.
    """
    if int(n) < 1:
        raise InputError(f"number of views must be at least 1, got {n}")
    if not 0.0 < fov_deg < 180.0:
        raise InputError(f"field of view {fov_deg} degrees is outside (0, 180)")
    if margin < 1.0:
        raise InputError(f"margin {margin} must be at least 1")
    lo, hi = robust_bounds(scene)
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo) / 2)
    radius = max(radius, 1e-3 * max(1.0, float(np.abs(centre).max())))
    fx = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    half = min(math.atan(0.5 * width / fx), math.atan(0.5 * height / fx))
    # A sphere of radius r seen from distance d subtends a half-angle asin(r / d).
    dist = margin * radius / math.sin(half)
    up_v = np.asarray(up, dtype=np.float64).reshape(3)
    if not np.linalg.norm(up_v) > 0:
        raise InputError(f"up vector {tuple(up)} has no direction")
    up_v /= np.linalg.norm(up_v)
    # Orthonormal frame whose third axis is ``up``.
    a = np.cross(up_v, np.eye(3)[np.argmin(np.abs(up_v))])
    a /= np.linalg.norm(a)
    b = np.cross(up_v, a)
    golden = math.pi * (3.0 - math.sqrt(5.0))
    K = np.array([[fx, 0.0, width / 2], [0.0, fx, height / 2], [0.0, 0.0, 1.0]], dtype=np.float64)
    cams = []
    for i in range(int(n)):
        z = 1.0 - 2.0 * (i + 0.5) / n
        r = math.sqrt(max(0.0, 1.0 - z * z))
        d = r * math.cos(golden * i) * a + r * math.sin(golden * i) * b + z * up_v
        eye = centre + dist * d
        cams.append(Camera(look_at(eye, centre, up_v), K.copy(), width, height, f"view_{i:04d}"))
    return cams


def _order(cameras: Sequence[Camera]) -> list[int]:
    return sorted(range(len(cameras)), key=lambda i: natural_key(cameras[i].name))


def limit_size(cameras: list[Camera], max_side: int) -> list[Camera]:
    """The same views, scaled down where the longer side exceeds ``max_side`` pixels."""
    return [
        c.scaled(max_side / max(c.width, c.height)) if max(c.width, c.height) > max_side else c
        for c in cameras
    ]


def sample_views(cameras: Sequence[Camera], fraction: float) -> list[int]:
    """Indices (ascending) of ``round(fraction * n)`` views (at least 1), evenly spaced over the
    cameras in name order."""
    try:
        f = float(fraction)
    except (TypeError, ValueError):
        raise InputError(f"view fraction {fraction!r} is not a number") from None
    if not 0.0 < f <= 1.0:
        raise InputError(f"view fraction {fraction} is outside (0, 1]")
    n = len(cameras)
    if n == 0:
        raise InputError("no cameras to sample views from")
    m = min(n, max(1, round(f * n)))
    order = _order(cameras)
    # Centre of each of m equal slices of the sorted list; distinct because n / m >= 1.
    return sorted(order[int((k + 0.5) * n / m)] for k in range(m))


def split_test_views(cameras: Sequence[Camera], every: int = 8) -> tuple[list[int], list[int]]:
    """3DGS convention: every ``every``-th camera by sorted name (starting with the first) is a test
    view. Returns (train indices, test indices), each ascending."""
    if int(every) < 2:
        raise InputError(f"test-view interval {every} must be at least 2")
    order = _order(cameras)
    test = sorted(order[::every])
    test_set = set(test)
    train = [i for i in range(len(cameras)) if i not in test_set]
    return train, test


def halfway(a: Camera, b: Camera) -> Camera:
    """The camera halfway between ``a`` and ``b``: the midpoint of their centres, the rotation nearest the
    mean of theirs (polar decomposition), ``a``'s intrinsics and size."""
    u, _, vt = np.linalg.svd(a.world_to_cam[:3, :3] + b.world_to_cam[:3, :3])
    R = u @ vt
    if np.linalg.det(R) < 0:  # opposite views: no mean rotation, keep a's
        R = a.world_to_cam[:3, :3]
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ (0.5 * (a.center + b.center))
    return Camera(w2c, a.K.copy(), a.width, a.height, f"{a.name}~{b.name}")


def between_views(cameras: Sequence[Camera], picked: Sequence[int]) -> list[Camera]:
    """For each camera index in ``picked``, the view halfway to its nearest other camera (by centre; itself
    where every other stands at its centre): views a scene's cameras do not hold, near the ones they do."""
    centres = np.stack([c.center for c in cameras])
    # A centre is recovered from its camera's rotation and translation: two cameras at one place may differ
    # by rounding (seen with numpy 2.4), so "the same centre" has a tolerance.
    same = 1e-9 * max(1.0, float(np.abs(centres).max()))
    out = []
    for i in picked:
        d = np.linalg.norm(centres - centres[i], axis=1)
        d[d <= same] = np.inf
        j = int(np.argmin(d))
        out.append(halfway(cameras[i], cameras[j]) if np.isfinite(d[j]) else cameras[i])
    return out
