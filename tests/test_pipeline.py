"""Pipeline-level behaviour: what the decoder accepts, what it writes, and when it refines."""

import numpy as np
import plyfile
import pytest
import torch
from scenes import coarse_residual_scene, random_scene

from gspc.encoder.policy import CheckPolicy, Outcome, trial_settles
from gspc.errors import CodecError, InputError
from gspc.format import container
from gspc.format.attribute_section import AttributeSection
from gspc.format.header import FileHeader
from gspc.format.side_chunk import read_side_views
from gspc.io import read_scene, write_ply
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, decode_bytes, encode, encode_scene


def side_of(c: container.Container) -> tuple:
    """(view records, residual images) of a file, read as the decoder reads them."""
    side = read_side_views(FileHeader.from_dict(c.header).side_info.legacy_views, c.chunks, 1 << 30)
    return side.views, side.images


@pytest.fixture(scope="module")
def encoded(tmp_path_factory):
    d = tmp_path_factory.mktemp("pipe")
    src = d / "in.ply"
    write_ply(coarse_residual_scene(), src)
    out = d / "s.gspc"
    # A coarse rate so the residuals are clearly above the skip threshold.
    rep = encode(src, out, opts=EncodeOptions(lam=40, synth_views=5, max_side=40, check_iterations=0))
    return src, out, rep


def test_encode_report_and_views(encoded):
    _, out, rep = encoded
    c = container.read(out)
    assert c.version == (1, 4) and "views" not in c.header["side_info"]
    assert [ch.type for ch in c.chunks].count("SIDE") == 1 and c.find("RESI", 0) is None
    views, images = side_of(c)
    assert len(views) == 2  # 40% of 5 views
    assert rep.bytes["file"] == out.stat().st_size
    assert len(images) == sum(v.residual is not None for v in views) == rep.num_views_with_residual
    assert rep.num_views == len(views) and rep.side_info is None  # check_iterations=0: no check
    assert len(images) >= 1


def as_format_1_0(c: container.Container) -> tuple[dict, list[container.Chunk]]:
    """The same side information in format 1.0's layout: records in the header, one RESI chunk per view."""
    views, images = side_of(c)
    header = {**c.header, "side_info": {**c.header["side_info"], "views": [v.to_dict() for v in views]}}
    chunks = [ch for ch in c.chunks if ch.type != "SIDE"]
    chunks += [container.Chunk("RESI", images[k], index=k) for k in sorted(images)]
    return header, chunks


def test_format_1_0_side_information_decodes_the_same(encoded, tmp_path):
    _, out, _ = encoded
    header, chunks = as_format_1_0(container.read(out))
    old = tmp_path / "old.gspc"
    container.write(old, header, chunks)
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    decode(out, a, DecodeOptions(iterations=3))
    decode(old, b, DecodeOptions(iterations=3))
    assert np.array_equal(read_scene(a).means.numpy(), read_scene(b).means.numpy())
    mixed = tmp_path / "mixed.gspc"
    container.write(mixed, header, chunks + [container.read(out).find("SIDE", 0)])
    with pytest.raises(CodecError, match="both"):
        decode(mixed, tmp_path / "m.ply")
    assert not (tmp_path / "m.ply").exists()


def test_decoded_ply_is_inria_layout(encoded, tmp_path):
    _, out, _ = encoded
    dst = tmp_path / "d.ply"
    decode(out, dst, DecodeOptions(iterations=3))
    ply = plyfile.PlyData.read(str(dst))
    names = [p.name for p in ply["vertex"].properties]
    k = 3 * ((2 + 1) ** 2 - 1)
    expected = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    expected += [f"f_rest_{i}" for i in range(k)] + ["opacity", "scale_0", "scale_1", "scale_2"]
    expected += ["rot_0", "rot_1", "rot_2", "rot_3"]
    assert names == expected
    assert read_scene(dst).num_gaussians == ply["vertex"].count


def test_refinement_changes_scene_only_with_side_info(encoded, tmp_path):
    _, out, _ = encoded
    plain, refined, norestore = tmp_path / "p.ply", tmp_path / "r.ply", tmp_path / "n.ply"
    decode(out, plain, DecodeOptions(refine=False))
    rep = decode(out, refined, DecodeOptions(iterations=5))
    assert "refine" in rep.seconds
    a, b = read_scene(plain), read_scene(refined)
    assert not np.array_equal(a.sh_dc.numpy(), b.sh_dc.numpy())
    rep = decode(out, norestore, DecodeOptions(iterations=5, restore=False))
    assert "refine" not in rep.seconds and rep.refine_iterations == 0
    assert np.array_equal(read_scene(norestore).sh_dc.numpy(), a.sh_dc.numpy())


