"""Which Gaussians any camera can see: lets the codec drop what no view will ever render."""

from __future__ import annotations

import numpy as np
import torch

from gspc.cameras import Camera


def visible_mask(
    means: np.ndarray, log_scales: np.ndarray, cameras: list[Camera], near: float = 0.01
) -> np.ndarray:
    """Boolean (N,) mask: True where a Gaussian's 3-sigma footprint overlaps some camera's image.

    Conservative on purpose (a bounding sphere of radius 3 * max scale), so only Gaussians that
    are certainly outside every frustum are reported invisible.
    """
    seen = np.zeros(len(means), dtype=bool)
    for mask, _ in _per_camera(means, log_scales, cameras, near):
        seen |= mask
    return seen


def seeing_cameras(
    means: np.ndarray, log_scales: np.ndarray, cameras: list[Camera], near: float = 0.01
) -> list[int]:
    """Indices of the cameras that see at least one of the Gaussians (the test of :func:`visible_mask`):
    the views a part of a scene (a spatial tile) is measured and scored at."""
    return [k for k, (mask, _) in enumerate(_per_camera(means, log_scales, cameras, near)) if mask.any()]


def sampling_coverage(
    means: np.ndarray, log_scales: np.ndarray, cameras: list[Camera], near: float = 0.01
) -> np.ndarray:
    """Per Gaussian (N,): how many of ``cameras`` see it (the test of :func:`visible_mask`, occlusion
    ignored), each counted by the pixels it gives the Gaussian against the closest of them: (p / p_v)^2,
    with p_v the world size of a pixel at the Gaussian's depth in camera v and p the smallest of those. A
    copy in the background, three times as far as the view that frames it, counts 1/9. 0 where none sees it.
    """
    best = np.full(len(means), np.inf)
    inverse_area = np.zeros(len(means))  # sum over the views that see it of 1 / p_v^2
    for mask, pixel in _per_camera(means, log_scales, cameras, near):
        best = np.where(mask, np.minimum(best, pixel), best)
        inverse_area += np.where(mask, 1.0 / pixel**2, 0.0)
    best[~np.isfinite(best)] = 0.0  # seen by none: its sum is 0 too
    return best**2 * inverse_area


def _per_camera(means: np.ndarray, log_scales: np.ndarray, cameras: list[Camera], near: float):
    """Per camera: the mask of Gaussians whose 3-sigma footprint overlaps its image, and the world size of
    one of its pixels at each Gaussian's (clamped) depth."""
    means = np.asarray(means, dtype=np.float64)
    # Clamped below float64's exp overflow: a Gaussian that large covers every view either way.
    radius = 3.0 * np.exp(np.minimum(np.asarray(log_scales, dtype=np.float64).max(axis=1), 700.0))
    for cam in cameras:
        R, t = cam.world_to_cam[:3, :3], cam.world_to_cam[:3, 3]
        p = means @ R.T + t
        z = p[:, 2]
        front = z + radius > near
        zc = np.maximum(z, near)
        # Screen-space radius grows as the Gaussian approaches the camera; inside the sphere -> always seen.
        u = cam.fx * p[:, 0] / zc + cam.cx
        v = cam.fy * p[:, 1] / zc + cam.cy
        ru = cam.fx * radius / zc
        rv = cam.fy * radius / zc
        inside_sphere = np.linalg.norm(p, axis=1) <= radius
        on_screen = (u + ru >= 0) & (u - ru <= cam.width) & (v + rv >= 0) & (v - rv <= cam.height)
        yield (front & on_screen) | inside_sphere, zc / cam.fx


def footprints(means: np.ndarray, log_scales: np.ndarray, cameras: list[Camera]) -> np.ndarray:
    """Per Gaussian (N,): the mean over ``cameras`` of the part of its projected Gaussian inside the image,
    as a fraction of the image's pixels (each Gaussian taken round, at its largest scale; occlusion and
    opacity ignored): how much of it the cameras show, cheaply, to compare two sets of cameras."""
    m = torch.as_tensor(np.asarray(means), dtype=torch.float64)
    # Clamped where float64 stays finite through the products below (e^60 covers any view either way).
    sigma = torch.as_tensor(np.asarray(log_scales), dtype=torch.float64).amax(1).clamp(max=60.0).exp()
    total = torch.zeros(len(m), dtype=torch.float64)
    for cam in cameras:
        R = torch.as_tensor(cam.world_to_cam[:3, :3], dtype=torch.float64)
        t = torch.as_tensor(cam.world_to_cam[:3, 3], dtype=torch.float64)
        p = m @ R.T + t
        z = p[:, 2].clamp(min=1e-6)
        # Its axes in pixels, at least the renderer's blur (a third of a pixel): a speck still counts.
        su = (cam.fx * sigma / z).clamp(min=0.3)
        sv = (cam.fy * sigma / z).clamp(min=0.3)
        u, v = cam.fx * p[:, 0] / z + cam.cx, cam.fy * p[:, 1] / z + cam.cy
        inside_u = torch.special.ndtr((cam.width - u) / su) - torch.special.ndtr(-u / su)
        inside_v = torch.special.ndtr((cam.height - v) / sv) - torch.special.ndtr(-v / sv)
        area = 2.0 * np.pi * su * sv / (cam.width * cam.height)
        part = torch.nan_to_num(inside_u * inside_v * area, nan=0.0, posinf=0.0)  # a camera inside it
        total += torch.where(p[:, 2] > 0, part, 0.0)
    return (total / max(len(cameras), 1)).numpy()
