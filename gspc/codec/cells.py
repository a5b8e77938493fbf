"""Quantisation cells: per attribute, the box of values that the attribute codec maps to the decoded one.

The original scene's attributes lie in these boxes (that is what quantisation means), so a decoder that
refines G~ may keep every attribute inside its cell and lose nothing the original could reach: the cells
are a prior that stops refinement from fitting the side information's coding noise with moves the
bitstream rules out (a projection, as in consistent JPEG decoding).

Boxes are (lo, hi) tensors shaped like the attributes. Quaternions' boxes hold the unit quaternion with
the sign that makes its largest component positive; the largest component's range follows from the other
three (its error is at most ``2 e (sqrt 3 + e)`` for a component error ``e``, see ``rotation_error_bound``).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from gspc.codec.attributes import OPACITY_FLOOR, SQRT_HALF
from gspc.codec.positions import cell_half_widths
from gspc.errors import CodecError
from gspc.scene import GaussianScene

Box = tuple[torch.Tensor, torch.Tensor]


def _around(x: torch.Tensor, half: torch.Tensor | float) -> Box:
    return x - half, x + half


def _logit(a: torch.Tensor) -> torch.Tensor:
    return torch.log(a) - torch.log1p(-a)


def quantisation_cells(decoded: GaussianScene, meta: dict) -> dict[str, Box]:
    """The cell of every attribute of ``decoded`` (what ``decode_attributes`` returned for ``meta``)."""
    try:
        dev = decoded.means.device
        pos_half = torch.from_numpy(
            np.ascontiguousarray(cell_half_widths(decoded.means.detach().cpu().numpy(), meta["position"]))
        ).to(dev)
        levels, rot_levels = int(meta["opacity_levels"]), int(meta["rotation_levels"])
        scale_step, dc_step = float(meta["scale_step"]), float(meta["dc_step"])
        sh_steps = torch.tensor([float(s) for s in meta["sh_steps"]], dtype=torch.float64, device=dev)
    except (KeyError, TypeError, ValueError) as err:
        raise CodecError(f"attribute codec header is malformed ({err})") from None
    g = {name: getattr(decoded, name).detach().double() for name in ("means", "quats", "opacities")}
    cells: dict[str, Box] = {
        "means": _around(g["means"], pos_half),
        "log_scales": _around(decoded.log_scales.detach().double(), scale_step / 2),
        "sh_dc": _around(decoded.sh_dc.detach().double(), dc_step / 2),
    }
    # A whole step: the encoder may round towards zero (dead zone). A Gaussian without SH rest (all zero)
    # may have been faint, whose SH rest the encoder drops whatever it was: no bound.
    rest = decoded.sh_rest.detach().double()
    half = sh_steps[None, :, None].expand_as(rest)
    coded = (rest != 0).flatten(1).any(1)[:, None, None]
    cells["sh_rest"] = _around(rest, torch.where(coded, half, torch.inf))
    # Opacity: alpha in [(q - 1/2) / L, (q + 1/2) / L], and pruning kept only alpha >= 1/255.
    q = torch.round(torch.sigmoid(g["opacities"]) * levels)
    lo = torch.clamp((q - 0.5) / levels, min=OPACITY_FLOOR)
    hi = torch.clamp((q + 0.5) / levels, max=1.0 - 1e-6)
    cells["opacities"] = (_logit(lo), _logit(hi))
    # Rotation: the three smaller components within half a step, the largest within its derived error.
    unit = g["quats"] / g["quats"].norm(dim=1, keepdim=True)
    big = unit.abs().argmax(dim=1, keepdim=True)
    unit = unit * torch.sign(unit.gather(1, big))
    e = 0.5 * (2.0 * SQRT_HALF / rot_levels)
    d = 2.0 * math.sqrt(3.0) * e * (math.sqrt(3.0) + math.sqrt(3.0) * e)
    # Where another component comes within two steps of the largest, the encoder may have called it the
    # largest: give it the largest's range too.
    near = unit.abs() >= unit.gather(1, big) - 2 * e
    half = torch.where(near, d, e)
    lo, hi = _around(unit, half)
    cells["quats"] = (lo.clamp(-1, 1), hi.clamp(-1, 1))
    dtype = decoded.means.dtype
    return {k: (a.to(dtype), b.to(dtype)) for k, (a, b) in cells.items()}


def project(name: str, value: torch.Tensor, box: Box) -> None:
    """Move ``value`` (in place) to the nearest point of its box; quaternions are compared as unit vectors
    signed like the box's centre."""
    lo, hi = box
    if name == "quats":
        centre = (lo + hi) / 2
        unit = value / value.norm(dim=1, keepdim=True).clamp_min(1e-12)
        unit = unit * torch.where((unit * centre).sum(1, keepdim=True) < 0, -1.0, 1.0)
        value.copy_(torch.minimum(torch.maximum(unit, lo), hi))
    else:
        value.copy_(torch.minimum(torch.maximum(value, lo), hi))
