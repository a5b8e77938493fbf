"""What the other tiles hide of a tile: a tile is coded alone, but the scene shows it behind its neighbours.

Measured alone, a tile counts as seen what other tiles hide: on the 1M district much of each tile's
blending weight at its cameras lies behind other tiles (bench/tiles.md, "What other tiles hide"): the
precision measure spends bits on it, and the searches score errors nobody sees. So before the tiles are
coded, each tile is rendered alone to the depth where it turns opaque (its transmittance under
OPAQUE_TRANSMITTANCE) at the scene's cameras and at the views halfway between them, and the scene's maps are
folded from the tiles' (per pixel the nearest, and the nearest of any other tile). A tile's job carries, per
view, the depth where the *other* tiles turn opaque: its measure counts of each Gaussian only the share of
its footprint in front of that (gspc/encoder/significance.py), and its removal search (at the halfway
views) and its tuning (at the cameras) score only the pixels where some of the tile is in front
(gspc/encoder/removal.py scorer, gspc/encoder/tuning.py).

The maps err towards precision: a tile's own opaque depth ignores what several tiles hide together, and a
map cell holds the farthest of the pixels it covers (MAP_CELLS bounds the maps whatever the cameras).
Nothing of this is written to a file: it only moves the encoder's choices.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.encoder import occlusion_cpu as kern
from gspc.render.project import Projected, project
from gspc.render.rules import ALPHA_MIN
from gspc.scene import GaussianScene
from gspc.views import between_views
from gspc.visibility import seeing_cameras

# A pixel is opaque once the Gaussians in front leave it this much light: what lies behind adds at most
# this share of its colour there.
OPAQUE_TRANSMITTANCE = 1.0 / 64.0
# The most map cells over all cameras (float32 each, per map): a cell covers a square of pixels, as few as
# fit this.
MAP_CELLS = 1 << 21


def map_cell(cameras: Sequence[Camera]) -> int:
    """The side in pixels of a map's cell for ``cameras``: the smallest whose maps hold at most MAP_CELLS."""
    cell = 1
    while sum(math.ceil(c.height / cell) * math.ceil(c.width / cell) for c in cameras) > MAP_CELLS:
        cell += 1
    return cell


@dataclass(frozen=True)
class DepthMaps:
    """One tile's opaque depths at the scene's cameras: per camera an (h, w) float32 map at 1/``cell`` of
    its pixels (each cell the farthest of its pixels), or None where the tile is out of its view."""

    cell: int
    maps: tuple[np.ndarray | None, ...]


def opaque_depths(scene: GaussianScene, cameras: Sequence[Camera], cell: int) -> DepthMaps:
    """``scene`` (a tile) rendered alone at ``cameras`` to where it turns opaque."""
    seen = set(seeing_cameras(scene.means.numpy(), scene.log_scales.numpy(), list(cameras)))
    maps: list[np.ndarray | None] = []
    for k, cam in enumerate(cameras):
        if k not in seen:
            maps.append(None)
            continue
        p = _projected(scene, cam)
        full = kern.opaque_depths(_arrays(p), cam.width, cam.height, OPAQUE_TRANSMITTANCE)
        maps.append(_cell_max(full, cell))
    return DepthMaps(cell, tuple(maps))


def scene_views(cameras: Sequence[Camera]) -> tuple[Camera, ...]:
    """The views whose opaque depths are folded: the scene's cameras, then for each the view halfway to its
    nearest other (where a tile's searches score: :meth:`Occlusion.scoring_views`)."""
    return (*cameras, *between_views(cameras, range(len(cameras))))


@dataclass(frozen=True)
class OcclusionKnown:
    """What a tile's job knew of the other tiles, for its summary: at how many of its views some of them is
    in view, of how many, and the maps' cell in pixels."""

    seen: int
    views: int
    cell: int