def test_residual_without_record_is_refused(encoded, tmp_path):
    _, out, _ = encoded
    header, chunks = as_format_1_0(container.read(out))
    views = header["side_info"]["views"]
    k = next(i for i, v in enumerate(views) if "residual" in v)
    del views[k]["residual"]
    bad = tmp_path / "bad.gspc"
    container.write(bad, header, chunks)
    dst = tmp_path / "o.ply"
    with pytest.raises(CodecError, match=f"view {k}"):
        decode(bad, dst)
    assert not dst.exists()


@pytest.mark.slow
def test_encoder_check_keeps_side_info_only_if_refinement_pays(tmp_path):
    src = tmp_path / "in.ply"
    write_ply(coarse_residual_scene(seed=4), src)
    out = tmp_path / "c.gspc"
    rep = encode(src, out, opts=EncodeOptions(lam=40, synth_views=6, max_side=40, check_iterations=20))
    d = rep.side_info
    c = container.read(out)
    views, images = side_of(c)
    assert c.header["side_info"]["refine_iterations"] == 20
    # Two resolutions weighed (the preset's 1/2 and 1/4), one refined.
    assert [cand.scale for cand in d.candidates] == [2, 4] and d.scale in (2, 4)
    assert all(cand.payload_bytes > 0 and cand.render_gain_db is not None for cand in d.candidates)
    if d.refined_db >= max(d.coded_db, d.best_rival_db) + EncodeOptions().check_margin_db:
        assert d.outcome is Outcome.SENT and len(images) >= 1
        assert all(v.residual.scale == d.scale for v in views if v.residual is not None)
    else:
        assert d.outcome in (Outcome.SPENT_ON_ATTRIBUTES, Outcome.DROPPED)
        assert not images and not views and c.find("SIDE", 0) is None


@pytest.mark.slow
def test_long_check_scores_a_trial_first(tmp_path):
    src = tmp_path / "in.ply"
    write_ply(coarse_residual_scene(seed=5), src)
    out = tmp_path / "c.gspc"
    opts = EncodeOptions(lam=40, synth_views=5, max_side=32, check_iterations=400)
    rep = encode(src, out, opts=opts)
    d = rep.side_info
    assert d is not None and container.read(out).header["side_info"]["refine_iterations"] == 400
    assert d.trial_iterations == CheckPolicy().trial_length(400) < 400
    bar = max(d.coded_db, d.best_rival_db) + opts.check_margin_db
    if d.predicted:  # sent on the trial's score, which settled it
        assert d.outcome is Outcome.SENT
        assert trial_settles(d.refined_db - d.coded_db, bar - d.coded_db, CheckPolicy().gain_ratio)
    else:  # the whole run decided
        assert (d.outcome is Outcome.SENT) == (d.refined_db >= bar)


def test_decoder_refines_inside_the_quantisation_cells(encoded, tmp_path):
    from gspc.codec.attributes import decode_attributes, decoded_precision
    from gspc.codec.cells import quantisation_cells

    _, out, _ = encoded
    c = container.read(out)
    section = AttributeSection.from_dict(c.header["attributes"])
    chunks = {ch.type: ch.payload for ch in c.chunks}
    coded = decode_attributes(chunks, section)
    cells = quantisation_cells(coded, section, decoded_precision(chunks, section))
    inside, free = tmp_path / "a.ply", tmp_path / "b.ply"
    # Two side-information views see each Gaussian at most twice, where the decoder's rates shrink to a
    # 64th or less (gspc/reconstruct.py, COVERAGE_FULL), and 5 iterations of a schedule made for hundreds
    # start slow: x1000 gives steps large enough to leave cells (x16 at an eighth moved positions by 1e-8).
    rep = decode(out, inside, DecodeOptions(iterations=5, lr_scale=1000))
    assert rep.refine_iterations == 5
    decode(out, free, DecodeOptions(iterations=5, in_cells=False, lr_scale=1000))
    a, b = read_scene(inside), read_scene(free)
    for name in ("means", "log_scales", "sh_dc"):
        lo, hi = cells[name]
        assert ((getattr(a, name) >= lo - 1e-6) & (getattr(a, name) <= hi + 1e-6)).all(), name
    assert not torch.equal(a.means, b.means)


@pytest.mark.parametrize("value", [-1, 2.5, "many", True])
def test_bad_refine_iterations_are_refused(encoded, tmp_path, value):
    _, out, _ = encoded
    c = container.read(out)
    bad = tmp_path / "bad.gspc"
    side = {**c.header["side_info"], "refine_iterations": value}
    container.write(bad, {**c.header, "side_info": side}, c.chunks)
    dst = tmp_path / "o.ply"
    with pytest.raises(CodecError, match="refine_iterations"):
        decode(bad, dst)
    assert not dst.exists()


