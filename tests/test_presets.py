"""The preset table's rules that depend on the scene: refinement length against the Gaussian count."""

import pytest

from gspc.encoder.prepare import iteration_counts
from gspc.options import EncodeOptions
from gspc.presets import MIN_SCALED_ITERATIONS, QUALITY, REFINE_WORK, refine_iterations_for


@pytest.mark.parametrize(
    ("preset", "n", "expected"),
    [
        (300, 20_000, 300),  # small scenes keep the preset's (every real scene of bench/refine.md)
        (1000, 20_000, 1000),
        (100, 99_999, 100),
        (300, 100_000, 300),
        (300, 300_000, 300),
        (300, REFINE_WORK // 300, 300),
        (300, REFINE_WORK // 300 + 1, 299),
        (300, 778_599, 192),  # the 1M scale scene's coded Gaussians (bench/scale_pipeline.md)
        (300, 1_000_000, 150),
        (1000, 1_000_000, 150),
        (100, 1_000_000, 100),
        (300, 3_000_000, MIN_SCALED_ITERATIONS),
        (300, 6_000_000, MIN_SCALED_ITERATIONS),  # never below the floor
        (30, 1_000_000, 30),  # a preset under the floor is not raised
        (300, 0, 300),
    ],
)
def test_refine_iterations_scale_with_the_scene(preset, n, expected):
    assert refine_iterations_for(preset, n) == expected


def test_explicit_check_iterations_are_not_scaled():
    low = QUALITY["low"].refine_iterations
    assert iteration_counts(EncodeOptions(), 1_000_000).refine == refine_iterations_for(low, 1_000_000)
    runs = iteration_counts(EncodeOptions(check_iterations=700), 1_000_000)
    assert (runs.check, runs.refine) == (700, 700)
    runs = iteration_counts(EncodeOptions(check_iterations=0), 1_000_000)
    assert (runs.check, runs.refine) == (0, refine_iterations_for(low, 1_000_000))


def test_check_iterations_stay_within_what_a_file_may_name():
    """A file's default refinement is bounded by its Gaussians (gspc/limits.py): the check runs no longer than
    the decode it predicts will."""
    runs = iteration_counts(EncodeOptions(check_iterations=5000), 300)
    assert (runs.check, runs.refine) == (1000, 1000)
    runs = iteration_counts(EncodeOptions(check_iterations=5000), 4000)
    assert (runs.check, runs.refine) == (4000, 4000)
