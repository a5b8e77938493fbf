"""Attribute codec version 4: per-Gaussian precision classes and SH degrees (the file's, and the plan)."""

import msgpack
import numpy as np
import pytest
import torch
from scenes import random_scene

from gspc.codec.attributes import decode_attributes, decoded_precision
from gspc.codec.cells import quantisation_cells
from gspc.codec.precision import PrecisionMap, encode_precision
from gspc.encoder.coding import encode_attributes
from gspc.encoder.params import CodecParams
from gspc.encoder.precision_plan import PrecisionParams, Significance, class_exponents, sh_degrees
from gspc.errors import CodecError
from gspc.format.attribute_section import AttributeSection
from gspc.format.chunks import OPAC, PREC, SHRS
from gspc.scene import ATTRIBUTE_NAMES, scene_equal


def _significance(n: int, degree: int, seed: int = 0) -> Significance:
    """Measures spread over six orders of magnitude, as a real scene's are (bench/significance.md)."""
    rng = np.random.default_rng(seed)
    grad = {k: 10.0 ** rng.uniform(-4, 2, n) for k in ATTRIBUTE_NAMES}
    return Significance(10.0 ** rng.uniform(-7, -1, n), grad, 10.0 ** rng.uniform(-5, 1, (n, degree)), 20)


PARAMS = CodecParams(lam=4.0, precision=PrecisionParams(exponents=(-1, 2), bias=1.0, sh_keep=1.0))


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_round_trip_is_exact_and_classes_reach_the_decoder(degree):
    scene = random_scene(600, sh_degree=degree, seed=degree)
    sig = _significance(600, degree, seed=degree)
    enc = encode_attributes(scene, PARAMS, significance=sig)
    assert enc.section.version == 4 and PREC in enc.chunks
    assert (SHRS in enc.chunks) == (degree > 0)
    dec = decode_attributes(enc.chunks, enc.section)
    assert scene_equal(dec, enc.decoded)
    # Through the header's bytes too: the section the file carries reads back equal.
    again = AttributeSection.from_dict(enc.section.to_dict())
    assert again == enc.section and scene_equal(decode_attributes(enc.chunks, again), dec)
    pmap = decoded_precision(enc.chunks, enc.section)
    assert len(np.unique(pmap.classes)) > 1
    if degree:
        assert len(np.unique(pmap.degrees)) > 1
        for b in range(1, degree + 1):  # bands above a Gaussian's degree decode as zero
            above = pmap.degrees < b
            assert (dec.sh_rest[torch.from_numpy(above), b * b - 1 : (b + 1) ** 2 - 1] == 0).all()


def test_each_class_keeps_its_error_within_its_own_steps():
    scene = random_scene(800, sh_degree=1, seed=4)
    enc = encode_attributes(scene, PARAMS, significance=_significance(800, 1, seed=4))
    pmap = decoded_precision(enc.chunks, enc.section)
    orig = scene.log_scales.detach()[torch.from_numpy(enc.kept)]
    err = (enc.decoded.log_scales - orig).abs().max(1).values.numpy()
    steps = [c.scale_step for c in enc.section.all_classes]
    for k, step in enumerate(steps):
        rows = pmap.rows(k)
        assert rows.size and err[rows].max() <= step / 2 + 1e-6
    assert max(steps) / min(steps) == 8.0  # exponents -1 .. 2


def test_cells_follow_each_gaussians_class():
    scene = random_scene(500, sh_degree=2, seed=6)
    enc = encode_attributes(scene, PARAMS, significance=_significance(500, 2, seed=6))
    pmap = decoded_precision(enc.chunks, enc.section)
    cells = quantisation_cells(enc.decoded, enc.section, pmap)
    orig = scene.map(lambda x: x.detach()[torch.from_numpy(enc.kept)])
    for name in ("log_scales", "sh_dc", "opacities"):
        lo, hi = cells[name]
        x = getattr(orig, name)
        assert ((x >= lo - 1e-5) & (x <= hi + 1e-5)).all(), name
    lo, hi = cells["log_scales"]
    width = (hi - lo)[:, 0].numpy()
    for k, c in enumerate(enc.section.all_classes):
        assert np.allclose(width[pmap.rows(k)], c.scale_step, rtol=1e-5)
    # SH bands above a Gaussian's degree were dropped by the encoder: no bound there.
    lo, hi = cells["sh_rest"]
    above = torch.from_numpy(pmap.degrees < 2)
    assert torch.isinf(hi[above, 3:8]).all() and torch.isfinite(hi[~above, 3:8]).all()


