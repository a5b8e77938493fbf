"""What every render backend returns (its own module so that the backends and the dispatcher in api.py
import it without importing each other)."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class RenderResult:
    image: torch.Tensor  # (H, W, 3), not clamped
    alpha: torch.Tensor  # (H, W) accumulated opacity, 1 - final transmittance
    depth: torch.Tensor  # (H, W) alpha-weighted camera-space z (expected depth * alpha)
