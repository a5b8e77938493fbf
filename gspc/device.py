"""The compute device a run asks for (``--device``): checked before any work, by the encoder and the decoder
alike, and what the run reports about it.

Rendering, restoration and refinement run on this device; the attribute codec always runs on the CPU
(numpy, integer tables), so its bytes and its decoded attributes are the same on every device.
"""

from __future__ import annotations

import torch

from gspc.errors import DeviceError
from gspc.render.api import backend_for

DEVICES = ("cpu", "cuda")


def check_device(name: str) -> torch.device:
    """The device called ``name``; DeviceError for a name gspc does not know or a GPU that is not there."""
    if name not in DEVICES:
        raise DeviceError(f"unknown device {name!r}; use cpu or cuda")
    if name == "cuda" and not torch.cuda.is_available():
        raise DeviceError("--device cuda was requested but no CUDA GPU is available")
    return torch.device(name)


def renderer_info(device: torch.device) -> str:
    """Which renderer a run on ``device`` uses, for its report: without gsplat a CUDA run renders with the
    torch renderer on the GPU (not on the CPU), and says so."""
    backend = backend_for(device)
    if device.type == "cuda" and backend == "torch":
        return "torch on cuda (gsplat is not installed: pip install gspc[cuda])"
    return f"{backend} on {device.type}"
