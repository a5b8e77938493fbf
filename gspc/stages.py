"""The timed stages of one run: each stage's seconds for the run's report, its opening and closing for the
progress lines (gspc/progress.py), and the time budget they share. The encoder and the decoder time every
stage through one of these, so the report names what ran and nothing else.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from gspc.device import synchronize
from gspc.progress import Progress


@dataclass
class Stages:
    progress: Progress | None = None
    budget: float | None = None  # seconds the run may take (``--time-budget``), from ``started``
    seconds: dict[str, float] = field(default_factory=dict)
    started: float = field(default_factory=time.perf_counter)

    @property
    def deadline(self) -> float | None:
        """The ``time.perf_counter()`` by which the run should end, or None."""
        return None if self.budget is None else self.started + self.budget

    def past_deadline(self) -> bool:
        return self.deadline is not None and time.perf_counter() >= self.deadline

    @contextmanager
    def stage(self, name: str, announce: bool = True) -> Iterator[None]:
        """Time ``name`` (seconds add up over repeats); ``announce``: report it opened and closed as one
        step (stages that report their own steps pass False)."""
        if announce and self.progress:
            self.progress(name, 0, 1)
        synchronize()  # on a GPU, a stage's seconds are its own work, not what was queued before it
        t0 = time.perf_counter()
        try:
            yield
        finally:
            synchronize()
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t0
        if announce and self.progress:
            self.progress(name, 1, 1)
