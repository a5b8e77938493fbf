"""What each Gaussian does to the views: the encoder's measures for spending precision where it shows.

Two measures, both accumulated over the encoder's cameras at the resolution they are given (the caller
decides whether that is the capture's native size or ``--max-side``):

- ``weight``: the blending weight a Gaussian takes over all pixels, sum_views sum_pixels alpha_i T_i (its
  footprint times opacity times the transmittance in front of it). It is the gradient of the summed
  composite with respect to a per-Gaussian feature of zero, so one backward pass per view gives it exactly,
  occlusion included.
- ``gradient``: per attribute group, sum_views |d sum(image) / d attribute| summed over the group's
  components: how far a change of that group moves the picture (C3DGS's sensitivity).

Neither is ever written to a file: precision classes chosen from them are what a decoder would read, so a
decoder never recomputes these. tools/bench_significance.py measures which of them predicts where the
attribute codec's error shows (bench/significance.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.render import render
from gspc.render.project import project
from gspc.render.rasterize import composite
from gspc.scene import ATTRIBUTE_NAMES, GaussianScene


@dataclass(frozen=True)
class Significance:
    """Per-Gaussian measures over a set of views, each (N,) float64."""

    weight: np.ndarray  # sum of blending weights alpha T over every pixel of every view
    gradient: dict[str, np.ndarray]  # attribute name -> sum of |d sum(image) / d attribute|

    def ranking(self, measure: str) -> np.ndarray:
        """Gaussian indices, most significant first (ties: lower index first), for "weight" or
        "gradient:<attribute>"."""
        values = self.weight if measure == "weight" else self.gradient[measure.split(":", 1)[1]]
        return np.lexsort((np.arange(len(values)), -values))


def blend_weights(scene: GaussianScene, camera: Camera) -> torch.Tensor:
    """(N,) sum over the view's pixels of each Gaussian's blending weight alpha_i T_i."""
    with torch.no_grad():
        p = project(
            scene.means, scene.quats, scene.log_scales, scene.opacities, scene.sh_dc, scene.sh_rest,
            camera, 0,
        )
    # Four columns, as render() composites colour and depth: the compiled compositor takes that layout.
    probe = torch.zeros(len(p.index), 4, dtype=scene.means.dtype, requires_grad=True)
    acc, _ = composite(
        p.means2d, p.conics, p.opacities, probe, p.depths, p.extents, camera.width, camera.height
    )
    (grad,) = torch.autograd.grad(acc.sum(), probe)
    # The projection may keep only the Gaussians in front of the camera (p.index): the rest weigh 0.
    out = torch.zeros(scene.num_gaussians, dtype=grad.dtype)
    return out.index_copy_(0, p.index, grad[:, 0])


def attribute_gradients(
    scene: GaussianScene, camera: Camera, background: Sequence[float]
) -> dict[str, torch.Tensor]:
    """Attribute name -> (N,) |d sum(image) / d attribute| summed over the attribute's components."""
    leaves = {k: v.detach().clone().requires_grad_(True) for k, v in scene.tensors().items()}
    probe = GaussianScene(**leaves, sh_degree=scene.sh_degree)
    bg = torch.tensor(background, dtype=scene.means.dtype)
    image = render(probe, camera, background=bg).image
    grads = torch.autograd.grad(image.sum(), list(leaves.values()), allow_unused=True)
    n = scene.num_gaussians
    zero = torch.zeros(n, dtype=torch.float64)
    return {k: zero if g is None else g.abs().reshape(n, -1).sum(1).double() for k, g in zip(leaves, grads)}


def significance(
    scene: GaussianScene, cameras: Sequence[Camera], background: Sequence[float] = (0.0, 0.0, 0.0)
) -> Significance:
    """Both measures, accumulated over ``cameras``."""
    n = scene.num_gaussians
    weight = torch.zeros(n, dtype=torch.float64)
    gradient = {k: torch.zeros(n, dtype=torch.float64) for k in ATTRIBUTE_NAMES}
    for cam in cameras:
        weight += blend_weights(scene, cam).double()
        for k, g in attribute_gradients(scene, cam, background).items():
            gradient[k] += g
    return Significance(weight.numpy(), {k: v.numpy() for k, v in gradient.items()})
