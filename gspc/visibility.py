"""Which Gaussians any camera can see: lets the codec drop what no view will ever render."""

from __future__ import annotations

import numpy as np

from gspc.cameras import Camera


def visible_mask(
    means: np.ndarray, log_scales: np.ndarray, cameras: list[Camera], near: float = 0.01
) -> np.ndarray:
    """Boolean (N,) mask: True where a Gaussian's 3-sigma footprint overlaps some camera's image.

    Conservative on purpose (a bounding sphere of radius 3 * max scale), so only Gaussians that
    are certainly outside every frustum are reported invisible.
    """
    means = np.asarray(means, dtype=np.float64)
    # Clamped below float64's exp overflow: a Gaussian that large covers every view either way.
    radius = 3.0 * np.exp(np.minimum(np.asarray(log_scales, dtype=np.float64).max(axis=1), 700.0))
    seen = np.zeros(len(means), dtype=bool)
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
        seen |= (front & on_screen) | inside_sphere
    return seen
