"""What a render asks for before it runs: the Gaussian-tile pairs of a view, counted from the projection alone
(spec 10.8, "The decoder's work"), so that the pair lists a render allocates, and the work a file asks of a
decoder, are bounded (gspc/limits.py) before any list is built."""

from __future__ import annotations

from collections.abc import Iterable

import torch

from gspc.cameras import Camera
from gspc.render.project import project
from gspc.render.rules import TILE
from gspc.scene import GaussianScene


def box_spans(means2d: torch.Tensor, extents: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """Each Gaussian's (Gaussian, tile) pairs, (M,) float64: for a Gaussian drawn (extents >= 0), the TILE x
    TILE tiles of a ``width`` x ``height`` image whose pixel centres (x + 0.5) its box of half-sizes
    ``extents`` (M, 2) around ``means2d`` (M, 2) reaches on both axes. The compositor's lists
    (gspc/render/rasterize.py bin_tiles) hold at most these: its exact test drops the tiles of a box that the
    ellipse misses."""
    size = torch.tensor([-(-width // TILE), -(-height // TILE)], dtype=torch.float64, device=means2d.device)
    m, e = means2d.detach().to(torch.float64), extents.detach().to(torch.float64)
    lo = torch.ceil((m - e - (TILE - 0.5)) / TILE).clamp_min(0.0)
    hi = torch.minimum(torch.floor((m + e - 0.5) / TILE), size - 1)
    span = (hi - lo + 1).clamp_min(0.0) * (e[:, :1] >= 0)
    return span[:, 0] * span[:, 1]


def box_pairs(means2d: torch.Tensor, extents: torch.Tensor, width: int, height: int) -> int:
    """The (Gaussian, tile) pairs of all the boxes (:func:`box_spans`)."""
    return int(box_spans(means2d, extents, width, height).sum())


@torch.no_grad()
def view_spans(scene, camera: Camera) -> torch.Tensor:
    """Each Gaussian's pairs of ``scene`` (a GaussianScene) at ``camera``: :func:`box_spans` of its
    projection (the renderer's own, gspc/render/project.py)."""
    p = project(
        scene.means, scene.quats, scene.log_scales, scene.opacities, scene.sh_dc, scene.sh_rest, camera, 0
    )
    return box_spans(p.means2d, p.extents, camera.width, camera.height)


def view_pairs(scene, camera: Camera) -> int:
    """The Gaussian-tile pairs of ``scene`` at ``camera`` (:func:`view_spans`)."""
    return int(view_spans(scene, camera).sum())


def drawn_at(scene, cameras) -> torch.Tensor:
    """Which Gaussians of ``scene`` have a pair at some camera of ``cameras``: the others draw nothing
    there, so a scene drawn beside a refined one (spec 10.15) keeps only these."""
    keep = torch.zeros(scene.num_gaussians, dtype=torch.bool, device=scene.means.device)
    for cam in cameras:
        keep |= view_spans(scene, cam) > 0
    return keep


def drawn_beside(tiles: Iterable[GaussianScene], cameras) -> GaussianScene | None:
    """The Gaussians of ``tiles`` (a tile's neighbours, spec 10.15) that have a pair at some camera of
    ``cameras`` (None: none), each tile culled as it comes, so that a lazy iterable holds one whole tile at
    a time."""
    parts = [tile.subset(drawn_at(tile, cameras)) for tile in tiles]
    parts = [p for p in parts if p.num_gaussians]
    return GaussianScene.concat(parts) if parts else None
