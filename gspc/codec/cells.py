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

import math
from collections.abc import Sequence

import numpy as np
import torch

from gspc.codec.positions import cell_half_widths
from gspc.codec.precision import PrecisionMap
from gspc.codec.quantisers import AttributeQuantisers, Box
from gspc.format.attribute_section import AttributeSection
from gspc.scene import GaussianScene

# Rows per block: the float64 boxes of a large scene at once would outweigh the scene itself (bench/scale.md,
# "Moved from code comments").
CELL_BLOCK = 1 << 16


def quantisation_cells(
    decoded: GaussianScene, section: AttributeSection, precision: PrecisionMap | None = None
) -> dict[str, Box]:
    """The cell of every attribute of ``decoded`` (what ``decode_attributes`` returned for ``section``, and
    at version 4 the file's ``precision``), in the scene's dtype; computed in float64 block by block of
    rows."""
    if section.precision and precision is None:
        raise ValueError("a version-4 section's cells need its precision map (gspc/codec/precision.py)")
    pos_half = cell_half_widths(decoded.means.detach().cpu().numpy(), section.position)
    half = torch.from_numpy(np.ascontiguousarray(pos_half)).to(decoded.means.device)
    classes = section.all_classes
    quants = [AttributeQuantisers.from_steps(c) for c in classes]
    cells: dict[str, Box] = {}
    for name in ("means", "log_scales", "sh_dc", "sh_rest", "opacities", "quats"):
        t = getattr(decoded, name).detach()
        lo, hi = torch.empty_like(t), torch.empty_like(t)
        for a in range(0, len(t), CELL_BLOCK):
            b = min(a + CELL_BLOCK, len(t))
            if name == "means":
                lo[a:b], hi[a:b] = _box(t[a:b].double(), half if len(half) == 1 else half[a:b])
                continue
            if precision is None:  # one class: its quantiser's cells
                lo[a:b], hi[a:b] = _cell(quants[0], name, t[a:b])
                continue
            cls = torch.from_numpy(precision.classes[a:b]).to(t.device)
            for k, quant in enumerate(quants):
                rows = torch.nonzero(cls == k).squeeze(1) + a
                if len(rows) == 0:
                    continue
                if name == "sh_rest":
                    # By codebook (version 5) every SH rest is an entry coded at class 0's steps.
                    sh = quants[0].sh_rest if section.codebook else quant.sh_rest
                    box = sh.cell(t[rows], every_row_coded=True)
                else:
                    box = _cell(quant, name, t[rows])
                lo[rows], hi[rows] = box[0].to(t.dtype), box[1].to(t.dtype)
            if name == "sh_rest":
                _open_dropped_bands(lo, hi, precision.degrees, a, b)
        cells[name] = (lo, hi)
    return cells


def span_cells(
    parts: Sequence[tuple[GaussianScene, AttributeSection, PrecisionMap | None]],
) -> dict[str, Box]:
    """The cells of a span's tiles refined as one scene (spec 10.17): each tile's Gaussians in its own
    section's cells, the tiles one after another."""
    each = [quantisation_cells(scene, section, precision) for scene, section, precision in parts]
    return {k: (torch.cat([c[k][0] for c in each]), torch.cat([c[k][1] for c in each])) for k in each[0]}


def _cell(quant: AttributeQuantisers, name: str, x: torch.Tensor) -> Box:
    q = {"log_scales": quant.scale, "sh_dc": quant.dc, "sh_rest": quant.sh_rest}
    q |= {"opacities": quant.opacity, "quats": quant.rotation}
    return q[name].cell(x)


def _open_dropped_bands(lo: torch.Tensor, hi: torch.Tensor, degrees: np.ndarray, a: int, b: int) -> None:
    """The encoder drops the bands above a Gaussian's SH degree, whatever they held: no bound; the bands up
    to it are coded, even where every symbol is 0 (a whole step, as the dead zone allows)."""
    deg = torch.from_numpy(degrees[a:b]).to(lo.device)
    for band in range(1, int(math.isqrt(lo.shape[1] + 1))):
        coefs = slice(band * band - 1, (band + 1) ** 2 - 1)
        dropped = torch.nonzero(deg < band).squeeze(1) + a
        lo[dropped, coefs], hi[dropped, coefs] = -torch.inf, torch.inf


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
