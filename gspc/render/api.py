"""render(): the one rendering entry point; picks a backend and applies the background."""

from __future__ import annotations

import torch

from gspc.cameras import Camera
from gspc.errors import DeviceError, InputError
from gspc.render.gsplat_backend import gsplat_status, render_gsplat
from gspc.render.project import project
from gspc.render.rasterize import composite
from gspc.render.result import RenderResult

BACKENDS = ("auto", "torch", "gsplat")


def render(
    scene, camera: Camera, background=None, backend: str = "auto", sh_degree: int | None = None
) -> RenderResult:
    """Render ``scene`` from ``camera``; differentiable w.r.t. every scene tensor (and a tensor background).

    ``background`` is an RGB 3-vector (default black) composited behind the Gaussians;
    ``sh_degree`` may lower the scene's SH degree; ``backend`` is "auto", "torch" or "gsplat".
    """
    deg = scene.sh_degree if sh_degree is None else int(sh_degree)
    if not 0 <= deg <= scene.sh_degree:
        raise InputError(f"sh_degree {sh_degree} is outside 0-{scene.sh_degree} (the scene's SH degree)")
    ref = scene.means
    bg = torch.zeros(3, dtype=ref.dtype, device=ref.device) if background is None else background
    bg = torch.as_tensor(bg, dtype=ref.dtype, device=ref.device).reshape(-1)
    if bg.numel() != 3:
        raise InputError(f"background must have 3 values (RGB), got {bg.numel()}")
    if _pick_backend(backend, ref) == "gsplat":
        return render_gsplat(scene, camera, bg, deg)
    return _render_torch(scene, camera, bg, deg)


def backend_for(device: torch.device) -> str:
    """The backend that ``backend="auto"`` picks for a scene on ``device``: gsplat on CUDA when its kernels
    run there (gsplat_status probes them once), else the torch renderer on that same device."""
    return "gsplat" if device.type == "cuda" and gsplat_status(device).usable else "torch"


def _pick_backend(backend: str, ref: torch.Tensor) -> str:
    if backend not in BACKENDS:
        raise InputError(f"unknown render backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    if backend == "torch":
        return "torch"
    if backend == "auto":
        return backend_for(ref.device)
    if not ref.is_cuda:
        raise DeviceError(
            "render backend 'gsplat' needs the scene on a CUDA device; use backend 'torch' on CPU"
        )
    return "gsplat"  # render_gsplat refuses it, with the reason, where its kernels do not run


def _render_torch(scene, camera: Camera, bg: torch.Tensor, deg: int) -> RenderResult:
    p = project(
        scene.means, scene.quats, scene.log_scales, scene.opacities, scene.sh_dc, scene.sh_rest, camera, deg
    )
    features = torch.cat([p.colors, p.depths[:, None]], 1)
    acc, alpha = composite(
        p.means2d, p.conics, p.opacities, features, p.depths, p.extents, camera.width, camera.height
    )
    image = acc[..., :3] + (1 - alpha)[..., None] * bg
    return RenderResult(image=image, alpha=alpha, depth=acc[..., 3])
