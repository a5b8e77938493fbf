"""What the other tiles hide of a tile: a tile is coded alone, but the scene shows it behind its neighbours.

Measured alone, a tile counts as seen what other tiles hide: on the 1M district a fifth to a third of each
tile's blending weight at its cameras lies behind other tiles (bench/tiles.md, "What other tiles hide"), and
the precision measure spends bits on it. So before the tiles are coded, each tile is rendered alone at the
scene's cameras to the depth where it turns opaque (its transmittance under OPAQUE_TRANSMITTANCE), and the
scene's maps are folded from the tiles' (per pixel the nearest, and the nearest of any other tile). A tile's
job carries, per camera, the depth where the *other* tiles turn opaque; its measure counts of each Gaussian
only the share of its footprint in front of that (gspc/encoder/significance.py).

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
from gspc.scene import GaussianScene
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
        full = kern.opaque_depths(*_arrays(p), cam.width, cam.height, OPAQUE_TRANSMITTANCE)
        maps.append(_cell_max(full, cell))
    return DepthMaps(cell, tuple(maps))


@dataclass(frozen=True)
class Occlusion:
    """What a tile's job carries: per camera of the scene, the depth where the other tiles turn opaque
    (None: nothing of theirs in view)."""

    cameras: tuple[Camera, ...]
    far: tuple[np.ndarray | None, ...]
    cell: int

    def far_at(self, camera: Camera) -> np.ndarray | None:
        """The map of ``camera`` (one of :attr:`cameras`, as it was given; None where none is known)."""
        key = _key(camera)
        for c, f in zip(self.cameras, self.far):
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
        return kern.shares_in_front(*_arrays(p), w, h, far, self.cell * zoom)


class Occluders:
    """The scene's maps, folded tile by tile in the parent: per camera the nearest opaque depth, its tile,
    and the nearest of any other tile (so a tile's others are one lookup)."""

    def __init__(self, cameras: Sequence[Camera], cell: int) -> None:
        self.cameras, self.cell = tuple(cameras), cell
        shapes = [(math.ceil(c.height / cell), math.ceil(c.width / cell)) for c in cameras]
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
        return Occlusion(self.cameras, tuple(far), self.cell)


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
