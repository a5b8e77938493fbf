import numpy as np
import torch
from scenes import random_scene

from gspc.encoder.significance import measure_view, significance
from gspc.render import render
from gspc.views import synthesize_views


def test_blend_weights_sum_to_the_rendered_alpha():
    scene = random_scene(200, sh_degree=1, seed=3)
    cam = synthesize_views(scene, 1, 48, 40)[0]
    w = measure_view(scene, cam, (0.0, 0.0, 0.0)).weight
    assert w.shape == (200,) and (w >= 0).all()
    # A fraction of the view's pixels: the summed weights are the rendered alpha's mean.
    assert torch.isclose(w.sum(), render(scene, cam).alpha.double().mean(), rtol=1e-5)


def test_hidden_gaussian_weighs_nothing():
    """A Gaussian behind an opaque one (alpha capped at 0.99 twice over) takes almost no weight."""
    scene = random_scene(2, sh_degree=0, seed=0, log_scale=-2.0, opacity_logit=12.0)
    cam = synthesize_views(scene, 1, 32, 32)[0]
    centre = torch.tensor(cam.center, dtype=torch.float32)
    with torch.no_grad():
        scene.means[0] = 0.5 * centre  # half-way to the camera
        scene.means[1] = -0.5 * centre  # behind the first, from the camera
        scene.log_scales[1] = scene.log_scales[0] - 1.0  # and smaller on screen: wholly covered
    w = measure_view(scene, cam, (0.0, 0.0, 0.0)).weight * (32 * 32)  # in pixels
    assert w[0] > 10 and w[1] < 0.02 * w[0]


def test_attribute_gradients_cover_every_group_and_a_faint_speck_ranks_last():
    scene = random_scene(60, sh_degree=2, seed=5)
    with torch.no_grad():
        scene.opacities[7] = -5.0  # alpha 0.0067: barely shows
        scene.log_scales[7] = -7.0
    cams = synthesize_views(scene, 3, 40, 40)
    m = measure_view(scene, cams[0], (0.0, 0.0, 0.0))
    g = m.gradient
    assert m.sh_band_change.shape == (60, 2) and (m.sh_band_change >= 0).all()
    assert set(g) == {"means", "quats", "log_scales", "opacities", "sh_dc", "sh_rest"}
    assert all(v.shape == (60,) and torch.isfinite(v).all() for v in g.values())
    sig = significance(scene, cams)
    for measure in ("weight", "gradient:quats", "gradient:sh_rest"):
        order = sig.ranking(measure)
        assert sorted(order.tolist()) == list(range(60))
        assert np.where(order == 7)[0][0] >= 50  # among the least significant


def test_sh_band_change_is_the_first_order_change_of_dropping_a_band():
    """Linear in the coefficients: the summed image changes by exactly the band's term when it is dropped."""
    scene = random_scene(40, sh_degree=2, seed=9)
    cam = synthesize_views(scene, 1, 40, 40)[0]
    m = measure_view(scene, cam, (0.0, 0.0, 0.0))
    whole = render(scene, cam).image.double().sum()
    dropped = scene.map(lambda x: x.detach().clone())
    with torch.no_grad():
        dropped.sh_rest[:, 3:8] = 0  # band 2, every Gaussian
    change = (whole - render(dropped, cam).image.double().sum()).abs()
    # Colours clamped at 0 make it first order only; the Gaussians' own terms bound it.
    assert change <= m.sh_band_change[:, 1].sum() * 1.001 + 1e-6


