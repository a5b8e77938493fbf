import numpy as np
import pytest
import torch
from scenes import front_cameras as _cameras
from scenes import front_scene as _scene

from gspc.errors import InputError
from gspc.refine import Schedule, refine, scene_extent
from gspc.scene import scene_equal


def _loss(scene, cams, targets, render):
    from gspc.metrics import ssim

    total = 0.0
    with torch.no_grad():
        for c, t in zip(cams, targets, strict=True):
            img = render(scene, c).image
            total += float(0.8 * (img - t).abs().mean() + 0.2 * (1 - ssim(img, t)))
    return total / len(cams)


@pytest.fixture
def setup():
    from gspc.render import render

    cams = _cameras()
    original = _scene()
    try:
        with torch.no_grad():
            targets = [render(original, c).image for c in cams]
    except NotImplementedError:
        pytest.skip("gspc.render.render is not implemented yet")
    g = torch.Generator().manual_seed(1)
    perturbed = original.map(lambda t: t + 0.05 * torch.randn(t.shape, generator=g))
    return render, cams, targets, perturbed


def test_refine_reduces_loss_and_is_deterministic(setup):
    render, cams, targets, perturbed = setup
    calls = []
    run = refine(perturbed, cams, targets, Schedule(30), progress=lambda *a: calls.append(a))
    assert [(done, total) for done, total, _ in calls] == [(i + 1, 30) for i in range(30)]
    assert run.iterations == 30
    out = run.scene
    assert out.num_gaussians == perturbed.num_gaussians
    assert not out.means.requires_grad
    assert _loss(out, cams, targets, render) < 0.9 * _loss(perturbed, cams, targets, render)
    assert scene_equal(out, refine(perturbed, cams, targets, Schedule(30)).scene)


def test_refine_only_chosen_attributes_and_leaves_input(setup):
    _, cams, targets, perturbed = setup
    before = perturbed.detach()
    out = refine(perturbed, cams, targets, Schedule(3, resolution=0.5), attributes=("sh_dc",)).scene
    assert scene_equal(perturbed, before)
    assert torch.equal(out.means, perturbed.means) and torch.equal(out.opacities, perturbed.opacities)
    assert not torch.equal(out.sh_dc, perturbed.sh_dc)


def test_refine_checks_inputs():
    cams = _cameras(2)
    scene = _scene(5)
    with pytest.raises(InputError):
        refine(scene, cams, [torch.zeros(32, 32, 3)], Schedule(1))
    with pytest.raises(InputError):
        refine(scene, cams, [torch.zeros(16, 32, 3)] * 2, Schedule(1))
    with pytest.raises(InputError):
        refine(scene, cams, [torch.zeros(32, 32, 3)] * 2, Schedule(1), attributes=("colour",))
    assert scene_equal(refine(scene, cams, [torch.zeros(32, 32, 3)] * 2, Schedule(0)).scene, scene)


def test_refine_deadline_shortens_the_schedule(setup, monkeypatch):
    """A deadline: the first PROBE_ITERATIONS are timed and the schedule cut to what fits; the decay then
    still ends at zero (no step at full rate is left for last). A clock stands in for the machine's."""
    import gspc.refine as refine_module

    _, cams, targets, perturbed = setup
    clock = iter(range(0, 10_000))  # one "second" per reading
    monkeypatch.setattr(refine_module.time, "perf_counter", lambda: float(next(clock)))
    calls = []
    run = refine(perturbed, cams, targets, Schedule(100), deadline=12.0, progress=lambda *a: calls.append(a))
    assert refine_module.PROBE_ITERATIONS < run.iterations < 100
    assert calls[-1][:2] == (run.iterations, run.iterations)
    # A deadline already passed: nothing runs, the scene is returned as it came.
    assert refine(perturbed, cams, targets, Schedule(100), deadline=-1.0).iterations == 0


