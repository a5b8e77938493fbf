"""The encoder's decisions as one typed record (gspc/encoder/decisions.py), what a run's summary says of
them, and the decoder's stage list (gspc/pipeline.py): what runs, what is read once, what is named."""

import os
import subprocess
import sys
from dataclasses import replace

import pytest
from cli_runs import run
from scenes import random_scene

import gspc.format.container as container_module
import gspc.pipeline as pipeline
from gspc.codec import attributes as codec_attributes
from gspc.encoder.decisions import GaussianCounts
from gspc.encoder.policy import CandidateScore, Outcome, SideInfoDecision
from gspc.encoder.removal import RemovalChoice, Trial
from gspc.io import write_ply
from gspc.options import DecodeOptions, EncodeOptions
from gspc.pipeline import decode_bytes, encode_scene


def small(**kw) -> EncodeOptions:
    return EncodeOptions(synth_views=4, max_side=40, **kw)


def coarse(**kw) -> EncodeOptions:
    """A coarse rate, so that residuals are sent (and checked where the check has iterations)."""
    return EncodeOptions(lam=40, synth_views=5, max_side=40, **kw)


def scene(seed=1):
    return random_scene(
        200, sh_degree=2, seed=seed, log_scale=-2.8, opacity_logit=1.5, dc_std=0.6, rest_std=0.2
    )


def test_counts_say_where_the_gaussians_went():
    assert GaussianCounts(100, 0, 0, 100).summary() == "100 given, all coded"
    said = GaussianCounts(1000, 20, 180, 800).summary()
    assert said.startswith("1,000 given, 800 coded: 20 not coded") and "180 removed" in said


def test_the_removal_line_says_why_the_kept_trial_won():
    base = Trial(0.035, 8.0, 1000, 40.0)
    won = Trial(0.07, 7.0, 998, 40.5)
    lost = Trial(0.14, 6.2, 999, 40.55)  # within the margin of the one kept: not taken
    choice = RemovalChoice(_Coded(7.0), _params(0.07), base, (won, lost), 16, 1.0, 0.1)
    said = choice.summary()
    assert said.startswith("x2 the preset's removal: +0.50 dB over the preset's at 16 views"), said
    assert "x4 at lambda 6.2 +0.55 dB" in said
    kept = RemovalChoice(_Coded(8.0), _params(0.035), base, (Trial(0.07, 7.0, 1000, 40.05),), 16, 1.0, 0.1)
    assert kept.summary().startswith("the preset's removal and grid: no trial gained 0.1 dB over it")


class _Coded:
    def __init__(self, lam):
        self.lam = lam


def _params(prune):
    from dataclasses import replace

    from gspc.presets import quality_preset

    p = quality_preset("low").attributes
    return replace(p, precision=replace(p.precision, prune=prune))


def test_a_file_without_side_information_says_why(tmp_path):
    _, rep = encode_scene(scene(), opts=small(side_info=False))
    assert rep.info["side info"] == "none (--no-side-info)"
    assert rep.info["decoder refines"] == "nothing (no side information)"
    assert rep.decisions.side is None and rep.decisions.counts.coded == rep.num_gaussians_out


def test_side_information_sent_unchecked_says_so():
    _, rep = encode_scene(scene(), opts=coarse(check_iterations=0))
    assert rep.info["side info"].startswith("sent (unchecked, --check-iterations 0): "), rep.info["side info"]


def test_the_side_information_line_gives_the_checks_figures():
    d = SideInfoDecision(
        Outcome.SPENT_ON_ATTRIBUTES,
        2,
        8,
        40.0,
        40.3,
        41.0,
        25,
        False,
        100,
        (CandidateScore(2, 1000, None, 41.0),),
    )
    from gspc.encoder.side_decision import _not_sent

    said = _not_sent(d)
    assert "41.00 dB at 8 views carrying none against 40.30 dB refined with it" in said


def test_a_lambda_the_encoder_moved_is_explained():
    _, rep = encode_scene(scene(seed=5), opts=small(side_info=False, lam=8.0))  # at the rate
    line = rep.info["lambda"]
    if rep.decisions.lambda_reasons:
        assert "asked (it sets the bytes), coded at" in line, line
    else:
        assert line == f"{rep.decisions.attributes.lam:.4g}"


