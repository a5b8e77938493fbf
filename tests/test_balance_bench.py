"""tools/bench_balance.py's pieces: the scaled measure moves only the named group's gradients, the larger
half is by size over distance to the nearest camera, and the ratio to a curve reads it log-linearly."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from bench_balance import larger_half, outside_region, ratios, scaled
from bench_precision import Point
from scenes import Shells, random_scene, with_shells

from gspc.cameras import Camera
from gspc.encoder.precision_plan import Significance


def _measure(n: int) -> Significance:
    rng = np.random.default_rng(0)
    return Significance(
        weight=rng.random(n),
        gradient={"rotations": rng.random(n), "sh_dc": rng.random((n, 3))},
        sh_band_change=rng.random((n, 2)),
        views=5,
    )


def test_scaled_moves_only_the_group():
    m = _measure(6)
    rows = np.array([True, False, True, False, False, True])
    s = scaled(m, rows, 4.0)
    np.testing.assert_array_equal(s.gradient["rotations"][rows], 4.0 * m.gradient["rotations"][rows])
    np.testing.assert_array_equal(s.gradient["rotations"][~rows], m.gradient["rotations"][~rows])
    np.testing.assert_array_equal(s.gradient["sh_dc"][rows], 4.0 * m.gradient["sh_dc"][rows])
    np.testing.assert_array_equal(s.gradient["sh_dc"][~rows], m.gradient["sh_dc"][~rows])
    assert s.weight is m.weight and s.sh_band_change is m.sh_band_change and s.views == m.views


def _camera_at(centre: np.ndarray) -> Camera:
    w2c = np.eye(4)
    w2c[:3, 3] = -centre  # identity rotation: the centre is -R^T t
    return Camera(world_to_cam=w2c, K=[[8.0, 0, 4], [0, 8.0, 4], [0, 0, 1]], width=8, height=8)


def test_larger_half_by_size_over_nearest_distance():
    # Four Gaussians of one size: the two near a camera span more of it than the two far from both.
    scene = random_scene(n=4, sh_degree=0, seed=1)
    means = torch.tensor([[0.0, 0, 1], [0.0, 0, 10], [5.0, 0, 1], [5.0, 0, 40]])
    scene = type(scene)(**{**scene.tensors(), "means": means, "log_scales": torch.zeros(4, 3)}, sh_degree=0)
    cams = [_camera_at(np.zeros(3)), _camera_at(np.array([5.0, 0, 0]))]
    np.testing.assert_array_equal(larger_half(scene, cams), [True, False, True, False])


def test_outside_region_finds_the_sky_not_a_bounded_object():
    obj = random_scene(n=400, sh_degree=0, seed=3)
    assert outside_region(obj) is None
    world = with_shells(obj, Shells(fraction=0.05))
    room = outside_region(world)
    assert room is not None and room[obj.num_gaussians :].all()


def test_ratios_read_the_curve_log_linearly():
    curve = [
        Point("a", 1000, 0, (30.0, 29.0), 0.0, (31.0, 30.0)),
        Point("b", 4000, 0, (40.0, 39.0), 0.0, (41.0, 40.0)),
    ]
    mid = Point("m", 1000, 0, (35.0, 34.0), 0.0, (36.0, 35.0))  # the curve has 2000 B there
    assert ratios(curve, mid) == pytest.approx((0.5, 0.5, 0.5))
    past = Point("p", 1000, 0, (45.0, 34.0), 0.0, (36.0, 35.0))
    assert ratios(curve, past)[0] is None