def test_without_significance_or_precision_the_uniform_codec_is_written():
    scene = random_scene(300, sh_degree=1, seed=1)
    plain = encode_attributes(scene, CodecParams(lam=4.0))
    assert encode_attributes(scene, PARAMS).chunks == plain.chunks  # no measure: nothing to plan from
    assert plain.section.version == 1 and PREC not in plain.chunks


def test_exponents_follow_half_the_log_of_sensitivity():
    sens = np.array([1.0, 4.0, 16.0, 0.25, 1 / 16, 0.0])
    e = class_exponents(sens, PrecisionParams(exponents=(-2, 2)))
    # median of the positive values is 1: four times as sensitive, half the step
    assert e.tolist() == [0, -1, -2, 1, 2, 2]


def test_exponents_beyond_the_tail_follow_at_half_the_pace():
    """Beyond ``tail`` two of the rule's classes make one: the measure over-predicts the most sensitive
    Gaussians (bench/precision.md), and a hard floor left a sky of large Gaussians coarse."""
    sens = 4.0 ** np.arange(0, 12)  # the rule's exponents 0, -1, ..., -11 (median 4^5.5: bias -5.5 evens it)
    rule = class_exponents(sens, PrecisionParams(exponents=(-20, 2), bias=-5.5))
    assert rule.tolist() == list(range(0, -12, -1))
    tailed = class_exponents(sens, PrecisionParams(exponents=(-7, 2), bias=-5.5, tail=-4))
    assert tailed.tolist() == [0, -1, -2, -3, -4, -4, -5, -5, -6, -6, -7, -7]
    # coarser than the tail, and without one, the rule as it was
    assert class_exponents(sens, PrecisionParams(exponents=(-4, 2), bias=-5.5)).tolist() == [
        max(e, -4) for e in rule.tolist()
    ]


