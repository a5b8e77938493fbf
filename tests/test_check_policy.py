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
