"""gsplat's CUDA rasteriser behind gspc's render() convention (imported lazily: CUDA machines only).

Same conventions as the torch backend (OpenCV camera, the low-pass and near plane of rules.py, SH
from the camera centre, classic 3DGS compositing); images agree up to float32 round-off and
gsplat's own tile culling of very faint tails. gsplat's kernels are float32: other dtypes are cast
there and back (gradients flow through the casts).
"""

from __future__ import annotations

import torch

from gspc.cameras import Camera
from gspc.errors import DeviceError
from gspc.render.result import RenderResult
from gspc.render.rules import LOWPASS, NEAR


def gsplat_available() -> bool:
    """True when gsplat imports (it also needs `packaging`, which it does not declare)."""
    try:
        import gsplat  # noqa: F401
    except Exception:  # any import-time failure means "not usable here"
        return False
    return True


def render_gsplat(scene, camera: Camera, background: torch.Tensor, sh_degree: int):
    """Render with gsplat.rasterization; returns a RenderResult in the scene's dtype."""
    if not scene.means.is_cuda:
        raise DeviceError(
            "render backend 'gsplat' needs the scene on a CUDA device; use backend 'torch' on CPU"
        )
    try:
        from gsplat import rasterization
    except Exception as e:
        raise DeviceError(f"render backend 'gsplat' is unavailable: {e}") from None
    dev, dt, f32 = scene.means.device, scene.means.dtype, torch.float32
    k = (sh_degree + 1) ** 2
    coeffs = torch.cat([scene.sh_dc[:, None, :], scene.sh_rest[:, : k - 1, :]], 1).to(f32)
    colors, alphas, _ = rasterization(
        scene.means.to(f32),
        scene.quats.to(f32),
        torch.exp(scene.log_scales).to(f32),
        torch.sigmoid(scene.opacities).to(f32),
        coeffs,
        torch.as_tensor(camera.world_to_cam, dtype=f32, device=dev)[None],
        torch.as_tensor(camera.K, dtype=f32, device=dev)[None],
        camera.width,
        camera.height,
        near_plane=NEAR,
        eps2d=LOWPASS,
        sh_degree=sh_degree,
        packed=False,
        render_mode="RGB+D",  # accumulated depth sum_i w_i z_i, as the torch backend
        rasterize_mode="classic",
    )
    acc, alpha = colors[0].to(dt), alphas[0, ..., 0].to(dt)
    image = acc[..., :3] + (1 - alpha)[..., None] * background
    return RenderResult(image=image, alpha=alpha, depth=acc[..., 3])