def test_zooms_keep_each_gaussians_largest_per_pixel_measure():
    """At 1x and 2x a measure is the larger of the two per pixel: a speck finer than a pixel at 1x moves the
    2x picture more per pixel by its scale."""
    scene = random_scene(80, sh_degree=1, seed=11)
    with torch.no_grad():
        scene.log_scales[3] = -7.0  # far under a pixel at 1x
    cams = synthesize_views(scene, 2, 32, 32)
    one = significance(scene, cams)
    assert np.array_equal(significance(scene, cams, zooms=(1.0,)).weight, one.weight)
    both = significance(scene, cams, zooms=(1.0, 2.0))
    two = significance(scene, [c.scaled(2.0) for c in cams])
    assert np.array_equal(both.weight, np.maximum(one.weight, two.weight))
    for k, g in both.gradient.items():
        assert np.allclose(g, np.maximum(one.gradient[k], two.gradient[k] / 4))
    assert np.allclose(both.sh_band_change, np.maximum(one.sh_band_change, two.sh_band_change / 4))
    assert both.gradient["log_scales"][3] >= one.gradient["log_scales"][3]


def _looking_out(scene, cams, skip):
    """``cams`` with one camera outside ``skip`` turned half about its y axis (same centre, looking away from
    the scene) and Gaussian 0 placed in front of it: that camera alone sees it whole."""
    from gspc.cameras import Camera

    j = next(i for i, c in enumerate(cams) if all(c is not s for s in skip))
    flip = np.diag([-1.0, 1.0, -1.0, 1.0])
    cams[j] = Camera(flip @ cams[j].world_to_cam, cams[j].K, cams[j].width, cams[j].height)
    centre = np.asarray(cams[j].center)
    with torch.no_grad():
        scene.means[0] = torch.tensor(centre * 1.3, dtype=torch.float32)
        scene.log_scales[0] = float(np.log(0.05 * np.linalg.norm(centre)))
    return cams


def test_every_camera_is_measured_at_its_own_size_and_a_sample_zoomed():
    """Up to WIDE_VIEWS cameras each is measured at 1x (what one camera alone sees is never a glimpse), a
    sample of them at the larger zooms, per Gaussian the largest per view of the whole set."""
    from gspc.encoder.significance import SIGNIFICANCE_VIEWS, WIDE_VIEWS, encoder_significance, evenly_spaced

    scene = random_scene(50, sh_degree=1, seed=2)
    cams = synthesize_views(scene, 3 * SIGNIFICANCE_VIEWS, 24, 24)
    assert len(cams) <= WIDE_VIEWS
    sample = evenly_spaced(cams, SIGNIFICANCE_VIEWS)
    cams = _looking_out(scene, cams, sample)
    sig = encoder_significance(scene, cams)
    one = significance(scene, cams)
    two = significance(scene, evenly_spaced(cams, SIGNIFICANCE_VIEWS), zooms=(2.0,))
    per_view = len(cams) / SIGNIFICANCE_VIEWS
    assert np.array_equal(sig.weight, np.maximum(one.weight, two.weight * per_view))
    for k, g in sig.gradient.items():
        assert np.array_equal(g, np.maximum(one.gradient[k], two.gradient[k] * per_view))
    assert np.array_equal(sig.sh_band_change, np.maximum(one.sh_band_change, two.sh_band_change * per_view))
    plain = significance(scene, sample, zooms=(1.0, 2.0))
    assert sig.weight[0] > 2 * per_view * plain.weight[0]


def test_beyond_the_measured_cameras_a_gaussian_they_under_show_is_measured_at_every_camera():
    """Past WIDE_VIEWS cameras, a Gaussian close in front of one unmeasured camera gets that camera's measure
    (per measured view) instead of the glimpse the others have of it; the rest keep theirs."""
    from gspc.encoder.significance import WIDE_VIEWS, encoder_significance, evenly_spaced

    scene = random_scene(50, sh_degree=0, seed=2)
    cams = synthesize_views(scene, 2 * WIDE_VIEWS, 16, 16)
    wide = evenly_spaced(cams, WIDE_VIEWS)
    cams = _looking_out(scene, cams, wide)
    plain = encoder_significance(scene, evenly_spaced(cams, WIDE_VIEWS))  # the same cameras, no survey
    sig = encoder_significance(scene, cams)
    assert sig.weight[0] > 2 * plain.weight[0]
    assert sig.gradient["log_scales"][0] > 2 * plain.gradient["log_scales"][0]
    # Only raised, never lowered; the others are shown as well by the measured cameras as by every camera.
    assert (sig.weight >= plain.weight).all()
    assert (sig.weight[1:] == plain.weight[1:]).mean() > 0.8


