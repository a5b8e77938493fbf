"""The side-information check's rules that need no scene: where it scores a trial, what a trial settles."""

import pytest

from gspc.encoder.policy import CheckPolicy, trial_verdict


def test_trial_length():
    p = CheckPolicy(trial_from=100, trial_fraction=0.25)
    assert p.trial_length(20) == 20  # a short run is run whole: its score is exact
    assert p.trial_length(99) == 99
    assert p.trial_length(100) == 25
    assert p.trial_length(301) == 76


@pytest.mark.parametrize(
    ("gain", "needed", "verdict"),
    [
        (1.0, 0.8, True),  # even the lowest ratio clears the bar
        (0.3, 0.8, None),  # between: the run goes on
        (0.2, 0.8, False),  # even the highest ratio falls short
        (-0.1, -0.5, False),  # the trial made the coded scene worse
        (0.0, 0.1, False),
        (0.4, 0.8, True),
    ],
)
def test_trial_verdict(gain, needed, verdict):
    assert trial_verdict(gain, needed, (2.0, 3.0)) is verdict


def test_policy_is_frozen():
    with pytest.raises(AttributeError):
        CheckPolicy().trial_fraction = 0.5  # type: ignore[misc]
