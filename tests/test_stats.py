import math
import warnings

import numpy as np
import pytest
from scenes import box_scene

from gspc.io import read_scene
from gspc.stats import scene_stats
from gspc.views import robust_bounds


def test_stats_values():
    st = scene_stats(box_scene())
    assert st["count"] == 1000 and st["sh_degree"] == 3
    assert st["ply_bytes_per_gaussian"] == 248
    assert st["bounds_min_x"] >= -1.0 and st["bounds_max_z"] <= 5.0
    assert st["bounds_p01_y"] > st["bounds_min_y"] and st["bounds_p99_y"] < st["bounds_max_y"]
    assert st["robust_extent"] == pytest.approx(math.sqrt(2**2 + 4**2 + 6**2), rel=0.05)
    assert st["scale_mean"] == pytest.approx(0.01) and st["scale_std"] == pytest.approx(0.0, abs=1e-9)
    assert st["opacity_min"] == pytest.approx(1 / (1 + math.exp(10)))
    assert st["opacity_max"] == pytest.approx(0.5)
    assert st["frac_opacity_below_1_255"] == pytest.approx(0.25)
    assert st["color_g_mean"] == pytest.approx(0.5)
    assert st["sh_rest_energy_mean"] == pytest.approx(45 * 0.01, rel=1e-5)
    assert st["position_y_mean"] == pytest.approx(1.0, abs=0.2)


def test_stats_are_plain_numbers_and_degree_zero():
    st = scene_stats(box_scene(n=10, degree=0))
    assert st["ply_bytes_per_gaussian"] == 68 and st["sh_rest_energy_max"] == 0.0
    assert all(type(v) in (int, float) for v in st.values())
    assert all(np.isfinite(v) for v in st.values())


def test_stats_on_real_scene(shared_data):
    st = scene_stats(read_scene(shared_data / "statues/massa.sog"))
    assert st["count"] == 58_649 and st["sh_degree"] == 0
    assert 0 <= st["frac_opacity_below_1_255"] < 0.05
    assert 1.0 < st["robust_extent"] < 10.0


def test_extreme_values_give_statistics_without_numpy_warnings():
    # Finite float32 values a hostile PLY may hold: a huge log scale, a hugely negative opacity logit.
    scene = box_scene(200, degree=1)
    scene.log_scales[4, 0] = 1e30
    scene.opacities[3] = -3e38
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        stats = scene_stats(scene)
        lo, hi = robust_bounds(scene)
    assert stats["scale_max"] == float("inf") and np.isfinite(lo).all() and np.isfinite(hi).all()
