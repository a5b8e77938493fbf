"""The encoder's choice of removal (gspc/encoder/removal.py): the equal-bytes rule, when no search runs, and
that the coding kept is the one its parameters say, in no more bytes than the preset's."""

import math
import time
from dataclasses import replace

import torch
from scenes import random_scene

import gspc.encoder.rate as rate
from gspc.encoder import removal
from gspc.encoder.coding import encode_attributes
from gspc.encoder.params import SHRules
from gspc.encoder.prepare import removal_params
from gspc.encoder.removal import RemovalParams, Trial, better, choose_removal
from gspc.encoder.significance import encoder_significance
from gspc.options import EncodeOptions
from gspc.presets import quality_preset
from gspc.views import synthesize_views


def test_a_trial_is_better_only_in_no_more_bytes_and_past_the_margin():
    best = Trial(0.035, 8.0, 1000, 40.0)
    assert better(best, Trial(0.07, 7.0, 990, 40.2), 1000, 0.1)
    assert not better(best, Trial(0.07, 7.0, 990, 40.05), 1000, 0.1)  # within the views' noise
    assert not better(best, Trial(0.07, 7.0, 1001, 45.0), 1000, 0.1)  # the search missed the bytes


def _small(opacity_logit: float = 1.0, degree: int = 1):
    scene = random_scene(1500, sh_degree=degree, seed=5, log_scale=-3.5, opacity_logit=opacity_logit)
    cams = synthesize_views(scene, 6, width=48, height=48)
    params = replace(quality_preset("low").attributes, lam=4.0)
    sig = encoder_significance(scene, cams)
    first = encode_attributes(scene, params, significance=sig)
    return scene, cams, params, sig, first


def _counting(monkeypatch) -> list[int]:
    codings: list[int] = []
    encode = rate.encode_attributes
    monkeypatch.setattr(rate, "encode_attributes", lambda *a, **k: codings.append(1) or encode(*a, **k))
    return codings


def test_no_search_with_nothing_to_try_or_past_the_deadline(monkeypatch):
    scene, cams, params, sig, first = _small()
    codings = _counting(monkeypatch)
    high = quality_preset("high").attributes  # removes nothing
    grid_kept = RemovalParams(position_offsets=())
    assert choose_removal(scene, first, high, None, sig, cams, (0, 0, 0), grid_kept).base is None
    uniform = replace(params, precision=None)
    assert choose_removal(scene, first, uniform, None, sig, cams, (0, 0, 0)).base is None
    late = choose_removal(scene, first, params, None, sig, cams, (0, 0, 0), deadline=time.perf_counter() - 1)
    assert late.base is None and late.encoded is first and late.params is params
    assert codings == []


def test_a_better_removal_is_kept_with_its_own_parameters_in_no_more_bytes(monkeypatch):
    # The scorer rewards fewer Gaussians (as a capture full of faint ones does): a stronger removal is
    # chosen, coded in at most the preset's bytes, and the coding kept is the one its parameters make.
    scene, cams, params, sig, first = _small()
    monkeypatch.setattr(removal, "scorer", lambda *a: lambda enc: 60.0 - 1e-2 * enc.decoded.num_gaussians)
    choice = choose_removal(scene, first, params, None, sig, cams, (0, 0, 0))
    chosen = choice.params.precision.prune
    assert chosen > params.precision.prune
    assert chosen in [t.prune for t in choice.trials]
    assert choice.encoded.num_bytes <= first.num_bytes
    again = encode_attributes(scene, choice.params, significance=sig)
    assert again.num_bytes == choice.encoded.num_bytes and again.lam == choice.encoded.lam
    assert choice.encoded.decoded.num_gaussians < first.decoded.num_gaussians
    assert "the preset's" in choice.summary()


def test_a_worse_removal_keeps_the_presets_coding(monkeypatch):
    # The scorer punishes every removed Gaussian: the preset's coding stays, after every step is tried.
    scene, cams, params, sig, first = _small()
    monkeypatch.setattr(removal, "scorer", lambda *a: lambda enc: 20.0 + 1e-2 * enc.decoded.num_gaussians)
    rp = RemovalParams(steps=(2, 4, 8), position_offsets=())
    choice = choose_removal(scene, first, params, None, sig, cams, (0, 0, 0), rp)
    assert choice.encoded is first and choice.params is params
    assert len(choice.trials) == 3


