"""Which implementation of the torch backend's two stages runs: the compiled CPU kernels (project_cpu.py,
composite_cpu.py) or the PyTorch code (project.py, rasterize.py), which runs on any device and is the
tests' second opinion on the CPU. Also what the compiled kernels share: their compile options and threads."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import torch

KERNELS = ("auto", "torch", "compiled")
# numba options of every compiled kernel: compiled once per machine (numba's cache; the first run takes some
# seconds). error_model "numpy": no zero check per division; each kernel's docstring says why its divisors
# are bounded away from 0.
JIT = {"cache": True, "error_model": "numpy"}
ROWS_PER_TASK = 4096  # rows (Gaussians, records, sort keys) a parallel task takes at least


def pick_kernel(kernel: str, ref: torch.Tensor) -> str:
    """The implementation to run, "compiled" or "torch": under "auto", compiled for CPU tensors, else the
    PyTorch code; ValueError for an unknown name, or for compiled kernels off the CPU."""
    if kernel not in KERNELS:
        raise ValueError(f"unknown render kernel {kernel!r}; choose one of {', '.join(KERNELS)}")
    if kernel == "auto":
        return "compiled" if ref.device.type == "cpu" else "torch"
    if kernel == "compiled" and ref.device.type != "cpu":
        raise ValueError("the compiled render kernels run on the CPU only")
    return kernel


@contextmanager
def parallel(threads: int) -> Iterator[None]:
    """Run the compiled kernels' parallel loops inside on ``threads`` threads (at most numba's pool).

    numba's OpenMP pool, started by its first parallel loop, sets the OpenMP thread count that torch also
    reads to the pool's size (every core): torch's own count (GSPC_THREADS) is put back after each run. One
    thread runs the kernels' serial versions and never starts the pool (idle pool threads may wait busily)."""
    import numba  # only the compiled kernels need it

    torch_threads = torch.get_num_threads()
    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        if torch.get_num_threads() != torch_threads:
            torch.set_num_threads(torch_threads)


def block_bounds(n: int, threads: int) -> np.ndarray:
    """Bounds b[0] = 0 .. b[-1] = n of the blocks of consecutive rows a parallel kernel's threads take:
    about four blocks a thread, of at least ROWS_PER_TASK rows (one block when n is smaller)."""
    blocks = max(1, min(4 * threads, n // ROWS_PER_TASK))
    return (np.arange(blocks + 1, dtype=np.int64) * n) // blocks
