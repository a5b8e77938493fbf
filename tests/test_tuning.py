"""The encoder's tuning of its coded values (gspc/encoder/tuning.py): it renders closer at its views, moves no
value more than its reach, keeps to its byte limit, and returns the untuned coding where it cannot help."""

import time
from dataclasses import replace

import numpy as np
import torch
from scenes import random_scene

from gspc.codec.attributes import decode_attributes
from gspc.codec.cells import quantisation_cells
from gspc.encoder.coding import encode_attributes
from gspc.encoder.significance import encoder_significance
from gspc.encoder.tuning import TuningParams, tune_coding
from gspc.metrics import mean_psnr
from gspc.presets import quality_preset
from gspc.reconstruct import render_images
from gspc.views import synthesize_views


def _small(precision: bool = True):
    scene = random_scene(1200, sh_degree=1, seed=3, log_scale=-3.0)
    cams = synthesize_views(scene, 8, width=40, height=40)
    params = replace(quality_preset("low").attributes, lam=8.0)
    sig = None
    if precision:
        sig = encoder_significance(scene, cams)
    else:
        params = replace(params, precision=None)
    enc = encode_attributes(scene, params, significance=sig)
    return scene, cams, params, sig, enc


def _psnr(scene, enc, cams) -> float:
    ref = render_images(scene, cams, (0.0, 0.0, 0.0))
    return mean_psnr(render_images(enc.decoded, cams, (0.0, 0.0, 0.0)), ref)


def test_tuned_values_render_closer_in_about_the_same_bytes():
    scene, cams, params, sig, enc = _small()
    tuned = tune_coding(scene, enc, params, cams, (0, 0, 0), None, sig, TuningParams(iterations=4))
    rep = tuned.report
    assert rep.kept and rep.after_db > rep.before_db and rep.iterations == 4
    assert tuned.encoded is not enc
    assert tuned.encoded.num_bytes <= enc.num_bytes * 1.02  # the default growth
    assert _psnr(scene, tuned.encoded, cams) > _psnr(scene, enc, cams)
    # A coding like any other: its chunks decode to its scene, its Gaussians are the untuned one's.
    again = decode_attributes(tuned.encoded.chunks, tuned.encoded.section)
    assert torch.equal(again.quats, tuned.encoded.decoded.quats)
    assert sorted(tuned.encoded.kept.tolist()) == sorted(enc.kept.tolist())


def test_the_uniform_codec_is_tuned_too():
    scene, cams, params, _, enc = _small(precision=False)
    tuned = tune_coding(scene, enc, params, cams, (0, 0, 0), None, None, TuningParams(iterations=3))
    assert tuned.report.kept and _psnr(scene, tuned.encoded, cams) > _psnr(scene, enc, cams)


def test_no_value_moves_past_its_reach():
    # Reach 1/4 cell: every decoded value is the nearest grid point or its neighbour, never two cells away.
    scene, cams, params, sig, enc = _small()
    tuned = tune_coding(
        scene, enc, params, cams, (0, 0, 0), None, sig, TuningParams(iterations=4, reach=0.25)
    )
    t = tuned.encoded
    assert t is not enc and np.array_equal(t.kept, enc.kept)
    lo, hi = quantisation_cells(enc.decoded, enc.section, enc.precision)["log_scales"]
    width = hi - lo
    moved = (t.decoded.log_scales - enc.decoded.log_scales).abs() / width
    assert moved.max() <= 1.0 + 1e-4 and (moved > 0.5).any()


def test_the_untuned_coding_where_tuning_cannot_help():
    scene, cams, params, sig, enc = _small()
    # No step: the same values, so the same coding, no closer.
    still = tune_coding(scene, enc, params, cams, (0, 0, 0), None, sig, TuningParams(iterations=2, step=0.0))
    assert still.encoded is enc and not still.report.kept
    # No coding fits the limit.
    tight = tune_coding(scene, enc, params, cams, (0, 0, 0), None, sig, TuningParams(iterations=2), 100)
    assert tight.encoded is enc and not tight.report.kept
    assert tight.report.before_db == tight.report.after_db > 0  # measured once, nothing kept
    # Past the deadline no iteration starts.
    late = tune_coding(
        scene,
        enc,
        params,
        cams,
        (0, 0, 0),
        None,
        sig,
        TuningParams(iterations=2),
        deadline=time.perf_counter(),
    )
    assert late.encoded is enc and late.report.iterations == 0


def test_the_share_of_cameras_rotates_over_all_of_them():
    from gspc.encoder.tuning import _share

    seen = set()
    for it in range(4):
        seen.update(_share(16, 4, it))
    assert seen == set(range(16)) and len(_share(16, 4, 1)) == 4 and _share(5, 1, 3) == [0, 1, 2, 3, 4]


def test_a_scene_past_the_work_bound_is_not_tuned(monkeypatch):
    from gspc.encoder import tuning

    scene, cams, params, sig, enc = _small()
    monkeypatch.setattr(tuning, "TUNE_WORK", tuning.MIN_VIEWS * scene.num_gaussians - 1)
    out = tune_coding(scene, enc, params, cams, (0, 0, 0), None, sig, TuningParams(iterations=2))
    assert out.encoded is enc and out.report.iterations == 0 and "work bound" in out.report.summary()


def test_twice_every_puts_both_sizes_in_every_share():
    """TuningParams.twice_every = 2 (measured, off by default: bench/precision.md, "Tuning at twice the
    size"): each iteration's share of the cameras holds views at their size and at twice it."""
    from gspc.encoder.tuning import _share, _zoomed

    cams = synthesize_views(random_scene(50, sh_degree=0, seed=1), 12, width=40, height=30)
    assert _zoomed(cams, 4, 0) == cams
    views = _zoomed(cams, 4, 2)
    for it in range(4):
        widths = {views[i].width for i in _share(len(views), 4, it)}
        assert widths == {40, 80}
