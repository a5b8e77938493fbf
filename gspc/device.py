"""The compute device a run asks for (``--device``): checked before any work, by the encoder and the decoder
alike; what the run reports about it; and the two things GPU work needs around it (synchronised clocks,
float32 math).

Rendering, restoration and refinement run on this device; the attribute codec always runs on the CPU
(numpy, integer tables), so its bytes and its decoded attributes are the same on every device.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch

from gspc.errors import DeviceError
from gspc.progress import Progress
from gspc.render.gsplat_backend import gsplat_status

DEVICES = ("cpu", "cuda")
CPU_RENDERER = "gspc's renderer, compiled for the CPU (numba)"  # what a run on the CPU reports


def check_device(name: str) -> torch.device:
    """The device called ``name``; DeviceError for a name gspc does not know or a GPU that is not there."""
    if name not in DEVICES:
        raise DeviceError(f"unknown device {name!r}; use cpu or cuda")
    if name == "cuda" and not torch.cuda.is_available():
        raise DeviceError("--device cuda was requested but no CUDA GPU is available")
    return torch.device(name)


def renderer_info(device: torch.device, progress: Progress | None = None, encoder: bool = False) -> str:
    """Which renderer a run on ``device`` uses, for its report (probing gsplat on CUDA, once per process).

    On CUDA: gsplat with its version, and its alpha cap where it differs from the file's rules, or the torch
    renderer on the GPU and why gsplat is not used. ``encoder``: the encoder renders the residuals' images
    with the torch renderer, which follows the rules (spec 10.12), whatever renders the rest."""
    if device.type != "cuda":
        return CPU_RENDERER
    status = gsplat_status(device, progress)
    if not status.usable:
        return f"torch on {device.type} (gsplat not used: {status.reason})"
    text = f"{status.describe()} on {device.type}"
    return text + ("; residuals rendered by the torch renderer (the file's rules)" if encoder else "")


def synchronize(device: torch.device | None = None) -> None:
    """Wait for the work queued on a CUDA ``device`` (None: the current one, if CUDA has been started), so
    that a clock read next counts it; nothing on the CPU, which runs eagerly."""
    if device is not None and device.type != "cuda":
        return
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        torch.cuda.synchronize(device)


@contextmanager
def float32_math() -> Iterator[None]:
    """Full float32 convolutions and matrix products inside (no TF32, which CUDA convolutions use by
    default on Ampere and later: SSIM's variances moved by ~1e-4); the flags are restored on exit. Also a
    decorator."""
    conv, matmul = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
    try:
        yield
    finally:
        torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32 = conv, matmul
