"""Progress of long runs as plain lines, for logs, job queues and CI (no terminal to draw bars on).

The pipeline reports ``progress(stage, done, total)``: ``done == 0`` opens a stage, ``done == total`` closes
it. :class:`ProgressLines` turns those calls into lines: one when a stage starts and ends, one at least every
``every`` seconds in between (done/total, elapsed, an estimate of the time left), and, once the first steps of
a long stage are timed, what the whole stage is expected to take on this machine. The command line uses it
whenever stderr is not a terminal, and its announcements beside the progress bars when it is.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

Progress = Callable[[str, int, int], None]  # (stage, done, total); done == 0 opens the stage

# A stage's expected length is announced after this many of its steps or seconds, whichever comes first
# (but never from its first step alone), and only if it is expected to last at least ANNOUNCE_MIN_S (short
# stages need no forecast).
ANNOUNCE_AFTER_STEPS = 3
ANNOUNCE_AFTER_S = 5.0
ANNOUNCE_MIN_S = 20.0


def format_seconds(s: float) -> str:
    """A duration as a person reads it: 42 s, 7 min 5 s, 1 h 3 min."""
    s = max(0.0, float(s))
    if s < 60:
        return f"{s:.0f} s" if s >= 10 else f"{s:.1f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60)} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60)} min"


def stage_unit(stage: str) -> str:
    """What a stage counts, for its announcement: refinement counts iterations, rendering counts views."""
    if "refine" in stage:
        return "refinement iterations"
    if "render" in stage:
        return "views"
    return "steps"


@dataclass
class _Stage:
    total: int
    start: float
    first_done: int  # steps already done when the stage was first reported (0 when it was opened)
    last_line: float
    announced: bool = False
    # (time, done) at the stage's first reported step: later steps are timed from there, since the first
    # may carry one-off costs (refinement's first iteration loads the compiled renderer: gspc/refine.py,
    # PROBE_ITERATIONS)
    first_step: tuple[float, int] | None = None


class ProgressLines:
    """A :data:`Progress` callback writing one plain line per event worth a line (see the module's doc).

    ``write`` takes a line; ``lines=False`` keeps only the announcements (for use beside progress bars);
    ``clock`` is injectable for tests.
    """

    def __init__(
        self,
        write: Callable[[str], None],
        every: float = 30.0,
        lines: bool = True,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.write, self.every, self.lines, self.clock = write, float(every), lines, clock
        self._stages: dict[str, _Stage] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        now = self.clock()
        st = self._stages.get(stage)
        if st is None or done == 0:
            st = self._stages[stage] = _Stage(total, now, done, now)
            if self.lines:
                self.write(f"{stage}: start, {total} {stage_unit(stage) if total > 1 else 'step'}")
            if done == 0:
                return
        elif total != st.total:  # a time budget shortened the stage
            st.total = total
            if self.lines:
                self.write(f"{stage}: now {total} {stage_unit(stage)} (time budget)")
        elapsed = now - st.start
        steps = done - st.first_done
        per_step = elapsed / steps if steps > 0 else 0.0
        if st.first_step is None and steps > 0:
            st.first_step = (now, done)
        after_first = done - st.first_step[1] if st.first_step else 0
        if after_first > 0:
            per_step = (now - st.first_step[0]) / after_first
        if done >= total:
            del self._stages[stage]
            if self.lines:
                self.write(f"{stage}: done, {total}/{total} in {format_seconds(elapsed)}")
            return
        if (
            not st.announced
            and after_first > 0
            and (steps >= ANNOUNCE_AFTER_STEPS or elapsed >= ANNOUNCE_AFTER_S)
        ):
            st.announced = True
            expected = elapsed + per_step * (total - done)
            if expected >= ANNOUNCE_MIN_S:
                self.write(
                    f"{stage}: {total} {stage_unit(stage)}, ~{format_seconds(expected)} on this machine "
                    f"({per_step:.2f} s each, measured on {after_first} after the first)"
                )
        if self.lines and now - st.last_line >= self.every:
            st.last_line = now
            self.write(
                f"{stage}: {done}/{total}, {format_seconds(elapsed)} elapsed, "
                f"~{format_seconds(per_step * (total - done))} left"
            )