def test_classes_follow_sensitivity_per_coded_component():
    """A Gaussian whose 45 SH rest coefficients are each as sensitive as its other components are on average
    gets the class of its twin without SH bands: the SH rest counts per coefficient (its gradient sums over
    them; squared as a whole it counted their colour up to 45 times over), and the class divides by the
    components a halving of the steps costs bits for (10 without SH bands, 55 with three)."""
    from gspc.encoder.precision_plan import RateSteps, plan_precision

    n, d = 400, 3
    rng = np.random.default_rng(7)
    twin = np.arange(n) % 2 == 1  # odd rows: a twin of the row before, without SH bands
    grad = {g: np.repeat(10.0 ** rng.uniform(-2, 2, n // 2), 2) for g in ("opacities", "log_scales")}
    grad.update(quats=np.repeat(10.0 ** rng.uniform(-2, 2, n // 2), 2), means=np.zeros(n))
    grad["sh_dc"] = np.repeat(10.0 ** rng.uniform(-2, 2, n // 2), 2)
    steps = RateSteps(100, 0.1, 0.01, 0.05, (0.1, 0.12, 0.144))
    alpha = np.full(n, 0.5)
    group_steps = {"opacities": 1.0 / (100 * 0.25), "log_scales": 0.1, "quats": 0.01, "sh_dc": 0.05}
    others = sum((grad[g] * s) ** 2 for g, s in group_steps.items())  # the twin's sensitivity, 10 components
    grad["sh_rest"] = np.where(twin, 0.0, 45 * np.sqrt(others / 10) / 0.1)
    change = np.where(twin[:, None], 0.0, 1e3)[:, [0, 0, 0]]  # every band worth keeping, or none
    sig = Significance(np.ones(n), grad, change, 20)
    params = PrecisionParams(exponents=(-6, 6), bias=0.0, sh_keep=1.0)
    plan = plan_precision(sig, alpha, steps, params, np.ones(n, bool), 0.0, 1.0)
    assert (plan.degree[~twin] == d).all() and (plan.degree[twin] == 0).all()
    assert len(np.unique(plan.exponent)) > 4
    assert np.array_equal(plan.exponent[twin], plan.exponent[~twin])


def test_small_classes_join_their_neighbour_towards_the_rates_steps():
    from gspc.encoder.precision_plan import merge_small_classes

    e = np.array([-3] * 2 + [-2] * 3 + [-1] * 10 + [0] * 10 + [1] * 4 + [2] * 10 + [-3] * 5)
    among = np.ones(len(e), bool)
    among[-5:] = False  # not coded (removed): they do not count, but move with their class
    params = PrecisionParams(exponents=(-3, 2), min_class=5)
    out = merge_small_classes(e, among, params)
    # -3 (2 coded) joins -2 (then 5: stays); 1 (4) joins 0; 2 (10) stays.
    assert out.tolist() == [-2] * 5 + [-1] * 10 + [0] * 14 + [2] * 10 + [-2] * 5
    assert merge_small_classes(e, among, PrecisionParams(exponents=(-3, 2))).tolist() == e.tolist()


def test_sh_degree_is_the_highest_band_worth_its_step():
    change = np.array([[5.0, 0.1, 3.0], [0.1, 0.1, 0.1], [2.0, 2.0, 0.0]])
    d = sh_degrees(change, np.array([1.0, 1.0, 1.0]), np.ones(3), 1.0)
    assert d.tolist() == [3, 0, 2]
    assert sh_degrees(change, np.ones(3), np.ones(3), 0.0).tolist() == [3, 3, 3]


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda a: a.update(classes=[{}]), "opacity_levels"),
        (lambda a: a.update(classes=[a["classes"][0]] * 16), "at most 15"),
        (lambda a: a.pop("classes"), "classes"),
        (lambda a: a.update(version=1), "chunk PREC in a file of attribute codec version 1"),
    ],
)
def test_hostile_class_headers_are_refused(edit, words):
    scene = random_scene(300, sh_degree=1, seed=2)
    enc = encode_attributes(scene, PARAMS, significance=_significance(300, 1, seed=2))
    a = enc.section.to_dict()
    edit(a)
    with pytest.raises(CodecError, match=words):
        section = AttributeSection.from_dict(a)
        decode_attributes(enc.chunks, section)


def test_hostile_class_payloads_are_refused():
    scene = random_scene(300, sh_degree=1, seed=2)
    enc = encode_attributes(scene, PARAMS, significance=_significance(300, 1, seed=2))
    n, c = enc.section.n, len(enc.section.all_classes)
    bad = PrecisionMap(np.full(n, c), np.zeros(n, np.int64))
    with pytest.raises(CodecError, match="precision class outside"):
        decode_attributes({**enc.chunks, PREC: encode_precision(bad, 1)}, enc.section)
    bad = PrecisionMap(np.zeros(n, np.int64), np.full(n, 2))
    with pytest.raises(CodecError, match="SH degree outside"):
        decode_attributes({**enc.chunks, PREC: encode_precision(bad, 1)}, enc.section)
    with pytest.raises(CodecError, match="array of"):
        short = msgpack.packb(msgpack.unpackb(enc.chunks[OPAC])[:-1], use_bin_type=True)
        decode_attributes({**enc.chunks, OPAC: short}, enc.section)
    with pytest.raises(CodecError, match="missing"):
        decode_attributes({k: v for k, v in enc.chunks.items() if k != PREC}, enc.section)


def test_gaussians_no_measured_view_shows_keep_the_rates_steps_and_their_place():
    """The measure renders a sample of the views: unmeasured Gaussians are neither removed nor coarsened."""
    scene = random_scene(400, sh_degree=2, seed=8)
    sig = _significance(400, 2, seed=8)
    unseen = np.zeros(400, bool)
    unseen[::7] = True
    sig.weight[unseen] = 0.0
    for g in sig.gradient.values():
        g[unseen] = 0.0
    sig.sh_band_change[unseen] = 0.0
    prec = PrecisionParams(exponents=(-1, 2), bias=1.0, sh_keep=1.0, prune=0.5)
    params = CodecParams(lam=4.0, precision=prec)
    enc = encode_attributes(scene, params, significance=sig)
    pmap = decoded_precision(enc.chunks, enc.section)
    rows = unseen[enc.kept]
    assert rows.sum() == unseen.sum()  # none removed
    assert (pmap.classes[rows] == 0).all() and (pmap.degrees[rows] == 2).all()
    assert len(enc.kept) < 400  # the measured faint ones were removed


def test_removal_keeps_half_at_any_lambda():
    """The removal floor grows with lambda but never past the median's weight: at least half the measured
    Gaussians stay (the low preset at lambda 200 removed every one of a small scene)."""
    from gspc.presets import QUALITY

    scene = random_scene(300, sh_degree=0, seed=5)
    for lam in (200.0, 1e6):
        enc = encode_attributes(
            scene, QUALITY["low"].attributes.with_lambda(lam), significance=_significance(300, 0, seed=5)
        )
        assert 150 <= len(enc.kept) < 300


def test_a_raised_cap_lets_the_floor_pass_the_medians_weight():
    # The encoder's removal search (gspc/encoder/removal.py) measures stronger removals than the preset's
    # cap allows: at twice the median's weight fewer than half stay.
    from dataclasses import replace

    from gspc.presets import QUALITY

    scene = random_scene(300, sh_degree=0, seed=5)
    params = QUALITY["low"].attributes.with_lambda(200.0)
    params = replace(params, precision=replace(params.precision, prune_cap=2.0))
    enc = encode_attributes(scene, params, significance=_significance(300, 0, seed=5))
    assert len(enc.kept) < 150


def test_the_high_preset_removes_nothing():
    from gspc.presets import QUALITY

    scene = random_scene(300, sh_degree=1, seed=3)
    enc = encode_attributes(scene, QUALITY["high"].attributes, significance=_significance(300, 1, seed=3))
    plain = encode_attributes(scene, CodecParams(lam=1.0))
    assert enc.section.version == 4 and np.array_equal(np.sort(enc.kept), np.sort(plain.kept))


def test_info_names_a_version_4_files_classes(tmp_path):
    from typer.testing import CliRunner

    from gspc.cli import app
    from gspc.format import container
    from gspc.io import write_ply
    from gspc.pipeline import EncodeOptions, encode

    src, out = tmp_path / "s.ply", tmp_path / "s.gspc"
    write_ply(random_scene(300, sh_degree=1, seed=2), src)
    encode(src, out, opts=EncodeOptions(side_info=False, synth_views=4, max_side=48))
    shown = CliRunner().invoke(app, ["info", str(out)], terminal_width=200).output
    section = AttributeSection.from_dict(container.read(out).header["attributes"])
    assert section.version == 4
    assert f"precision: {len(section.all_classes)} classes per Gaussian" in shown


def test_unrefined_parameters_code_finer_geometry_only_at_low_rates():
    """A file without side information codes scales and rotations on CodecParams.unrefined()'s schedule: the
    same steps up to lambda 6, finer beyond; the uniform codec keeps its own."""
    from gspc.encoder.rate import coded_with
    from gspc.presets import QUALITY

    assert CodecParams(lam=10.0).unrefined() == CodecParams(lam=10.0)
    low = QUALITY["low"].attributes
    fine = low.unrefined()
    assert fine.with_lambda(4.0).geometry_lam == low.with_lambda(4.0).geometry_lam == 4.0
    assert fine.with_lambda(10.0).geometry_lam == pytest.approx(6.0 * (10.0 / 6.0) ** 0.25)
    assert fine.with_lambda(10.0).geometry_lam < low.with_lambda(10.0).geometry_lam
    scene = random_scene(300, sh_degree=1, seed=4)
    sig = _significance(300, 1, seed=4)
    enc = encode_attributes(scene, low.with_lambda(10.0), significance=sig)
    assert coded_with(enc, low) and not coded_with(enc, fine)
    enc4 = encode_attributes(scene, low.with_lambda(4.0), significance=sig)
    assert coded_with(enc4, fine)  # a search may start from it


def test_a_file_without_side_information_has_the_unrefined_steps(tmp_path):
    from gspc.format import container
    from gspc.io import write_ply
    from gspc.pipeline import EncodeOptions, encode
    from gspc.presets import QUALITY

    src, out = tmp_path / "s.ply", tmp_path / "s.gspc"
    write_ply(random_scene(300, sh_degree=1, seed=2), src)
    # Past the knee whatever lambda the removal search settles on (its steps code at lower ones).
    encode(src, out, opts=EncodeOptions(side_info=False, synth_views=4, max_side=48, lam=16.0))
    base = AttributeSection.from_dict(container.read(out).header["attributes"]).base_class()
    params = QUALITY["low"].attributes
    lam = base.dc_step / params.dc_step  # the lambda the encoder's search settled on
    assert lam > params.geometry_knee  # a rate where the two schedules differ
    fine, coarse = params.unrefined().with_lambda(lam), params.with_lambda(lam)
    assert base.scale_step == pytest.approx(fine.scale_step * fine.geometry_lam, rel=1e-9)
    assert base.scale_step < coarse.scale_step * coarse.geometry_lam