@dataclass(frozen=True)
class Occlusion:
    """What a tile's job carries: per view of :func:`scene_views`, the depth where the other tiles turn
    opaque (None: nothing of theirs in view)."""

    views: tuple[Camera, ...]  # the scene's cameras, then the views halfway between them
    far: tuple[np.ndarray | None, ...]
    cell: int

    def known(self) -> OcclusionKnown:
        return OcclusionKnown(sum(f is not None for f in self.far), len(self.far), self.cell)

    def scoring_views(self, cameras: Sequence[Camera], picked: Sequence[int]) -> list[Camera]:
        """For each of ``cameras[i]``, i in ``picked`` (the scene's cameras), the view halfway to its nearest
        other of the scene's, as gspc/views.py between_views makes it: views whose maps are known."""
        n = len(self.views) // 2
        keys = {_key(c): k for k, c in enumerate(self.views[:n])}
        out = []
        for i in picked:
            k = keys.get(_key(cameras[i]))
            out.append(self.views[n + k] if k is not None else between_views(cameras, [i])[0])
        return out

    def masks(self, scene: GaussianScene, views: Sequence[Camera]) -> list[torch.Tensor | None]:
        """Per view, (H, W, 1) float: 1 where some of ``scene`` (the tile) lies in front of the other tiles,
        0 where they hide all of it (None: nothing of theirs in view). A pixel's error counts only where 1."""
        out: list[torch.Tensor | None] = []
        for v in views:
            far = self.far_at(v)
            if far is None:
                out.append(None)
                continue
            p = _projected(scene, v)
            first = kern.opaque_depths(_arrays(p), v.width, v.height, 1.0 - 0.5 * ALPHA_MIN)
            front = -_cell_max(-first, self.cell) < far  # the nearest of each cell's pixels
            full = np.repeat(np.repeat(front, self.cell, 0), self.cell, 1)[: v.height, : v.width]
            out.append(torch.from_numpy(full[..., None].astype(np.float32)))
        return out

    def far_at(self, camera: Camera) -> np.ndarray | None:
        """The map of ``camera`` (one of :attr:`views`, as it was given; None where none is known)."""
        key = _key(camera)
        for c, f in zip(self.views, self.far):
            if _key(c) == key:
                return f
        return None

    def shares(self, p: Projected, camera: Camera, zoom: float = 1.0) -> np.ndarray | None:
        """Per Gaussian of ``p`` (projected at ``camera`` scaled by ``zoom``), the alpha-weighted share of
        its footprint in front of the other tiles; None where nothing of theirs is in view."""
        far = self.far_at(camera)
        if far is None:
            return None
        w, h = round(camera.width * zoom), round(camera.height * zoom)
        return kern.shares_in_front(_arrays(p), w, h, far, self.cell * zoom)


class Occluders:
    """The scene's maps, folded tile by tile in the parent: per view the nearest opaque depth, its tile, and
    the nearest of any other tile (so a tile's others are one lookup)."""

    def __init__(self, views: Sequence[Camera], cell: int) -> None:
        self.views, self.cell = tuple(views), cell
        shapes = [(math.ceil(c.height / cell), math.ceil(c.width / cell)) for c in views]
        self.far = [np.full(s, np.inf, np.float32) for s in shapes]
        self.owner = [np.full(s, -1, np.int32) for s in shapes]
        self.second = [np.full(s, np.inf, np.float32) for s in shapes]

    def fold(self, tile: int, depths: DepthMaps) -> None:
        for k, m in enumerate(depths.maps):
            if m is not None:
                kern.fold_depths(self.far[k], self.owner[k], self.second[k], tile, m)

    def others(self, tile: int) -> Occlusion:
        far = []
        for f, o, s in zip(self.far, self.owner, self.second):
            m = np.where(o == tile, s, f)
            far.append(m if np.isfinite(m).any() else None)
        return Occlusion(self.views, tuple(far), self.cell)


def _projected(scene: GaussianScene, camera: Camera) -> Projected:
    with torch.no_grad():
        s = scene.tensors()
        return project(
            s["means"],
            s["quats"],
            s["log_scales"],
            s["opacities"],
            s["sh_dc"],
            s["sh_rest"],
            camera,
            scene.sh_degree,
        )


def _arrays(p: Projected) -> tuple[np.ndarray, ...]:
    return tuple(t.detach().double().numpy() for t in (p.means2d, p.conics, p.opacities, p.depths, p.extents))


def _cell_max(full: np.ndarray, cell: int) -> np.ndarray:
    """The map at 1/``cell``: each cell the farthest of its pixels (the edges' cells of those they hold)."""
    if cell == 1:
        return full
    h, w = full.shape
    rows, cols = math.ceil(h / cell), math.ceil(w / cell)
    padded = np.full((rows * cell, cols * cell), -np.inf, np.float32)
    padded[:h, :w] = full
    return padded.reshape(rows, cell, cols, cell).max(axis=(1, 3))


def _key(camera: Camera) -> tuple:
    return camera.world_to_cam.tobytes(), camera.K.tobytes(), camera.width, camera.height