def test_the_measure_reports_one_stage_from_open_to_close():
    """The 1x views and the zoomed sample are one "significance" stage: opened once, counted up, closed."""
    from gspc.encoder.significance import SIGNIFICANCE_VIEWS, encoder_significance

    scene = random_scene(30, sh_degree=0, seed=4)
    cams = synthesize_views(scene, SIGNIFICANCE_VIEWS + 5, 12, 12)
    calls = []
    encoder_significance(scene, cams, progress=lambda stage, done, total: calls.append((stage, done, total)))
    assert {c[0] for c in calls} == {"significance"}
    done = [c[1] for c in calls]
    total = calls[0][2]
    assert all(c[2] == total for c in calls) and done == sorted(done)
    assert done.count(0) == 1 and done.count(total) == 1 and done[-1] == total


def test_the_1x_pass_is_bounded_in_gaussian_views_never_below_the_sample(monkeypatch):
    """Past WIDE_WORK Gaussian-views the 1x pass measures fewer cameras (a 1M-Gaussian scene would otherwise
    pay about 150 s for 44 more views), never fewer than the sample; there the measure is the sample's own."""
    import gspc.encoder.significance as sg

    cams = synthesize_views(random_scene(10, seed=1), 3 * sg.SIGNIFICANCE_VIEWS, 16, 16)
    assert len(sg.wide_cameras(cams, 1000)) == len(cams)  # 60 <= WIDE_VIEWS
    assert len(sg.wide_cameras(cams, sg.WIDE_WORK // 30)) == 30
    assert len(sg.wide_cameras(cams, 10 * sg.WIDE_WORK)) == sg.SIGNIFICANCE_VIEWS
    scene = random_scene(40, sh_degree=0, seed=6)
    monkeypatch.setattr(sg, "WIDE_WORK", 40)  # one view's worth for 40 Gaussians: the sample alone
    sig = sg.encoder_significance(scene, cams)
    sample = sg.evenly_spaced(cams, sg.SIGNIFICANCE_VIEWS)
    plain = significance(scene, sample, zooms=(1.0, 2.0))
    assert np.allclose(sig.weight[plain.weight > 0], plain.weight[plain.weight > 0])


def test_the_compiled_sums_are_the_plain_ones():
    # significance_cpu.py against the PyTorch sums it replaced: absolute values summed per row, and per SH
    # band |sum of gradient x coefficient| (products in the inputs' dtype, sums in float64).
    from gspc.encoder import significance_cpu as kern

    g = torch.Generator().manual_seed(3)
    every = np.arange(500)
    some = every[::3]  # the drawn rows: the others are read as zero
    for dtype in (torch.float32, torch.float64):
        rows = torch.randn(500, 7, generator=g, dtype=dtype)
        expected = rows.double().abs().sum(1).numpy()
        np.testing.assert_allclose(kern.abs_row_sums(rows.numpy(), every), expected, rtol=1e-6)
        part = kern.abs_row_sums(rows.numpy(), some)
        assert np.array_equal(part[some], kern.abs_row_sums(rows.numpy(), every)[some])
        assert not np.delete(part, some).any()
        grad, coef = torch.randn(2, 500, 15, 3, generator=g, dtype=dtype).unbind(0)
        product = (grad * coef).double()
        for degree in (1, 2, 3):
            bands = [product[:, b * b - 1 : (b + 1) ** 2 - 1].sum((1, 2)).abs() for b in range(1, degree + 1)]
            got = kern.band_changes(grad.numpy(), coef.numpy(), degree, every)
            assert got.shape == (500, degree)
            np.testing.assert_allclose(got, torch.stack(bands, 1).numpy(), rtol=1e-9, atol=1e-12)
            part = kern.band_changes(grad.numpy(), coef.numpy(), degree, some)
            assert np.array_equal(part[some], got[some]) and not np.delete(part, some, axis=0).any()