def test_decoding_without_refinement_renders_and_restores_nothing(monkeypatch):
    data, _ = encode_scene(scene(), opts=coarse(check_iterations=0))

    def forbidden(*a, **k):
        raise AssertionError("a decode that does not refine rendered or restored")

    monkeypatch.setattr(pipeline, "reconstruct", forbidden)
    monkeypatch.setattr(pipeline, "load_restorer", forbidden)
    for opts in (DecodeOptions(refine=False), DecodeOptions(iterations=0), DecodeOptions(restore=False)):
        _, rep = decode_bytes(data, opts)
        assert rep.info["refine"].startswith("none (") and "restorer" not in rep.info
        assert "render" not in rep.seconds and "restore" not in rep.seconds


def test_a_file_is_parsed_once_and_its_precision_map_decoded_once(monkeypatch):
    data, _ = encode_scene(scene(), opts=coarse(check_iterations=0))
    calls = {"unpack": 0, "prec": 0}
    unpack, prec = container_module.unpack, codec_attributes.decode_precision

    def counted_unpack(*a, **k):
        calls["unpack"] += 1
        return unpack(*a, **k)

    def counted_prec(*a, **k):
        calls["prec"] += 1
        return prec(*a, **k)

    monkeypatch.setattr(container_module, "unpack", counted_unpack)
    monkeypatch.setattr(codec_attributes, "decode_precision", counted_prec)
    _, rep = decode_bytes(data, DecodeOptions(iterations=2))
    assert calls == {"unpack": 1, "prec": 1} and rep.refine_iterations == 2
    assert rep.bytes["file"] == len(data) and sum(v for k, v in rep.bytes.items() if k != "file") == len(data)


def test_the_summary_divides_bytes_by_the_gaussians_given_and_coded(tmp_path):
    src, out = tmp_path / "in.ply", tmp_path / "s.gspc"
    sc = random_scene(400, sh_degree=0, seed=3)
    sc.opacities[:100] = -9.0  # under 1/255 opaque: not coded
    write_ply(sc, src)
    res = run("encode", src, "-o", out, "--views", 4, "--max-side", 32, "--no-side-info")
    assert res.exit_code == 0, res.output
    assert "B/Gaussian given" in res.output and "B/Gaussian coded" in res.output
    assert "Gaussians: 400 given" in res.output and "100 not coded" in res.output


def test_ctrl_c_exits_130(tmp_path, monkeypatch):
    src = tmp_path / "in.ply"
    write_ply(random_scene(50, sh_degree=0), src)

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(pipeline, "encode", interrupted)
    res = run("encode", src, "-o", tmp_path / "o.gspc")
    assert res.exit_code == 130 and "interrupted" in res.output
    assert not (tmp_path / "o.gspc").exists()


@pytest.mark.slow
def test_a_machine_without_compiled_kernels_is_told_so(tmp_path):
    # numba's cache in an empty folder: every kernel is uncompiled there (gspc/jit.py), which a run reports
    # as a stage of its own before it waits.
    code = "from gspc.jit import uncompiled_kernels; print(len(uncompiled_kernels()))"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert int(out.stdout) > 0


def test_a_target_fidelity_is_reached_in_the_fewest_bytes_and_reported():
    # gspc/encoder/fidelity.py: --target-psnr searches lambda for the coding that reaches it at views
    # between the encoder's cameras; the summary and the file's header say what the file reaches there.
    from gspc.format.file import read_file

    s = scene(seed=3)
    close, rep = encode_scene(s, opts=small(side_info=False, target_psnr=48.0))
    far, rep2 = encode_scene(s, opts=small(side_info=False, target_psnr=38.0))
    assert len(far) < len(close)
    reached = read_file(close).header.scene.psnr_db
    assert reached >= 48.0 - 0.05 and rep.info["fidelity"].startswith(f"{reached:.2f} dB"), rep.info
    assert "searched for the 38 dB target" in rep2.info["lambda"]


def test_a_fidelity_no_lambda_reaches_is_refused_in_one_line():
    from gspc.errors import InputError

    with pytest.raises(InputError, match="--target-psnr 119 dB cannot be reached"):
        encode_scene(scene(), opts=small(side_info=False, target_psnr=119.0))
    with pytest.raises(InputError, match="--target-psnr"):
        EncodeOptions(target_psnr=5.0).validate()


