"""Running tasks: on this process, on local worker processes (``--workers``) or on Ray (``--ray``).

A task is a plain function of plain data (a tile's rows and the run's settings) to plain data (its chunks):
the executor is chosen at the top (:func:`open_executor`) and never seen by the maths. Results come back in
task order, and every task runs on one thread wherever it runs, so a run's bytes do not depend on how many
workers ran it, nor on which machines; the parallelism is across tasks, where it does not fight itself on a
busy machine. Ray's tasks call the same task function with the same job as a local worker does
(bench/ray.md measures both); ``import ray`` happens only where a run asks for it.

Inputs and outputs move as files or object references, never as one pickled scene: a tile's job names its
file and rows (gspc/io/ply.py PlyRows), which the worker reads itself, or carries the tile's own Gaussians
(a scene in memory, or :class:`DriverReads`); on Ray each job is put in the object store once and its task
receives the reference.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import socket
import subprocess
import sys
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TypeVar

from gspc import __version__
from gspc.errors import DeviceError, GspcError, InputError
from gspc.progress import Progress

J = TypeVar("J")
R = TypeVar("R")
# Tasks handed to the workers ahead of the one whose result is awaited, per worker: enough to keep each busy,
# few enough that the jobs and results waiting their turn stay a few tiles' worth of memory.
AHEAD = 2
RAY_INSTALL = "pip install 'gspc[ray]'"
# A local Ray instance's object store, per CPU: room for the jobs and results in flight (AHEAD per worker,
# a tile's Gaussians each way); past it Ray spills to disk rather than fail.
RAY_STORE_PER_CPU = 256 << 20
RAY_STORE_MIN = 256 << 20
# Seconds a --ray ADDRESS has to accept a connection, then to answer as a Ray cluster: Ray's own client
# retries an address that does not answer for many minutes; gspc answers in bounded time (tests/test_ray.py).
CONNECT_SECONDS = 5.0
ANSWER_SECONDS = 45.0


def default_workers(worker_bytes: int | None = None) -> int:
    """The cores this process may run on (its CPU affinity, else the machine's count); with ``worker_bytes``
    (the memory one worker may need), no more than the memory available now holds, and at least one."""
    try:
        cores = max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no sched_getaffinity (macOS, Windows)
        cores = max(1, os.cpu_count() or 1)
    free = available_memory()
    if worker_bytes is None or free is None:
        return cores
    return max(1, min(cores, free // worker_bytes))


def available_memory() -> int | None:
    """Bytes of memory available to new processes (Linux's MemAvailable; None where it is not known)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


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
    functions of plain data), so its file is hidden while the workers start."""
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


def _ray_task(fn: Callable[[J], R], job: J, version: str) -> R:
    """A task on a Ray worker: the driver's gspc must be the worker's, or the bytes could differ."""
    import gspc

    if gspc.__version__ != version:
        raise DeviceError(
            f"a Ray worker runs gspc {gspc.__version__}, the driver gspc {version}: install the same gspc "
            "on every node of the cluster"
        )
    _init_worker()
    return _call(fn, job)


@dataclass(frozen=True)
class TaskFailure:
    """A task that failed, in a run that goes on past failures (``keep_going``): its name and one line."""

    name: str
    message: str


class WorkerDied(Exception):
    """The process running a task ended without an answer (killed, out of memory, a lost node)."""


def error_line(e: BaseException) -> str:
    """An error as the command line reports it: gspc's own as they are, the system's with their type, and
    anything else as an internal error."""
    if isinstance(e, GspcError):
        return str(e)
    if isinstance(e, (OSError, MemoryError)):
        return f"{type(e).__name__}: {e}"
    return f"internal error ({type(e).__name__}: {e}); rerun with GSPC_DEBUG=1 for a traceback"


class Executor:
    """Where tasks run. :meth:`map` runs ``fn`` over jobs with at most ``AHEAD`` tasks per slot in flight,
    results in order; a task that raises ends the run with its error named by its task (``keep_going``: a
    :class:`TaskFailure` in its place, the others go on)."""

    slots = 1  # tasks that run side by side
    dies_together = False  # a worker's death fails the other tasks in flight too (they run again)

    def describe(self) -> str:
        raise NotImplementedError

    def _submit(self, fn: Callable, job):
        raise NotImplementedError

    def _result(self, handle):
        """The task's result; its own error, or WorkerDied."""
        raise NotImplementedError

    def _cancel(self, handle) -> None:
        pass

    def _restart(self) -> None:
        """After a WorkerDied: make the executor usable again (the local pool is broken)."""

    def close(self) -> None:
        pass

    def _ahead(self) -> int:
        return AHEAD * self.slots

    @contextmanager
    def _starting(self) -> Iterator[None]:
        yield

    def map(
        self,
        fn: Callable[[J], R],
        jobs: Iterable[J],
        name: Callable[[J], str],
        total: int,
        progress: Progress | None = None,
        stage: str = "tasks",
        keep_going: bool = False,
    ) -> Iterator[R | TaskFailure]:
        if progress:
            progress(stage, 0, total)
        done = 0
        pending: deque = deque()
        it = iter(jobs)
        end = object()
        with self._starting():
            try:
                while True:
                    while len(pending) < self._ahead():
                        job = next(it, end)
                        if job is end:
                            break
                        pending.append((job, self._submit_named(fn, job, name)))
                    if not pending:
                        return
                    job, handle = pending.popleft()
                    try:
                        result = self._result(handle)
                    except WorkerDied as e:
                        self._restart()
                        if not keep_going:
                            raise GspcError(f"{name(job)}: {e}") from None
                        if self.dies_together:
                            pending = deque((j, self._submit_named(fn, j, name)) for j, _ in pending)
                        result = TaskFailure(name(job), str(e))
                    except Exception as e:
                        if not keep_going:
                            if isinstance(e, GspcError):
                                raise type(e)(f"{name(job)}: {e}") from None
                            raise
                        result = TaskFailure(name(job), error_line(e))
                    done += 1
                    if progress:
                        progress(stage, done, total)
                    yield result
            finally:
                for _, h in pending:
                    self._cancel(h)

    def _submit_named(self, fn: Callable, job, name: Callable) -> object:
        try:
            return self._submit(fn, job)
        except WorkerDied as e:
            raise GspcError(f"{name(job)}: {e}") from None


class InProcess(Executor):
    """Every task on this process, one after another (``--workers 1``)."""

    def describe(self) -> str:
        return "1 worker"

    def _ahead(self) -> int:
        return 1  # a job is made when its task runs: nothing waits in memory

    def _submit(self, fn: Callable, job):
        return fn, job

    def _result(self, handle):
        return _call(*handle)


class LocalProcesses(Executor):
    """Tasks on worker processes of this machine (forkserver where there is one), started at the first
    task and kept for the executor's life: a batch of scenes starts them once."""

    dies_together = True  # a process pool is broken by one death

    def __init__(self, workers: int) -> None:
        self.slots = workers
        self._pool: ProcessPoolExecutor | None = None

    def describe(self) -> str:
        return f"{self.slots} workers"

    @contextmanager
    def _starting(self) -> Iterator[None]:
        with _main_unseen():
            yield

    def _submit(self, fn: Callable, job):
        if self._pool is None:
            method = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
            ctx = multiprocessing.get_context(method)
            self._pool = ProcessPoolExecutor(self.slots, mp_context=ctx, initializer=_init_worker)
        try:
            return self._pool.submit(_call, fn, job)
        except BrokenProcessPool:
            self._restart()
            raise WorkerDied("a worker process died (out of memory?)") from None

    def _result(self, handle):
        try:
            return handle.result()
        except BrokenProcessPool:
            raise WorkerDied("a worker process died (out of memory?)") from None

    def _cancel(self, handle) -> None:
        handle.cancel()

    def _restart(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def import_ray():
    """The ``ray`` module, or one line saying how to install it."""
    try:
        import ray
    except ImportError:
        raise DeviceError(f"--ray needs Ray, which is not installed: {RAY_INSTALL}") from None
    return ray


class RayExecutor(Executor):
    """Tasks on Ray: a local instance this executor starts (``--ray auto``), a running cluster it joins
    (``--ray ADDRESS``), or the one this process is already connected to (``ray.init`` before the call).
    Each job goes to the object store once, its task gets the reference; a cluster's nodes import their own
    gspc, which must be the driver's (each task checks)."""

    def __init__(self, address: str, workers: int | None) -> None:
        ray = self.ray = import_ray()
        quiet = dict(log_to_driver=False, logging_level=logging.ERROR, include_dashboard=False)
        self.owned = not ray.is_initialized()
        self.address = address
        if not self.owned:
            self.where = "the Ray instance this process is connected to"
        elif address == "auto":
            cpus = workers or default_workers()
            store = max(RAY_STORE_MIN, cpus * RAY_STORE_PER_CPU)
            _ray_init(ray, address="local", num_cpus=cpus, num_gpus=0, object_store_memory=store, **quiet)
            self.where = "a local Ray instance"
        else:
            check_ray_address(address)
            _ray_init(ray, address=address, **quiet)
            self.where = f"the Ray cluster at {address}"
        cpus = int(ray.cluster_resources().get("CPU", 0))
        self.cpus = cpus
        self.slots = max(1, workers if workers and address != "auto" else cpus)
        self.version = __version__
        self._task = ray.remote(num_cpus=1, max_retries=0, retry_exceptions=False)(_ray_task)

    def describe(self) -> str:
        return f"{self.where} ({self.cpus} CPUs)"

    def _submit(self, fn: Callable, job):
        return self._task.remote(fn, self.ray.put(job), self.version)

    def _result(self, handle):
        exc = self.ray.exceptions
        try:
            return self.ray.get(handle)
        except exc.RayTaskError as e:
            cause = e.cause
            if isinstance(cause, OSError) and cause.filename is not None:
                raise InputError(
                    f"{cause.filename}: {cause.strerror or cause} on a Ray worker (every node must read the "
                    "input at that path; or encode with --ship-inputs)"
                ) from None
            if isinstance(cause, Exception):
                raise cause from None
            raise GspcError(f"a Ray task failed ({' '.join(str(e).split())[:200]})") from None
        except exc.RayError as e:
            why = f"{type(e).__name__}; out of memory, or a node lost?"
            raise WorkerDied(f"a Ray worker died ({why})") from None

    def _cancel(self, handle) -> None:
        try:
            self.ray.cancel(handle, force=True)
        except Exception:  # already done, or the cluster is gone: nothing to stop
            pass

    def close(self) -> None:
        if self.owned:
            self.ray.shutdown()


def _ray_init(ray, **kwargs) -> None:
    """``ray.init``, its failure one line."""
    try:
        ray.init(**kwargs)
    except Exception as e:
        where = kwargs["address"] if kwargs["address"] != "local" else "a local instance"
        raise DeviceError(f"--ray: Ray did not start on {where} ({' '.join(str(e).split())[:300]})") from None


# Joins the cluster at argv[1] in a process of its own and prints its CPUs (or its error) as JSON: a process
# the driver can stop when the address never answers.
_PROBE = """
import json, logging, sys
try:
    import ray
    ray.init(address=sys.argv[1], log_to_driver=False, logging_level=logging.ERROR)
    print(json.dumps({"cpus": ray.cluster_resources().get("CPU", 0)}))
    ray.shutdown()
except Exception as e:
    print(json.dumps({"error": " ".join(str(e).split())[:300]}))
"""


def check_ray_address(address: str) -> None:
    """DeviceError in one line, within about CONNECT_SECONDS + ANSWER_SECONDS, unless a Ray cluster answers
    at ``address`` (HOST:PORT, or ray://HOST:PORT for Ray Client)."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    try:
        with socket.create_connection((host, int(port)), timeout=CONNECT_SECONDS):
            pass
    except (OSError, ValueError) as e:
        why = getattr(e, "strerror", None) or str(e) or type(e).__name__
        raise DeviceError(
            f"--ray {address}: nothing answers there ({why}); start the cluster's head with "
            "`ray start --head` and give its address"
        ) from None
    try:
        probe = subprocess.run(
            [sys.executable, "-c", _PROBE, address], capture_output=True, text=True, timeout=ANSWER_SECONDS
        )
    except subprocess.TimeoutExpired:
        raise DeviceError(
            f"--ray {address}: answers, but not as a Ray cluster within {ANSWER_SECONDS:g} s (the address of "
            "the head's GCS, port 6379 by default?)"
        ) from None
    lines = probe.stdout.strip().splitlines()
    answer = json.loads(lines[-1]) if lines and lines[-1].startswith("{") else {"error": "no answer"}
    if "error" in answer:
        raise DeviceError(f"--ray {address}: not a Ray cluster this Ray can join ({answer['error']})")


@contextmanager
def open_executor(
    workers: int | None, ray: str | None = None, worker_bytes: int | None = None
) -> Iterator[Executor]:
    """The executor a run's options ask for, closed (Ray shut down, where it started it) when the run
    ends: Ray where ``ray`` names it ("auto": a local instance of ``workers`` CPUs, or an address), else
    ``workers`` local processes (None: the cores this process may use, as many as the available memory
    holds at ``worker_bytes`` each; 1: this process)."""
    if ray is not None:
        ex: Executor = RayExecutor(ray, workers or (default_workers(worker_bytes) if ray == "auto" else None))
    else:
        n = workers or default_workers(worker_bytes)
        ex = InProcess() if n <= 1 else LocalProcesses(n)
    try:
        yield ex
    finally:
        ex.close()


@contextmanager
def executor_for(
    given: Executor | None, workers: int | None, ray: str | None, worker_bytes: int | None = None
) -> Iterator[Executor]:
    """``given`` where the caller holds one (a batch shares its executor), else one of the options' own."""
    if given is not None:
        yield given
        return
    with open_executor(workers, ray, worker_bytes) as ex:
        yield ex


def run_tasks(
    fn: Callable[[J], R],
    jobs: Iterable[J],
    workers: int | Executor,
    name: Callable[[J], str],
    total: int,
    progress: Progress | None = None,
    stage: str = "tasks",
) -> Iterator[R]:
    """``fn(job)`` for each job, in order, on ``workers`` (an executor, or a count of local processes; 1:
    this one). A task that fails ends the run with its error, named by ``name(job)``; a worker that dies,
    with one line saying so."""
    if isinstance(workers, Executor):
        yield from workers.map(fn, jobs, name, total, progress, stage)
        return
    with open_executor(workers) as ex:
        yield from ex.map(fn, jobs, name, total, progress, stage)


class DriverReads:
    """A rows source (gspc/io/ply.py PlyRows) whose tiles the driver reads and sends with each task, for
    workers that cannot read its file (a cluster without a shared file system: ``--ship-inputs``)."""

    def __init__(self, source) -> None:
        self.source = source
        self.num_gaussians, self.sh_degree = source.num_gaussians, source.sh_degree
        self.coordinates = source.coordinates

    def positions(self):
        return self.source.positions()

    def log_scales(self):
        return self.source.log_scales()

    def rows(self, rows):
        return self.source.rows(rows)

    def tile(self, rows):
        """What a tile's job carries: its Gaussians, read here."""
        return self.source.rows(rows), None
