"""PLACEHOLDER - the renderer helper replaces this file."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class RenderResult:
    image: torch.Tensor  # (H, W, 3), not clamped
    alpha: torch.Tensor  # (H, W) accumulated opacity
    depth: torch.Tensor  # (H, W) alpha-weighted camera-space z (expected depth * alpha)


def render(scene, camera, background=None, backend: str = "auto", sh_degree=None) -> RenderResult:
    raise NotImplementedError