def test_a_preset_aims_at_its_fidelity_and_lambda_codes_at_the_rate():
    # gspc/presets.py: each preset names a fidelity its attributes are searched for; --lambda and
    # --target-size name the rate instead, and the preset's search does not run.
    from gspc.encoder.prepare import fidelity_params
    from gspc.presets import QUALITY

    for name, preset in QUALITY.items():
        fp = fidelity_params(EncodeOptions(quality=name))
        assert fp.target_db == preset.target_db and fp.max_bytes_per_gaussian == preset.max_bytes_per_gaussian
    assert [QUALITY[q].target_db for q in ("low", "medium", "high")] == sorted(
        QUALITY[q].target_db for q in ("low", "medium", "high")
    )
    assert fidelity_params(EncodeOptions(lam=8.0)) is None
    assert fidelity_params(EncodeOptions(target_size=100_000)) is None
    assert fidelity_params(EncodeOptions(target_psnr=40.0)).max_bytes_per_gaussian is None
    _, rep = encode_scene(scene(seed=3), opts=small(side_info=False))
    assert f"searched for the {QUALITY['low'].target_db:g} dB target" in rep.info["lambda"], rep.info
    _, at_rate = encode_scene(scene(seed=3), opts=small(side_info=False, lam=8.0))
    assert "fidelity" not in at_rate.info


def test_a_preset_whose_target_needs_more_than_its_size_says_so_in_one_line():
    # A preset's stated size bounds its search: the closest coding within it is written, and the summary
    # says the target was not reached there (the file's header holds what it reaches).
    from gspc.encoder.fidelity import FidelityParams, code_to_fidelity
    from gspc.encoder.params import CodecParams
    from gspc.format.file import read_file
    from gspc.views import synthesize_views

    s = scene(seed=3)
    cams = synthesize_views(s, 6, 40, 40)
    fp = FidelityParams(119.0, 0.5, max_bytes_per_gaussian=25.0)
    fid = code_to_fidelity(s, CodecParams(lam=8.0), None, None, cams, (0, 0, 0), fp)
    assert fid.encoded.num_bytes <= 25 * s.num_gaussians and not fid.reached
    assert f"not reached within the preset's size, {25 * s.num_gaussians:,} B" in fid.summary()
    # A size no coding fits (the models alone are more): the smallest coding tried, said the same way.
    tight = code_to_fidelity(
        s, CodecParams(lam=8.0), None, None, cams, (0, 0, 0), replace(fp, max_bytes_per_gaussian=1.0)
    )
    assert not tight.reached and "not reached within the preset's size" in tight.summary()
    data, rep = encode_scene(s, opts=small(side_info=False, quality="high"))
    reached = read_file(data).header.scene.psnr_db
    assert rep.info["fidelity"].startswith(f"{reached:.2f} dB at") and "target 56 dB" in rep.info["fidelity"]


def test_a_tuned_coding_past_its_target_is_searched_again_for_fewer_bytes():
    # gspc/encoder/fidelity.py tuned_to_fidelity: tuning lifts the search's coding past the target, so
    # the search runs once more for the target less the tuning's gain, kept where it still reaches it.
    from types import SimpleNamespace as NS

    from gspc.encoder.fidelity import Fidelity, tuned_to_fidelity

    db = {100: 44.2, 110: 45.4, 80: 43.0, 88: 44.1}  # bytes -> PSNR at the search's views

    def coding(n):
        return NS(num_bytes=n, lam=8.0 * 100 / n)

    def tune(enc):
        return coding(enc.num_bytes + 10 if enc.num_bytes == 100 else 88), "report"

    searched = []

    def search(target, lam):
        searched.append(round(target, 2))
        return coding(80)

    fid = Fidelity(coding(100), 44.2, 44.0, 16, 3, 1.0, None, lambda e: db[e.num_bytes])
    enc, report, got = tuned_to_fidelity(fid.encoded, fid, 0.5, tune, search)  # its score known
    assert searched == [42.8] and enc.num_bytes == 88 and got == 44.1
    # Tuning that takes the coding under the target (it tunes at the cameras): the untuned coding is kept.
    fid_low = Fidelity(
        coding(100), 44.2, 44.0, 16, 3, 1.0, None, lambda e: {100: 44.2, 110: 43.8}[e.num_bytes]
    )
    kept = tuned_to_fidelity(coding(100), fid_low, 0.5, lambda e: (coding(110), "report"), search)
    assert kept[0].num_bytes == 100 and kept[1] is None and kept[2] == 44.2
    # Within the band already: no second search.
    near = Fidelity(coding(100), 44.2, 45.0, 16, 3, 1.0, None, lambda e: db[e.num_bytes])
    searched.clear()
    assert tuned_to_fidelity(coding(100), near, 0.5, tune, search)[0].num_bytes == 110 and not searched