def test_a_step_that_loses_does_not_end_the_search(monkeypatch):
    # x2 scores under the preset's coding, x4 1 dB over it, x8 under again: every step is tried, x4 kept.
    scene, cams, params, sig, first = _small()
    scores = iter([40.0, 39.0, 41.0, 39.5])  # the preset's, x2, x4, x8
    monkeypatch.setattr(removal, "scorer", lambda *a: lambda enc: next(scores))
    rp = RemovalParams(steps=(2, 4, 8), position_offsets=())
    choice = choose_removal(scene, first, params, None, sig, cams, (0, 0, 0), rp)
    assert [t.prune for t in choice.trials] == [params.precision.prune * k for k in (2, 4, 8)]
    assert choice.params.precision.prune == params.precision.prune * 4


def _coarser_scores_better(enc) -> float:
    """A scorer that rewards a coarser position grid (as the trained captures' views do) and nothing else."""
    return 40.0 + 10.0 * math.log2(max(enc.section.position.step))


def test_coarser_positions_are_kept_where_they_score_better_in_no_more_bytes(monkeypatch):
    scene, cams, params, sig, first = _small()
    monkeypatch.setattr(removal, "scorer", lambda *a: _coarser_scores_better)
    rp = RemovalParams(steps=(), position_offsets=(-1.0, -2.0))  # positions alone
    choice = choose_removal(scene, first, params, None, sig, cams, (0, 0, 0), rp)
    assert choice.params.position_offset == -2.0 and choice.params.precision.prune == params.precision.prune
    assert [t.position_offset for t in choice.trials] == [-1.0, -2.0]
    assert choice.encoded.num_bytes <= first.num_bytes
    assert max(choice.encoded.section.position.step) > max(first.section.position.step)
    again = encode_attributes(scene, choice.params, significance=sig)  # the coding its parameters make
    assert again.chunks == choice.encoded.chunks
    assert choice.summary().startswith("positions -2 bit: +"), choice.summary()


def test_the_rates_grid_stays_where_coarser_positions_score_worse(monkeypatch):
    scene, cams, params, sig, first = _small()
    monkeypatch.setattr(removal, "scorer", lambda *a: lambda enc: -_coarser_scores_better(enc))
    rp = RemovalParams(steps=(), position_offsets=(-1.0, -2.0))
    choice = choose_removal(scene, first, params, None, sig, cams, (0, 0, 0), rp)
    assert choice.encoded is first and choice.params is params
    assert [t.position_offset for t in choice.trials] == [-1.0]  # the first offset that loses ends it
    assert "positions -1 bit at lambda" in choice.summary()


def test_a_preset_that_removes_nothing_searches_only_the_grid(monkeypatch):
    # The high preset's search: no removal step, the grid a bit finer in no more bytes, kept where the views
    # score it better (here: a scorer that rewards finer voxels).
    scene, cams, _, sig, _ = _small()
    high = replace(quality_preset("high").attributes, lam=2.0)
    first = encode_attributes(scene, high, significance=sig)
    monkeypatch.setattr(removal, "scorer", lambda *a: lambda enc: -_coarser_scores_better(enc))
    rp = RemovalParams(position_offsets=quality_preset("high").position_offsets)
    choice = choose_removal(scene, first, high, None, sig, cams, (0, 0, 0), rp)
    assert [t.position_offset for t in choice.trials] == [1.0]
    assert choice.params.position_offset == 1.0 and choice.params.precision.prune == 0.0
    assert choice.encoded.num_bytes <= first.num_bytes
    assert max(choice.encoded.section.position.step) < max(first.section.position.step)
    assert choice.encoded.decoded.num_gaussians == first.decoded.num_gaussians  # nothing removed
    again = encode_attributes(scene, choice.params, significance=sig)
    assert again.chunks == choice.encoded.chunks


