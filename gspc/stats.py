"""Summary numbers of a scene for ``gspc info``: a flat dict of ints and floats, no printing."""

from __future__ import annotations

import numpy as np
import torch

from gspc.io.ply import inria_bytes_per_gaussian
from gspc.scene import SH_C0, GaussianScene

AXES = ("x", "y", "z")
CHANNELS = ("r", "g", "b")


def _summary(prefix: str, values: np.ndarray, out: dict) -> None:
    with np.errstate(over="ignore", invalid="ignore"):  # an infinite value's statistics are inf / nan
        out[f"{prefix}_mean"] = float(values.mean())
        out[f"{prefix}_std"] = float(values.std())
    out[f"{prefix}_min"] = float(values.min())
    out[f"{prefix}_max"] = float(values.max())


def scene_stats(scene: GaussianScene) -> dict[str, int | float]:
    """Count, SH degree, bounds (full and 1-99 percentile), per-attribute mean/std/min/max of
    positions, activated scales, activated opacity, DC colour and SH rest energy, the fraction of
    nearly transparent Gaussians and the INRIA PLY size per Gaussian."""
    n, deg = scene.num_gaussians, scene.sh_degree
    means = scene.means.detach().cpu().double().numpy()
    # torch's exp and sigmoid: a hostile scene's huge logs give inf and 0 without numpy's overflow warnings
    scales = torch.exp(scene.log_scales.detach().cpu().double()).numpy()
    opacity = torch.sigmoid(scene.opacities.detach().cpu().double()).numpy().reshape(-1)
    colour = 0.5 + SH_C0 * scene.sh_dc.detach().cpu().double().numpy()
    rest = scene.sh_rest.detach().cpu().double().numpy()

    out: dict[str, int | float] = {
        "count": n,
        "sh_degree": deg,
        "ply_bytes_per_gaussian": inria_bytes_per_gaussian(deg),
    }
    lo, hi = np.percentile(means, [1.0, 99.0], axis=0)
    for i, a in enumerate(AXES):
        out[f"bounds_min_{a}"] = float(means[:, i].min())
        out[f"bounds_max_{a}"] = float(means[:, i].max())
        out[f"bounds_p01_{a}"] = float(lo[i])
        out[f"bounds_p99_{a}"] = float(hi[i])
    out["robust_extent"] = float(np.linalg.norm(hi - lo))  # diagonal of the 1-99 percentile box
    for i, a in enumerate(AXES):
        _summary(f"position_{a}", means[:, i], out)
    _summary("scale", scales, out)  # all three axes pooled
    _summary("scale_max_axis", scales.max(axis=1), out)
    _summary("opacity", opacity, out)
    for i, c in enumerate(CHANNELS):
        _summary(f"color_{c}", colour[:, i], out)
    energy = (rest**2).sum(axis=(1, 2)) if rest.shape[1] else np.zeros(n)
    _summary("sh_rest_energy", energy, out)
    out["frac_opacity_below_1_255"] = float((opacity < 1.0 / 255.0).mean())
    return out
