"""Which implementation of the torch backend's two stages runs: the compiled CPU kernels (project_cpu.py,
composite_cpu.py) or the PyTorch code (project.py, rasterize.py), which runs on any device and is the
tests' second opinion on the CPU. Also what the compiled kernels share: their compile options and threads."""

from __future__ import annotations

import torch

KERNELS = ("auto", "torch", "compiled")
# numba options of every compiled kernel: compiled once per machine (numba's cache; the first run takes some
# seconds). error_model "numpy": no zero check per division; each kernel's docstring says why its divisors
# are bounded away from 0.
JIT = {"cache": True, "error_model": "numpy"}


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


def set_threads(n: int) -> None:
    """Run the compiled kernels' parallel loops on ``n`` threads (at most numba's pool)."""
    import numba  # only the compiled kernels need it

    numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))