def test_each_preset_names_its_grid_search_and_sh_trials():
    assert removal_params(EncodeOptions(quality="low")).position_offsets == (-1.0,)
    assert removal_params(EncodeOptions(quality="high")).position_offsets == (1.0,)
    # Low tries every SH band of every Gaussian without a dead zone, then the SH rest by codebook; high keeps
    # its rules.
    low = removal_params(EncodeOptions(quality="low")).sh_options
    assert low == (SHRules(0.0, 0.0, 0.0), SHRules(4.0, 0.0, 0.02, 4096))
    assert removal_params(EncodeOptions(quality="high")).sh_options == ()
    assert removal_params(EncodeOptions(quality="high", removal_search=False)) is None


def _sh_kept(enc) -> float:
    """A scorer that rewards every Gaussian the coding keeps view-dependent colour for (as a glossy scene's
    views do)."""
    rest = enc.decoded.sh_rest.reshape(enc.decoded.num_gaussians, -1)
    return 40.0 + 1e-2 * float((rest != 0).any(dim=1).sum())


def test_sh_rules_that_keep_more_are_kept_where_they_score_better_in_no_more_bytes(monkeypatch):
    # Every band, then faint Gaussians' too (most of this scene's are faint): each tried in turn in the
    # preset's bytes, the last kept, and the coding kept is the one its parameters make.
    scene, cams, params, sig, first = _small(opacity_logit=-1.5)
    monkeypatch.setattr(removal, "scorer", lambda *a: _sh_kept)
    bands, faint = SHRules(0.0, 0.0, params.sh_faint_alpha), SHRules(0.0, 0.0, 0.0)
    rp = RemovalParams(steps=(), position_offsets=(), sh_options=(bands, faint))
    choice = choose_removal(scene, first, params, None, sig, cams, (0, 0, 0), rp)
    assert [t.sh for t in choice.trials] == [bands, faint]
    assert choice.params.sh_rules == faint and choice.kept.sh == faint
    assert choice.encoded.num_bytes <= first.num_bytes
    assert again_same(scene, choice, sig)
    assert "faint Gaussians' too" in choice.summary()


def _distinct_sh(enc) -> float:
    """A scorer that rewards fewer distinct SH rests (as a codebook codes them)."""
    rest = enc.decoded.sh_rest.reshape(enc.decoded.num_gaussians, -1)
    return 60.0 - 1e-2 * len(torch.unique(rest, dim=0))


def test_a_codebook_is_kept_where_it_scores_better_and_its_file_says_so(monkeypatch):
    scene, cams, params, sig, first = _small(degree=2)
    monkeypatch.setattr(removal, "scorer", lambda *a: _distinct_sh)
    book = SHRules(params.precision.sh_keep, 0.0, params.sh_faint_alpha, 64)
    rp = RemovalParams(steps=(), position_offsets=(), sh_options=(book,))
    choice = choose_removal(scene, first, params, None, sig, cams, (0, 0, 0), rp)
    assert choice.params.sh_rules == book and choice.kept.sh == book
    assert choice.encoded.section.version == 5 and choice.encoded.section.codebook <= 64
    assert choice.encoded.num_bytes <= first.num_bytes
    assert again_same(scene, choice, sig)
    assert "SH rest by a codebook of up to 64 entries" in choice.summary()


def test_the_presets_sh_rules_stay_where_keeping_more_scores_worse(monkeypatch):
    scene, cams, params, sig, first = _small()
    monkeypatch.setattr(removal, "scorer", lambda *a: lambda enc: 80.0 - _sh_kept(enc))
    rp = RemovalParams(steps=(), position_offsets=(), sh_options=(SHRules(0.0, 0.0, 0.0),))
    choice = choose_removal(scene, first, params, None, sig, cams, (0, 0, 0), rp)
    assert choice.encoded is first and choice.params.sh_rules == params.sh_rules
    assert choice.chosen() == "the preset's removal and grid"


def again_same(scene, choice, sig) -> bool:
    """Whether ``choice``'s parameters code the scene into the coding it kept."""
    return encode_attributes(scene, choice.params, significance=sig).chunks == choice.encoded.chunks
