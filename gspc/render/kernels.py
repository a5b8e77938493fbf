"""Which implementation of the torch backend's two stages runs: the compiled CPU kernels (project_cpu.py,
composite_cpu.py) or the PyTorch code (project.py, rasterize.py), which runs on any device and is the
tests' second opinion on the CPU."""

from __future__ import annotations

import torch

KERNELS = ("auto", "torch", "compiled")


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
