"""Running tasks on this process or on local worker processes (``--workers``).

A task is a plain function of plain data (a tile's rows and the run's settings) to plain data (its chunks):
the executor is chosen at the top and never seen by the maths. Results come back in task order, and every
task runs on one thread wherever it runs, so a run's bytes do not depend on how many workers ran it; the
parallelism is across tasks, where it does not fight itself on a busy machine (bench/tiles.md).
"""

from __future__ import annotations

import multiprocessing
import os
import sys
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from typing import TypeVar

from gspc.errors import GspcError, InputError
from gspc.progress import Progress

J = TypeVar("J")
R = TypeVar("R")
# Tasks handed to the pool ahead of the one whose result is awaited, per worker: enough to keep each busy,
# few enough that the results waiting their turn stay a few tiles' worth of memory.
AHEAD = 2


def default_workers() -> int:
    """The cores this process may run on (its CPU affinity, else the machine's count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no sched_getaffinity (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def check_workers(value: object) -> int:
    """``--workers``: a whole number from 1 up (more than the tasks only idle)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InputError(f"--workers {value!r}: give a whole number of worker processes, 1 or more")
    return value


@contextmanager
def one_thread() -> Iterator[None]:
    """Torch's and the compiled kernels' threads at one inside (gspc/render/kernels.py reads torch's)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@contextmanager
def _main_unseen() -> Iterator[None]:
    """A worker process runs the main script's file again unless it cannot find it: a script without an
    ``if __name__ == "__main__"`` guard would start its own workers there, and one run from standard input
    or a notebook has no file (``<stdin>``). The tasks need nothing of the main module (they are gspc's
    functions of plain data), so its file is hidden while the workers run."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if path is None:
        yield
        return
    del main.__file__
    try:
        yield
    finally:
        main.__file__ = path


def _init_worker() -> None:
    import torch

    os.environ["GSPC_THREADS"] = "1"
    torch.set_num_threads(1)


def _call(fn: Callable[[J], R], job: J) -> R:
    with one_thread():
        return fn(job)


def run_tasks(
    fn: Callable[[J], R],
    jobs: Iterable[J],
    workers: int,
    name: Callable[[J], str],
    total: int,
    progress: Progress | None = None,
    stage: str = "tasks",
) -> Iterator[R]:
    """``fn(job)`` for each job, in order, on ``workers`` processes (1: this one). A task that fails ends the
    run with its error, named by ``name(job)``; a worker that dies, with one line saying so."""
    if progress:
        progress(stage, 0, total)
    done = 0
    if workers <= 1:
        for job in jobs:
            try:
                yield _call(fn, job)
            except GspcError as e:
                raise type(e)(f"{name(job)}: {e}") from None
            done += 1
            if progress:
                progress(stage, done, total)
        return
    method = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
    ctx = multiprocessing.get_context(method)
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker)
    with _main_unseen(), pool:
        pending: deque = deque()
        it = iter(jobs)
        try:
            while True:
                while len(pending) < AHEAD * workers:
                    job = next(it, None)
                    if job is None:
                        break
                    try:
                        pending.append((job, pool.submit(_call, fn, job)))
                    except BrokenProcessPool:
                        raise GspcError(f"{name(job)}: a worker process died (out of memory?)") from None
                if not pending:
                    return
                job, future = pending.popleft()
                try:
                    result = future.result()
                except GspcError as e:
                    raise type(e)(f"{name(job)}: {e}") from None
                except BrokenProcessPool:
                    raise GspcError(f"{name(job)}: a worker process died (out of memory?)") from None
                done += 1
                if progress:
                    progress(stage, done, total)
                yield result
        finally:
            for _, f in pending:
                f.cancel()
