"""The side-information check's rules that need no scene: where it scores a trial, when a trial settles it."""

import pytest

from gspc.encoder.policy import CheckPolicy, trial_settles


def test_trial_length():
    p = CheckPolicy(trial_from=100, trial_fraction=0.25)
    assert p.trial_length(20) == 20  # a short run is run whole: its score is exact
    assert p.trial_length(99) == 99
    assert p.trial_length(100) == 25
    assert p.trial_length(301) == 76


@pytest.mark.parametrize(
    ("gain", "needed", "ratio", "settles"),
    [
        (1.0, 0.8, 1.0, True),  # the trial already clears the bar
        (0.8, 0.8, 1.0, True),
        (0.3, 0.8, 1.0, False),  # it does not: the run goes on
        (0.3, 0.5, 2.0, True),  # predicted at twice the trial's gain
        (-0.1, -0.5, 1.0, False),  # a trial that made the coded scene worse settles nothing
        (0.0, 0.0, 1.0, False),
    ],
)
def test_trial_settles(gain, needed, ratio, settles):
    assert trial_settles(gain, needed, ratio) is settles


def test_policy_is_frozen():
    with pytest.raises(AttributeError):
        CheckPolicy().trial_fraction = 0.5  # type: ignore[misc]


def test_each_part_of_the_checks_run_is_its_own_stage():
    """The trial and the rest of the run report as two stages, each counting from 0 and closing at its end
    (a trial that settles the check leaves no stage open); a deadline that shortens the run shortens it."""
    from gspc.encoder.policy import _stage_report

    calls = []
    report = _stage_report(lambda *a: calls.append(a), "rest", 75, 300)
    report(76, 300, 0.0)
    report(200, 250, 0.0)  # the run was cut to 250
    assert calls == [("rest", 0, 225), ("rest", 1, 225), ("rest", 125, 175)]
    assert _stage_report(None, "rest", 0, 10) is None


def test_log_linear_reads_a_value_between_two_codings_in_log_bytes():
    from gspc.encoder.policy import _log_linear

    assert _log_linear((1000, 30.0), (4000, 34.0), 2000) == pytest.approx(32.0)  # halfway in log bytes
    assert _log_linear((1000, 30.0), (4000, 34.0), 1000) == 30.0
    assert _log_linear((1000, 30.0), (1000, 31.0), 1000) == 30.0  # one coding: its own value


def _rival_inputs(shares: list[float]):
    """CheckInputs enough for the rivals: a small scene coded at the low preset, views to score at, and
    candidates whose side information weighs ``shares`` of the attributes' bytes."""
    from dataclasses import replace

    from scenes import random_scene

    from gspc.encoder.coding import encode_attributes
    from gspc.encoder.policy import CheckInputs
    from gspc.encoder.side import SideCandidate
    from gspc.encoder.significance import encoder_significance
    from gspc.presets import quality_preset
    from gspc.views import synthesize_views

    scene = random_scene(2000, sh_degree=1, seed=11, log_scale=-3.5)
    cams = synthesize_views(scene, 6, width=48, height=48)
    params = replace(quality_preset("low").attributes, lam=4.0)
    sig = encoder_significance(scene, cams)
    enc = encode_attributes(scene, params, significance=sig)
    cands = [SideCandidate(2 * (k + 1), [], {}, bytes(int(f * enc.num_bytes))) for k, f in enumerate(shares)]
    return CheckInputs(
        scene=scene,
        attributes=enc,
        params=params.unrefined(),
        visible=None,
        significance=sig,
        view_cameras=[],
        check_cameras=cams[:3],
        original=[],
        coded=[],
        candidates=cands,
        restorer=None,
        iterations=0,
        background=(0.0, 0.0, 0.0),
        margin_db=0.15,
    )


def test_the_rivals_are_read_off_two_codings_and_agree_with_each_ones_own_search(monkeypatch):
    # Two candidates' rivals from one bracket: fewer codings than a search per candidate, and each close to
    # the PSNR its own search to the policy's tolerance reaches (the check's comparison before). So small a
    # scene's PSNR is jagged in its bytes (0.15 dB between codings 0.1% apart here); the bird's and the 1M
    # scene's checks compare in bench/speed.md.
    import gspc.encoder.rate as rate
    from gspc.encoder import policy
    from gspc.metrics import mean_psnr
    from gspc.reconstruct import render_images

    inp = _rival_inputs([0.03, 0.012])
    reference = render_images(inp.scene, inp.check_cameras, inp.background)

    def score(s):
        return mean_psnr(render_images(s, inp.check_cameras, inp.background), reference)

    codings = []
    encode = rate.encode_attributes

    def counted(*a, **k):
        codings.append(1)
        return encode(*a, **k)

    monkeypatch.setattr(rate, "encode_attributes", counted)
    before = score(inp.attributes.decoded)
    read = policy._rivals(inp, score, None, before)
    bracket = len(codings)
    codings.clear()
    own = [policy._rival_coding(inp, policy._rival_target(inp, c)) for c in inp.candidates]
    assert bracket < len(codings)
    for r, o, c in zip(read, own, inp.candidates):
        assert o.num_bytes <= policy._rival_target(inp, c)
        assert abs(r - score(o.decoded)) < 0.3, (r, score(o.decoded))


