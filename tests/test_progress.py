"""Progress lines for runs without a terminal: stage start/end, a line at least every 30 s, a forecast."""

import pytest
from scenes import random_scene
from typer.testing import CliRunner

from gspc.cli import app
from gspc.io import write_ply
from gspc.progress import ProgressLines, format_seconds


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_lines_at_start_end_and_every_30_seconds():
    clock, lines = FakeClock(), []
    log = ProgressLines(lines.append, every=30.0, clock=clock)
    log("refine", 0, 100)
    for i in range(1, 101):
        clock.t = 2.0 * i  # 2 s per iteration: 200 s in all
        log("refine", i, 100)
    assert lines[0] == "refine: start, 100 refinement iterations"
    assert lines[-1] == "refine: done, 100/100 in 3 min 20 s"
    # The forecast comes once, after the first 3 iterations, from the time of those after the first.
    forecasts = [ln for ln in lines if "on this machine" in ln]
    assert forecasts == [
        "refine: 100 refinement iterations, ~3 min 20 s on this machine "
        "(2.00 s each, measured on 2 after the first)"
    ]
    ticks = [ln for ln in lines if "elapsed" in ln]
    # A line at least every 30 s of a 200 s stage, each with done/total and the time left.
    assert len(ticks) >= 200 // 30 - 1
    assert ticks[0] == "refine: 15/100, 30 s elapsed, ~2 min 50 s left"


def test_short_stages_get_no_forecast_and_announcements_alone_beside_bars():
    clock, lines = FakeClock(), []
    log = ProgressLines(lines.append, clock=clock)
    log("render coded", 0, 10)
    for i in range(1, 11):
        clock.t = 0.5 * i
        log("render coded", i, 10)
    assert lines == ["render coded: start, 10 views", "render coded: done, 10/10 in 5.0 s"]
    quiet = []
    bars = ProgressLines(quiet.append, lines=False, clock=clock)
    bars("check refine", 0, 1000)
    clock.t += 6.0  # slow iterations: the forecast waits for 5 s or 3 iterations, and for a second one
    bars("check refine", 1, 1000)
    assert quiet == []
    clock.t += 6.0
    bars("check refine", 2, 1000)
    assert quiet == [
        "check refine: 1000 refinement iterations, ~1 h 40 min on this machine "
        "(6.00 s each, measured on 1 after the first)"
    ]


def test_a_slow_first_step_does_not_inflate_the_forecast():
    # Refinement's first iteration loads the compiled renderer; the forecast times the iterations after it.
    clock, lines = FakeClock(), []
    log = ProgressLines(lines.append, every=1e9, clock=clock)
    log("refine", 0, 100)
    clock.t = 10.0
    log("refine", 1, 100)
    for i in range(2, 4):
        clock.t = 10.0 + (i - 1)
        log("refine", i, 100)
    assert lines[1] == (
        "refine: 100 refinement iterations, ~1 min 49 s on this machine "
        "(1.00 s each, measured on 1 after the first)"
    )


def test_a_stage_reported_without_its_opening_measures_from_its_first_report():
    clock, lines = FakeClock(), []
    log = ProgressLines(lines.append, clock=clock)
    clock.t = 10.0
    log("tool stage", 5, 50)  # a caller that never sent done == 0
    clock.t = 40.0
    log("tool stage", 8, 50)
    assert lines[0] == "tool stage: start, 50 steps"
    clock.t = 70.0
    log("tool stage", 11, 50)
    forecast = [ln for ln in lines if "on this machine" in ln]
    assert "10.00 s each" in forecast[0]  # (70 - 40) s over the 3 steps after the first report, not over 11


@pytest.mark.parametrize(
    ("s", "text"), [(4.24, "4.2 s"), (42, "42 s"), (425, "7 min 5 s"), (3780, "1 h 3 min")]
)
def test_format_seconds(s, text):
    assert format_seconds(s) == text


def test_cli_without_a_terminal_prints_plain_stage_lines(tmp_path):
    scene = tmp_path / "s.ply"
    write_ply(random_scene(200, sh_degree=0, seed=1), scene)
    res = CliRunner().invoke(
        app, ["encode", str(scene), "-o", str(tmp_path / "s.gspc"), "--no-side-info", "--views", "4"]
    )
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("gspc: ")]
    for stage in ("read", "attributes", "write"):
        assert f"gspc: {stage}: start, 1 step" in lines
        assert any(ln.startswith(f"gspc: {stage}: done, 1/1 in ") for ln in lines)
    assert "\x1b[" not in "\n".join(lines)  # no terminal control codes in a log
