"""Dense per-pixel reference renderer: the test oracle, written for clarity, not speed.

Every Gaussian is evaluated at every pixel in float64, one Gaussian at a time in depth order,
with no tiles and no culling box; only the rules themselves (near-plane cull, alpha threshold,
0.99 cap, transmittance stop) decide what is drawn. Differentiable by plain autograd.
"""

from __future__ import annotations

import torch

from gspc.cameras import Camera
from gspc.render.result import RenderResult
from gspc.render.rules import ALPHA_MAX, ALPHA_MIN, LOWPASS, NEAR, T_MIN
from gspc.render.sh import sh_basis

SLACK = 0.3  # x/z, y/z clamped to the frustum widened by this much (project.py FRUSTUM_SLACK - 1)


def render_reference(scene, camera: Camera, background=None, sh_degree: int | None = None) -> RenderResult:
    """Render ``scene`` (any dtype; computed in float64) exactly by the rules, pixel by pixel."""
    s = scene.to(dtype=torch.float64) if scene.means.dtype != torch.float64 else scene
    deg = s.sh_degree if sh_degree is None else sh_degree
    dt = torch.float64
    w2c = torch.tensor(camera.world_to_cam, dtype=dt)
    W, t = w2c[:3, :3], w2c[:3, 3]
    bg = torch.zeros(3, dtype=dt) if background is None else torch.as_tensor(background, dtype=dt)

    H, Wd = camera.height, camera.width
    ys, xs = torch.meshgrid(torch.arange(H, dtype=dt) + 0.5, torch.arange(Wd, dtype=dt) + 0.5, indexing="ij")
    image = torch.zeros(H, Wd, 3, dtype=dt)
    depth = torch.zeros(H, Wd, dtype=dt)
    T = torch.ones(H, Wd, dtype=dt)
    stopped = torch.zeros(H, Wd, dtype=torch.bool)

    z_all = (s.means @ W.T + t)[:, 2]
    visible = [i for i in range(s.num_gaussians) if z_all[i].item() > NEAR]
    visible.sort(key=lambda i: z_all[i].item())  # Python's sort is stable: ties keep index order

    for i in visible:
        mean2d, cov2d, z = _project_one(s, i, W, t, camera)
        color = _color_one(s, i, W, t, deg)
        opacity = torch.sigmoid(s.opacities[i])
        conic = torch.linalg.inv(cov2d)
        dx, dy = xs - mean2d[0], ys - mean2d[1]
        q = conic[0, 0] * dx * dx + 2 * conic[0, 1] * dx * dy + conic[1, 1] * dy * dy
        alpha = torch.clamp(opacity * torch.exp(-0.5 * q), max=ALPHA_MAX)
        T_next = T * (1 - alpha)
        drawn = (alpha >= ALPHA_MIN) & ~stopped
        stop_here = drawn & (T_next < T_MIN)  # 3DGS: stop before the Gaussian that ends the pixel
        stopped = stopped | stop_here
        drawn = drawn & ~stop_here
        weight = torch.where(drawn, alpha * T, torch.zeros_like(alpha))
        image = image + weight[:, :, None] * color
        depth = depth + weight * z
        T = torch.where(drawn, T_next, T)
    image = image + T[:, :, None] * bg
    return RenderResult(image=image, alpha=1 - T, depth=depth)


def _project_one(s, i, W, t, camera):
    """2D mean, low-passed 2D covariance and camera z of Gaussian i (EWA splatting)."""
    q = s.quats[i] / s.quats[i].norm()
    w, x, y, z = q[0], q[1], q[2], q[3]
    Rq = torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
        ]
    )
    S = torch.diag(torch.exp(s.log_scales[i]))
    sigma_world = Rq @ S @ S.T @ Rq.T
    sigma_cam = W @ sigma_world @ W.T
    p = W @ s.means[i] + t
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    # Clamp the direction used by the Jacobian to the frustum widened by SLACK of the half FOV each side.
    tan_x, tan_y = 0.5 * camera.width / fx, 0.5 * camera.height / fy
    x_over_z = torch.clamp(p[0] / p[2], -(cx / fx + SLACK * tan_x), (camera.width - cx) / fx + SLACK * tan_x)
    y_over_z = torch.clamp(p[1] / p[2], -(cy / fy + SLACK * tan_y), (camera.height - cy) / fy + SLACK * tan_y)
    zero = torch.zeros((), dtype=p.dtype)
    J = torch.stack(
        [
            torch.stack([fx / p[2], zero, -fx * x_over_z / p[2]]),
            torch.stack([zero, fy / p[2], -fy * y_over_z / p[2]]),
        ]
    )
    cov2d = J @ sigma_cam @ J.T + LOWPASS * torch.eye(2, dtype=p.dtype)
    mean2d = torch.stack([fx * p[0] / p[2] + cx, fy * p[1] / p[2] + cy])
    return mean2d, cov2d, p[2]


def _color_one(s, i, W, t, deg):
    """max(SH(view direction) + 0.5, 0), the direction from the camera centre to the mean."""
    centre = -W.T @ t
    d = s.means[i] - centre
    d = d / d.norm()
    basis = sh_basis(d[None], deg)[0]  # ((deg + 1)^2,)
    coeffs = torch.cat([s.sh_dc[i][None], s.sh_rest[i][: len(basis) - 1]])  # ((deg + 1)^2, 3)
    return torch.clamp(basis @ coeffs + 0.5, min=0.0)