def test_a_rival_searched_past_the_deadline_starts_no_second_coding(monkeypatch):
    # The rival a file holds ("spent on attributes") is searched after the check's refinement: past the
    # time budget's deadline its search stops where it starts.
    import time

    import gspc.encoder.rate as rate
    from gspc.encoder import policy

    inp = _rival_inputs([0.05])
    codings = []
    encode = rate.encode_attributes
    monkeypatch.setattr(rate, "encode_attributes", lambda *a, **k: codings.append(1) or encode(*a, **k))
    target = policy._rival_target(inp, inp.candidates[0])
    policy._rival_coding(inp, target, deadline=time.perf_counter() - 1.0)
    late = len(codings)
    assert late <= 1  # the search's start (the file's own coding where the parameters agree, else one)
    codings.clear()
    policy._rival_coding(inp, target)
    assert len(codings) > late  # without a deadline the same search goes on


class _Scored:
    """A stand-in for a scene or its render: the check's score reads ``db`` (patched below)."""

    def __init__(self, db: float) -> None:
        self.db = db

    def to(self, device):
        return self


class _Coding:
    def __init__(self, db: float, num_bytes: int = 1000) -> None:
        self.decoded, self.num_bytes = _Scored(db), num_bytes
        self.section = self.precision = None
        self.lam = 4.0


class _Run:
    def __init__(self, refined_db: float, total: int) -> None:
        self.refined, self.done, self.total = refined_db, 0, total

    def run(self, count, deadline, report):
        self.done = self.total if count is None else min(self.total, self.done + count)

    def scene(self):
        return _Scored(self.refined)


def _scored_check(monkeypatch, refined_db: float, tuned_db: float | None):
    """check_side_info on stand-ins: coded 40 dB, the untuned rival 40.5 dB, the refinement ``refined_db``,
    the rival tuned ``tuned_db`` (None: no tuning asked); what the check decided and what tune was asked."""
    from gspc.encoder import policy
    from gspc.encoder.policy import CheckInputs
    from gspc.encoder.side import SideCandidate

    monkeypatch.setattr(policy, "render_images", lambda s, *a, **k: s)
    monkeypatch.setattr(policy, "mean_psnr", lambda images, reference, capped=False: images.db)
    monkeypatch.setattr(policy, "_rivals", lambda inp, score, progress, before: [40.5])
    monkeypatch.setattr(policy, "restored_targets", lambda *a: None)
    monkeypatch.setattr(policy, "decoder_refinement", lambda *a, **k: _Run(refined_db, 10))
    monkeypatch.setattr(policy, "_rival_coding", lambda inp, target, *a, **k: _Coding(40.5, target))
    asked = []

    def tune(enc, limit):
        asked.append((enc.num_bytes, limit))
        return _Coding(tuned_db, enc.num_bytes), "its report"

    inp = CheckInputs(
        scene=_Scored(99.0),
        attributes=_Coding(40.0),
        params=None,
        visible=None,
        significance=None,
        view_cameras=[],
        check_cameras=[None] * 8,
        original=[],
        coded=[],
        candidates=[SideCandidate(2, [], {}, bytes(200))],
        restorer=None,
        iterations=10,
        background=(0.0, 0.0, 0.0),
        margin_db=0.15,
        tune=None if tuned_db is None else tune,
    )
    return policy.check_side_info(inp), asked


def test_side_information_must_beat_the_rival_the_encoder_would_tune(monkeypatch):
    # The refinement (41.0 dB) beats the untuned rival (40.5) by the margin, not the rival tuned (41.2): the
    # tuned rival is the file, tuned once, in the side information's bytes and the file's attributes'.
    from gspc.encoder.policy import Outcome

    result, asked = _scored_check(monkeypatch, 41.0, 41.2)
    d = result.decision
    assert d.outcome is Outcome.SPENT_ON_ATTRIBUTES and result.side is None
    assert d.rival_db == 40.5 and d.tuned_rival_db == 41.2
    assert result.attributes.decoded.db == 41.2 and result.tuning == "its report"
    target = 1000 + 200 + CheckPolicy().chunk_entry_bytes  # the attributes, the payload, its chunk
    assert asked == [(target, target)]
    assert "41.20 dB tuned" in d.summary()["check"]


def test_side_information_that_beats_the_tuned_rival_is_sent(monkeypatch):
    from gspc.encoder.policy import Outcome

    result, asked = _scored_check(monkeypatch, 41.0, 40.7)
    assert result.decision.outcome is Outcome.SENT and result.side is not None
    assert result.decision.tuned_rival_db == 40.7 and len(asked) == 1
    assert result.tuning is None


def test_without_tuning_the_check_compares_the_untuned_rival_alone(monkeypatch):
    from gspc.encoder.policy import Outcome

    result, asked = _scored_check(monkeypatch, 41.0, None)
    assert result.decision.outcome is Outcome.SENT and result.decision.tuned_rival_db is None
    # A refinement that loses to the untuned rival never asks for the tuned one.
    result, asked = _scored_check(monkeypatch, 40.55, 45.0)
    assert result.decision.outcome is Outcome.SPENT_ON_ATTRIBUTES and asked == []
    assert result.decision.tuned_rival_db is None
