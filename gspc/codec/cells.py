"""Quantisation cells: per attribute, the box of values that the attribute codec maps to the decoded one.

The original scene's attributes lie in these boxes (that is what quantisation means), so a decoder that
refines G~ may keep every attribute inside its cell and lose nothing the original could reach: the cells
are a prior that stops refinement from fitting the side information's coding noise with moves the
bitstream rules out (a projection, as in consistent JPEG decoding).

Boxes are (lo, hi) tensors shaped like the attributes; each attribute's quantiser states its own cell
(gspc/codec/quantisers.py), positions' cells come from their grid (gspc/codec/positions.py). Quaternions'
boxes hold the unit quaternion with the sign that makes its largest component positive.
"""

from __future__ import annotations

import numpy as np
import torch

from gspc.codec.positions import cell_half_widths
from gspc.codec.quantisers import AttributeQuantisers, Box
from gspc.errors import CodecError
from gspc.scene import GaussianScene


def quantisation_cells(decoded: GaussianScene, meta: dict) -> dict[str, Box]:
    """The cell of every attribute of ``decoded`` (what ``decode_attributes`` returned for ``meta``)."""
    try:
        pos_half = cell_half_widths(decoded.means.detach().cpu().numpy(), meta["position"])
        quant = AttributeQuantisers.from_meta(meta)
    except (KeyError, TypeError, ValueError) as err:
        raise CodecError(f"attribute codec header is malformed ({err})") from None
    means = decoded.means.detach().double()
    half = torch.from_numpy(np.ascontiguousarray(pos_half)).to(decoded.means.device)
    cells: dict[str, Box] = {
        "means": (means - half, means + half),
        "log_scales": quant.scale.cell(decoded.log_scales),
        "sh_dc": quant.dc.cell(decoded.sh_dc),
        "sh_rest": quant.sh_rest.cell(decoded.sh_rest),
        "opacities": quant.opacity.cell(decoded.opacities),
        "quats": quant.rotation.cell(decoded.quats),
    }
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
        value.copy_(unit.clamp_(lo, hi))
    else:
        value.clamp_(lo, hi)
