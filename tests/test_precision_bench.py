"""The shells generator of tools/bench_precision.py (tools/scenes.py with_shells): deterministic, the sizes it
states, finite, at the distances and sizes it states."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scenes import Shells, random_scene, with_shells

from gspc.views import robust_bounds


@pytest.fixture(scope="module")
def obj():
    return random_scene(n=500, sh_degree=1, seed=2)


def test_same_seed_same_scene_other_seed_other_scene(obj):
    a, b = with_shells(obj, Shells(seed=3)), with_shells(obj, Shells(seed=3))
    for k, v in a.tensors().items():
        assert torch.equal(v, b.tensors()[k]), k
    c = with_shells(obj, Shells(seed=4))
    assert not torch.equal(a.means, c.means)


def test_counts_object_first_and_unchanged(obj):
    spec = Shells(radii=(10.0, 40.0), fraction=0.03, floaters=7)
    world = with_shells(obj, spec)
    n = obj.num_gaussians
    assert spec.counts(n) == (15, 15, 7)
    assert world.num_gaussians == n + 15 + 15 + 7
    assert world.sh_degree == obj.sh_degree
    for k, v in obj.tensors().items():
        assert torch.equal(world.tensors()[k][:n], v), k
    world.validate()
    for k, v in world.tensors().items():
        assert torch.isfinite(v).all(), k


def test_distances_and_sizes_grow_with_distance(obj):
    spec = Shells()
    world = with_shells(obj, spec)
    n = obj.num_gaussians
    lo, hi = robust_bounds(obj)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2)
    d = np.linalg.norm(world.means[n:].double().numpy() - centre, axis=1) / radius
    counts = spec.counts(n)
    start = 0
    for r, c in zip(spec.radii, counts):
        part = d[start : start + c]
        assert (part >= r * (1 - spec.jitter) - 1e-3).all() and (part <= r * (1 + spec.jitter) + 1e-3).all()
        start += c
    far = d[start:]
    assert far.size == spec.floaters
    assert (far >= spec.floater_radii[0] - 1e-2).all() and (far <= spec.floater_radii[1] + 1e-2).all()
    # Every added Gaussian's longest axis is the same angle seen from the centre, so sizes follow distance.
    longest = np.exp(world.log_scales[n:].double().numpy().max(1)) / (d * radius)
    np.testing.assert_allclose(longest, np.sqrt(4.0 * spec.cover / counts[0]), rtol=1e-4)
    # Shapes are the copies' own: the spread of log scales within a Gaussian is kept.
    spread = world.log_scales[n:].max(1).values - world.log_scales[n:].min(1).values
    assert float(spread.max()) > 0.1


def test_unseen_views_are_none_of_the_encoders_and_look_alike(obj):
    """tools/bench_setups.py unseen_views: the scoring views sit between the encoder's synthesised cameras
    (the encoder measures every one of those), at their size and field of view."""
    from bench_setups import unseen_views

    from gspc.views import synthesize_views

    cams = synthesize_views(obj, 60, width=40, height=40)
    centres = np.array([c.center for c in cams])
    for n in (12, 67):  # the tables; the whole sphere (bench_precision.py --shell-views)
        views = unseen_views(obj, cams, n)
        assert len(views) == n and len({tuple(np.round(v.center, 9)) for v in views}) == n
        gap = min(np.linalg.norm(centres - np.asarray(v.center), axis=1).min() for v in views)
        assert gap > 1e-3 * np.linalg.norm(centres[0])
        assert all(v.width == 40 and v.height == 40 and np.isclose(v.fx, cams[0].fx) for v in views)


def test_scores_float_beside_8_bit(obj):
    """tools/bench_precision.py Views.scores: the 8-bit PSNR the tables use and the float one beside it. A
    change of a hundredth of a level flips a few 8-bit roundings, which cost the 8-bit score far more than
    the error itself (bench/precision.md, "The shells scored in float")."""
    from bench_precision import Views

    from gspc.views import synthesize_views

    views = Views.of(obj, synthesize_views(obj, 2, width=64, height=64), (0.0, 0.0, 0.0))
    nudged = obj.map(lambda t: t.detach().clone())
    nudged.sh_dc.add_(1e-2 / 255 / 0.2820948)  # a hundredth of a level of colour (C0 = 0.2820948)
    eight, flt = views.scores(nudged)
    assert eight == views.psnr(nudged)
    assert all(np.isfinite(eight)) and all(np.isfinite(flt))
    assert flt[0] > eight[0] + 10 and flt[1] > eight[1] + 10
    assert all(x > 80 for x in flt)  # 20 log10(100 x 255) = 88 dB where every pixel moves by that much