def test_memory_api_matches_the_path_api(encoded, tmp_path):
    src, out, rep = encoded
    opts = EncodeOptions(lam=40, synth_views=5, max_side=40, check_iterations=0)
    data, mem = encode_scene(read_scene(src), None, opts)
    assert data == out.read_bytes() and mem.bytes == rep.bytes and mem.num_views == rep.num_views
    scene, drep = decode_bytes(data, DecodeOptions(iterations=3))
    dst = tmp_path / "d.ply"
    decode(out, dst, DecodeOptions(iterations=3))
    assert torch.equal(read_scene(dst).sh_dc, scene.sh_dc) and drep.refine_iterations == 3


def test_decode_time_budget_shortens_refinement(encoded, tmp_path):
    _, out, _ = encoded
    rep = decode(out, tmp_path / "b.ply", DecodeOptions(iterations=40, time_budget=1e-6))
    assert rep.refine_iterations < 40 and "time budget" in rep.info["refine"]
    rep = decode(out, tmp_path / "f.ply", DecodeOptions(iterations=4, time_budget=3600))
    assert rep.refine_iterations == 4 and rep.info["refine"] == "4 iterations"


@pytest.mark.parametrize("value", [0, -5, float("nan"), float("inf"), "soon"])
def test_bad_time_budgets_are_refused(encoded, tmp_path, value):
    src, out, _ = encoded
    with pytest.raises(InputError, match="--time-budget"):
        decode(out, tmp_path / "x.ply", DecodeOptions(time_budget=value))
    with pytest.raises(InputError, match="--time-budget"):
        encode(src, tmp_path / "x.gspc", opts=EncodeOptions(time_budget=value))
    assert not (tmp_path / "x.ply").exists() and not (tmp_path / "x.gspc").exists()


@pytest.mark.slow
def test_encode_time_budget_writes_the_iterations_it_checked(tmp_path):
    src = tmp_path / "in.ply"
    write_ply(coarse_residual_scene(seed=4), src)
    out = tmp_path / "c.gspc"
    opts = EncodeOptions(lam=40, synth_views=6, max_side=40, check_iterations=400, time_budget=1e-6)
    rep = encode(src, out, opts=opts)
    d = rep.side_info
    assert d is not None and d.iterations < 400
    written = container.read(out).header["side_info"]["refine_iterations"]
    assert written == (d.iterations if d.outcome is Outcome.SENT else 400)


def test_encode_time_budget_bounds_the_search_for_a_file_without_side_information(tmp_path):
    """A file without side information re-codes its attributes for decoding as they are (a search of up to
    12 encodes); with the budget spent it keeps the coding it has instead."""
    src = tmp_path / "in.ply"
    write_ply(coarse_residual_scene(seed=4), src)
    base = dict(lam=40, synth_views=6, max_side=40, side_info=False)
    free = encode(src, tmp_path / "a.gspc", opts=EncodeOptions(**base))
    assert "attributes for no side information" in free.seconds
    spent = encode(src, tmp_path / "b.gspc", opts=EncodeOptions(**base, time_budget=1e-6))
    assert "attributes for no side information" not in spent.seconds
    assert (tmp_path / "b.gspc").stat().st_size <= (tmp_path / "a.gspc").stat().st_size * 1.02


def test_bytes_spent_on_attributes_are_the_rivals(tmp_path):
    """A margin side information cannot meet: the file holds the rival's finer attributes."""
    from gspc.codec.attributes import decode_attributes
    from gspc.format.attribute_section import attribute_chunks

    src = tmp_path / "in.ply"
    write_ply(coarse_residual_scene(seed=2), src)
    out = tmp_path / "c.gspc"
    opts = EncodeOptions(lam=40, synth_views=5, max_side=32, check_iterations=20, check_margin_db=90.0)
    rep = encode(src, out, opts=opts)
    assert rep.side_info.outcome is Outcome.SPENT_ON_ATTRIBUTES
    c = container.read(out)
    assert c.find("SIDE", 0) is None
    section = AttributeSection.from_dict(c.header["attributes"])
    decoded = decode_attributes(attribute_chunks(c.chunks), section)
    assert decoded.num_gaussians == rep.num_gaussians_out > 0


@pytest.mark.parametrize("side_info", [False, True])
def test_target_size_bounds_the_whole_file(tmp_path, side_info):
    # --target-size is the file's size at most, side information included (counted inside the target).
    src = tmp_path / "in.ply"
    write_ply(coarse_residual_scene(seed=3), src)
    out = tmp_path / "c.gspc"
    small = dict(synth_views=5, max_side=40, check_iterations=0)
    opts = EncodeOptions(target_size=6000, side_info=side_info, **small)
    rep = encode(src, out, opts=opts)
    size = out.stat().st_size
    assert 0.85 * 6000 <= size <= 6000, size
    assert rep.bytes["file"] == size and "6,000 B target" in rep.info["lambda"], rep.info["lambda"]
    assert ("SIDE" in rep.bytes) == rep.info["side info"].startswith("sent"), rep.info["side info"]


