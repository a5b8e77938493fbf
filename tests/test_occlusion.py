"""What other tiles hide of a tile (gspc/encoder/occlusion.py): opaque depths, their fold over tiles, and a
tile's measure counting only what the others leave in view."""

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.encoder.occlusion import MAP_CELLS, Occluders, map_cell, opaque_depths
from gspc.encoder.significance import significance
from gspc.scene import GaussianScene
from gspc.views import look_at


def _blob(n: int, centre: tuple[float, float, float], spread: float, seed: int) -> GaussianScene:
    """``n`` opaque Gaussians of size ~``spread`` / 4 in a square of side 2 ``spread`` facing the camera
    (the plane z = centre z)."""
    g = np.random.default_rng(seed)
    means = np.array(centre) + np.c_[g.uniform(-spread, spread, (n, 2)), np.zeros(n)]
    return GaussianScene(
        means=torch.tensor(means, dtype=torch.float32),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n),
        log_scales=torch.full((n, 3), float(np.log(spread / 4))),
        opacities=torch.full((n,), 6.0),  # sigmoid ~ 0.998: opaque
        sh_dc=torch.tensor(g.uniform(-1, 1, (n, 3)), dtype=torch.float32),
        sh_rest=torch.zeros(n, 0, 3),
    )


def _camera() -> Camera:
    K = np.array([[60.0, 0, 40], [0, 60.0, 30], [0, 0, 1]])
    return Camera(look_at(np.array([0.0, 0, -5]), np.zeros(3), np.array([0.0, -1, 0])), K, 80, 60)


def test_a_wall_turns_the_view_opaque_at_its_depth_and_nowhere_else():
    wall = _blob(400, (0.0, 0.0, 0.0), 0.5, seed=1)
    (far,) = opaque_depths(wall, [_camera()], 1).maps
    assert far.shape == (60, 80)
    assert np.isfinite(far[30, 40]) and abs(far[30, 40] - 5.0) < 0.5  # the wall's centre, 5 ahead
    assert np.isinf(far[0, 0])  # the corner sees past it


def test_each_tile_is_hidden_by_the_others_not_by_itself():
    cam = _camera()
    near, behind = _blob(400, (0.0, 0.0, 0.0), 1.0, seed=1), _blob(200, (0.0, 0.0, 2.0), 0.3, seed=2)
    occ = Occluders([cam], 1)
    occ.fold(0, opaque_depths(near, [cam], 1))
    occ.fold(1, opaque_depths(behind, [cam], 1))
    # Where both are opaque, the near tile's others are the one behind, and the other way round.
    assert abs(occ.others(0).far[0][30, 40] - 7.0) < 0.5 and abs(occ.others(1).far[0][30, 40] - 5.0) < 0.5

    alone = significance(behind, [cam]).weight
    hidden = significance(behind, [cam], occlusion=occ.others(1)).weight
    assert alone.sum() > 0 and hidden.sum() < 0.05 * alone.sum()
    # The near tile in front of nothing keeps its measure exactly.
    own = occ.others(0)
    assert np.array_equal(significance(near, [cam], occlusion=own).weight, significance(near, [cam]).weight)


def test_a_cell_holds_the_farthest_of_its_pixels_and_maps_stay_bounded():
    cam = _camera()
    wall = _blob(400, (0.0, 0.0, 0.0), 0.5, seed=1)
    (fine,) = opaque_depths(wall, [cam], 1).maps
    (coarse,) = opaque_depths(wall, [cam], 4).maps
    assert coarse.shape == (15, 20)
    assert np.array_equal(coarse, fine.reshape(15, 4, 20, 4).max(axis=(1, 3)))
    big = Camera(cam.world_to_cam, cam.K, 4000, 3000)
    cell = map_cell([big] * 8)
    assert 8 * (3000 // cell + 1) * (4000 // cell + 1) <= MAP_CELLS * 1.01 and cell > 1
    assert map_cell([cam]) == 1


def test_a_tiles_searches_score_only_where_it_is_in_front():
    from gspc.encoder.occlusion import scene_views
    from gspc.encoder.removal import RemovalParams, scoring_views
    from gspc.views import between_views

    cams = [_camera(), Camera(look_at(np.array([0.3, 0, -5]), np.zeros(3), np.array([0.0, -1, 0])),
                              _camera().K, 80, 60)]  # fmt: skip
    near, behind = _blob(400, (0.0, 0.0, 0.0), 1.0, seed=1), _blob(200, (0.0, 0.0, 2.0), 0.3, seed=2)
    views = scene_views(cams)
    occ = Occluders(views, 1)
    occ.fold(0, opaque_depths(near, views, 1))
    occ.fold(1, opaque_depths(behind, views, 1))
    hidden = occ.others(1)
    # The scoring views are the scene's halfway views (whose maps are known), the ones between_views makes.
    picked = scoring_views(cams[1:], 200, RemovalParams(), hidden)
    assert len(picked) == 1 and picked[0].name == between_views(cams, [1])[0].name
    (mask,) = hidden.masks(behind, picked)
    assert mask.shape == (60, 80, 1) and float(mask.sum()) == 0.0  # all of it behind the near tile
    (mask,) = occ.others(0).masks(near, picked)
    assert float(mask[30, 40, 0]) == 1.0 and float(mask.sum()) < 80 * 60  # in front, where it is at all
