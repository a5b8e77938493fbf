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
from gspc.format.attribute_section import AttributeSection
from gspc.scene import GaussianScene

CELL_BLOCK = 1 << 16  # rows per block: the float64 boxes of a million Gaussians at once took 1.4 GB


def quantisation_cells(decoded: GaussianScene, section: AttributeSection) -> dict[str, Box]:
    """The cell of every attribute of ``decoded`` (what ``decode_attributes`` returned for ``section``), in
    the scene's dtype; computed in float64 block by block of rows."""
    pos_half = cell_half_widths(decoded.means.detach().cpu().numpy(), section.position)
    quant = AttributeQuantisers.from_section(section)
    half = torch.from_numpy(np.ascontiguousarray(pos_half)).to(decoded.means.device)
    cell_of = {
        "means": lambda x, a, b: _box(x.double(), half if len(half) == 1 else half[a:b]),
        "log_scales": lambda x, a, b: quant.scale.cell(x),
        "sh_dc": lambda x, a, b: quant.dc.cell(x),
        "sh_rest": lambda x, a, b: quant.sh_rest.cell(x),
        "opacities": lambda x, a, b: quant.opacity.cell(x),
        "quats": lambda x, a, b: quant.rotation.cell(x),
    }
    cells: dict[str, Box] = {}
    for name, cell in cell_of.items():
        t = getattr(decoded, name).detach()
        lo, hi = torch.empty_like(t), torch.empty_like(t)
        for a in range(0, len(t), CELL_BLOCK):
            b = min(a + CELL_BLOCK, len(t))
            lo[a:b], hi[a:b] = cell(t[a:b], a, b)  # assignment rounds to the scene's dtype
        cells[name] = (lo, hi)
    return cells


def _box(x: torch.Tensor, half: torch.Tensor) -> Box:
    return x - half, x + half


def clamp_into(name: str, value: torch.Tensor, box: Box) -> None:
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