def test_a_target_size_no_coding_reaches_is_refused_in_one_line(tmp_path):
    src = tmp_path / "in.ply"
    write_ply(random_scene(3000, sh_degree=0, seed=2), src)
    out = tmp_path / "c.gspc"
    with pytest.raises(InputError, match="--target-size 1,024 B cannot be reached"):
        encode(src, out, opts=EncodeOptions(target_size=1024, side_info=False, synth_views=4, max_side=32))
    assert not out.exists()


def test_the_encoder_reports_the_removal_it_chose_and_can_be_told_to_keep_the_presets(tmp_path):
    # gspc/encoder/removal.py: at the low preset's lambda the encoder's cameras weigh stronger removals and
    # the report says what they found; --no-removal-search codes the preset's removal without weighing.
    src = tmp_path / "in.ply"
    write_ply(coarse_residual_scene(seed=5), src)
    base = dict(synth_views=4, max_side=40, side_info=False)
    searched = encode(src, tmp_path / "a.gspc", opts=EncodeOptions(**base))
    said = searched.info["removal"]
    assert "at 4 views between the encoder's cameras" in said and "(x2 at lambda" in said, said
    kept = encode(src, tmp_path / "b.gspc", opts=EncodeOptions(**base, removal_search=False))
    assert "removal" not in kept.info
    # The preset's removal kept: the very file the unsearched encode writes; a stronger one: another file.
    same = (tmp_path / "a.gspc").read_bytes() == (tmp_path / "b.gspc").read_bytes()
    assert same == said.startswith("the preset's removal and grid: no trial gained"), said


def test_the_high_preset_weighs_a_finer_position_grid_and_no_removal(tmp_path):
    # gspc/presets.py: the high preset removes nothing, so its search is the grid alone, a bit finer.
    src = tmp_path / "in.ply"
    write_ply(coarse_residual_scene(seed=5), src)
    rep = encode(src, tmp_path / "h.gspc", opts=EncodeOptions(quality="high", synth_views=4, max_side=40))
    said = rep.info["removal"]
    assert "positions +1 bit at lambda" in said and " x2 " not in said, said


def test_the_encoder_tunes_its_coded_values_unless_told_not_to(encoded, tmp_path):
    # gspc/encoder/tuning.py: on by default for a file without side information (the report says what it
    # did), off with --tune-iterations 0; both files decode the same Gaussians. A file whose side information
    # the decoder refines against is not tuned.
    assert "tuning" not in encoded[2].info
    src = tmp_path / "in.ply"
    write_ply(coarse_residual_scene(seed=6), src)
    base = dict(synth_views=4, max_side=40, side_info=False)
    tuned = encode(src, tmp_path / "a.gspc", opts=EncodeOptions(**base))
    assert "4 iterations at" in tuned.info["tuning"], tuned.info["tuning"]
    plain = encode(src, tmp_path / "b.gspc", opts=EncodeOptions(**base, tune_iterations=0))
    assert "tuning" not in plain.info
    a, b = decode(tmp_path / "a.gspc", tmp_path / "a.ply"), decode(tmp_path / "b.gspc", tmp_path / "b.ply")
    assert a.num_gaussians_out == b.num_gaussians_out == tuned.num_gaussians_out


@pytest.mark.parametrize("value", [-1, 1001, 2.5, "4"])
def test_bad_tune_iterations_are_refused(tmp_path, value):
    with pytest.raises(InputError, match="--tune-iterations"):
        encode(tmp_path / "in.ply", tmp_path / "x.gspc", opts=EncodeOptions(tune_iterations=value))


def test_a_target_that_sends_no_side_information_spends_it_on_attributes(tmp_path):
    # gspc/encoder/side_decision.py: the attributes are coded again in what side information would leave;
    # where the check then drops it (refinement did not improve the views), the file is the attributes in
    # the whole target, as --no-side-info codes them, not in what the dropped residuals left.
    src, out, alone = tmp_path / "in.ply", tmp_path / "o.gspc", tmp_path / "a.gspc"
    write_ply(random_scene(3000, sh_degree=1, seed=11), src)
    small = dict(synth_views=8, max_side=32, tune_iterations=0, check_iterations=20, target_size=12000)
    rep = encode(src, out, opts=EncodeOptions(**small))
    assert rep.info["side info"].startswith("none: refinement did not improve"), rep.info["side info"]
    encode(src, alone, opts=EncodeOptions(**small, side_info=False))
    assert out.stat().st_size >= 0.99 * alone.stat().st_size, rep.info["side info"]