def test_a_cut_short_schedule_takes_the_steps_of_its_new_length(setup, monkeypatch):
    """full_rate_from: a run below it takes rates x length / full_rate_from; a deadline that cuts the
    schedule rescales the remaining steps to the new length (as if that length had been asked for)."""
    import gspc.refine as refine_module
    from gspc.adam import FusedAdam

    _, cams, targets, perturbed = setup
    rates = []
    step = FusedAdam.step

    def recording_step(self, *a, **k):
        rates.append(self.param_groups[0]["lr"])
        return step(self, *a, **k)

    monkeypatch.setattr(FusedAdam, "step", recording_step)
    refine(perturbed, cams, targets, Schedule(200, full_rate_from=400))
    full = rates[0] / 0.5  # the first step runs at the undecayed rate x 200 / 400
    rates.clear()
    clock = iter(range(0, 10_000))
    monkeypatch.setattr(refine_module.time, "perf_counter", lambda: float(next(clock)))
    run = refine(perturbed, cams, targets, Schedule(200, full_rate_from=400), deadline=12.0)
    n = run.iterations
    assert refine_module.PROBE_ITERATIONS < n < 200
    it = n - 1  # the last step: decayed over the new length, at rates x n / 400
    expected = full * (n / 400) * 0.5 * (1 + np.cos(np.pi * it / n))
    assert rates[-1] == pytest.approx(expected, rel=1e-9)


def test_scene_extent_from_cameras():
    assert np.isclose(scene_extent(_cameras(3), _scene(5)), 0.3 * 1.1)
    assert scene_extent(_cameras(1), _scene(5)) > 0
    # One camera: the Gaussians' spread, which far floaters (5 of 100, 1000 units out) do not set.
    scene = _scene(100)
    near = scene_extent(_cameras(1), scene)
    scene.means[:5] += 1000.0
    assert near < 2.0 and scene_extent(_cameras(1), scene) < 2 * near


def test_schedule_decays_to_zero_and_scales_short_runs():
    s = Schedule(100, rate=8.0)
    assert s.learning_rate_factor(0, 100) == 8.0
    assert s.learning_rate_factor(50, 100) == pytest.approx(4.0)
    assert s.learning_rate_factor(99, 100) < 0.01
    short = Schedule(100, rate=8.0, full_rate_from=400)
    assert short.learning_rate_factor(0, 100) == pytest.approx(2.0)  # 8 x 100 / 400
    assert short.learning_rate_factor(0, 50) == pytest.approx(1.0)  # a cut run: its new length decides
    assert Schedule(500, full_rate_from=400).learning_rate_factor(0, 500) == 1.0


def test_a_paused_run_goes_on_as_one_run(setup):
    """The check scores a run part-way and continues it: the result is the uninterrupted run's, exactly."""
    from gspc.refine import Refinement

    _, cams, targets, perturbed = setup
    whole = refine(perturbed, cams, targets, Schedule(12, rate=2.0)).scene
    run = Refinement(perturbed, cams, targets, Schedule(12, rate=2.0))
    run.run(5)
    assert run.done == 5 and not scene_equal(run.scene(), perturbed)
    run.run(5)  # already there: nothing more
    assert run.done == 5
    run.run()
    assert run.done == 12 and scene_equal(run.result().scene, whole)


def test_deadline_probes_then_shortens(monkeypatch):
    import gspc.refine as refine_module
    from gspc.refine import Deadline

    clock = iter([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])  # one "second" per iteration
    monkeypatch.setattr(refine_module.time, "perf_counter", lambda: next(clock))
    d = Deadline(10.0)
    assert not d.passed()  # 0 s
    assert d.length(1, 100) == 100  # 1 s: the first iteration, not timed
    assert d.length(2, 100) == 100 and d.length(3, 100) == 100
    # 4 s after 1 + PROBE_ITERATIONS: 1 s each, 6 s left: 6 more
    assert refine_module.PROBE_ITERATIONS == 3 and d.length(4, 100) == 10
