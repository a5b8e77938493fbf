"""EWA projection of 3D Gaussians to screen space (INRIA 3DGS / gsplat conventions).

Everything the compositor needs per visible Gaussian: 2D mean, inverse 2D covariance (conic),
opacity, RGB from SH, camera-space depth, and the half-extents of the screen box outside which
the Gaussian's alpha is below 1/255 (so tile culling never changes the image). On the CPU the compiled
kernels of project_cpu.py compute it (bench/render.md); the PyTorch code below, differentiated by autograd,
serves every other device and is the tests' second implementation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.render.kernels import pick_kernel
from gspc.render.rules import ALPHA_MIN, EXTENT_ABS_MARGIN, EXTENT_REL_MARGIN, LOWPASS, NEAR
from gspc.render.sh import C0, sh_basis

FRUSTUM_SLACK = 1.3  # x/z, y/z are clamped to this multiple of the frustum before building the Jacobian


# Below this fraction of Gaussians in front of the camera, rows are copied out before projecting;
# above it, the few behind are projected with a stand-in depth and marked never-drawn (cheaper). The
# PyTorch path only: the compiled kernels always take every row (they cull per Gaussian).
SUBSET_BELOW = 0.9


@dataclass
class Projected:
    index: torch.Tensor  # (M,) int64 scene rows these Gaussians come from, increasing
    means2d: torch.Tensor  # (M, 2) pixel coordinates (pixel centres at x + 0.5)
    conics: torch.Tensor  # (M, 3) inverse 2D covariance (a, b, c) as [[a, b], [b, c]]
    opacities: torch.Tensor  # (M,)
    colors: torch.Tensor  # (M, 3); the compiled kernel leaves the never-drawn at 0
    depths: torch.Tensor  # (M,) camera-space z
    extents: torch.Tensor  # (M, 2) half-sizes of the alpha >= 1/255 box; -1 = never drawn; no grad

    @property
    def drawn(self) -> torch.Tensor:
        return self.extents[:, 0] >= 0


def camera_tensors(camera: Camera, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """World-to-camera rotation (3, 3), translation (3,) and camera centre (3,) in ``like``'s dtype/device."""
    w2c = torch.as_tensor(camera.world_to_cam, dtype=like.dtype, device=like.device)
    R, t = w2c[:3, :3], w2c[:3, 3]
    return R, t, -(R.T @ t)


def quat_to_rotmat(quats: torch.Tensor) -> list[list[torch.Tensor]]:
    """Rotation matrices from unnormalised (w, x, y, z) quaternions, as 3x3 nested lists of (N,) tensors
    (per-entry tensors keep autograd cheap: no (N, 3, 3) temporaries or broadcast reductions)."""
    w, x, y, z = (quats / quats.norm(dim=1, keepdim=True)).unbind(1)
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
    return [
        [1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)],
        [2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)],
        [2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)],
    ]


def frustum_limits(camera: Camera) -> tuple[float, float, float, float]:
    """Clamp range for x/z and y/z: the frustum widened by FRUSTUM_SLACK - 1 of the half field of view on each
    side.

    Equals 3DGS's +-1.3 tan(fov/2) for a centred principal point (gsplat's generalisation).
    """
    tan_x, tan_y = 0.5 * camera.width / camera.fx, 0.5 * camera.height / camera.fy
    slack = FRUSTUM_SLACK - 1.0
    return (
        -(camera.cx / camera.fx + slack * tan_x),
        (camera.width - camera.cx) / camera.fx + slack * tan_x,
        -(camera.cy / camera.fy + slack * tan_y),
        (camera.height - camera.cy) / camera.fy + slack * tan_y,
    )


def alpha_extents(cov_xx: torch.Tensor, cov_yy: torch.Tensor, opacities: torch.Tensor) -> torch.Tensor:
    """Half-extents (M, 2) of the box outside which opacity * exp(-q/2) < 1/255.

    alpha >= 1/255 needs q <= 2 ln(255 o); that ellipse's bounding box has half-widths
    sqrt(threshold * Sigma_xx) and sqrt(threshold * Sigma_yy). Opacities below 1/255 get -1 (never drawn).
    """
    thr = 2.0 * torch.log(opacities / ALPHA_MIN)
    ext = torch.sqrt(thr.clamp_min(0)[:, None] * torch.stack([cov_xx, cov_yy], 1))
    ext = ext * (1 + EXTENT_REL_MARGIN) + EXTENT_ABS_MARGIN
    return torch.where(thr[:, None] >= 0, ext, torch.full_like(ext, -1.0))


def project(
    means: torch.Tensor,
    quats: torch.Tensor,
    log_scales: torch.Tensor,
    opacity_logits: torch.Tensor,
    sh_dc: torch.Tensor,
    sh_rest: torch.Tensor,
    camera: Camera,
    sh_degree: int,
    kernel: str = "auto",
) -> Projected:
    """Project Gaussians to the screen; differentiable w.r.t. every input tensor.

    Those that cannot reach a pixel centre with alpha >= 1/255 (centre at z <= NEAR, opacity below
    1/255, box off-screen) get extents -1 and zero gradients; the compositor skips them. ``kernel``:
    "auto" (compiled on the CPU, PyTorch elsewhere), "torch" or "compiled"; the same up to round-off.
    """
    if pick_kernel(kernel, means) == "compiled":
        # No subset here: the kernels cull the Gaussians behind the camera themselves (zero gradients, no
        # colour): copying out the rest and scattering their gradients back into zeros costs page faults and
        # system time every refinement iteration (bench/render.md, "Reading").
        out = _ProjectCompiled.apply(
            means, quats, log_scales, opacity_logits, sh_dc, sh_rest, camera, sh_degree
        )
        return Projected(torch.arange(len(means), device=means.device), *out)
    R, t, centre = camera_tensors(camera, means)
    with torch.no_grad():
        in_front = means @ R[2] + t[2] > NEAR
        n_front = int(in_front.sum())
    if n_front < SUBSET_BELOW * len(means):
        index = torch.nonzero(in_front).squeeze(1)
        means, quats, log_scales, opacity_logits, sh_dc, sh_rest = (
            x.index_select(0, index) for x in (means, quats, log_scales, opacity_logits, sh_dc, sh_rest)
        )
        in_front = torch.ones_like(in_front[index])
    else:
        index = torch.arange(len(means), device=means.device)

    x, y, z = (means @ R.T + t).unbind(1)
    if n_front < len(x):  # stand-in depth for the culled: finite values, so their zero gradients stay 0
        z = torch.where(in_front, z, torch.ones_like(z))
    u, v = camera.fx * x / z + camera.cx, camera.fy * y / z + camera.cy
    cxx, cxy, cyy = _screen_covariance(x, y, z, quats, log_scales, R, camera)
    opacities = torch.sigmoid(opacity_logits)
    with torch.no_grad():
        ext = alpha_extents(cxx, cyy, opacities)
        on_screen = (u + ext[:, 0] >= 0.5) & (u - ext[:, 0] <= camera.width - 0.5)
        on_screen &= (v + ext[:, 1] >= 0.5) & (v - ext[:, 1] <= camera.height - 0.5)
        ext[~(on_screen & in_front)] = -1.0

    det = cxx * cyy - cxy * cxy
    conics = torch.stack([cyy / det, -cxy / det, cxx / det], 1)
    dirs = means - centre
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    colors = _sh_colors(sh_dc, sh_rest, dirs, sh_degree)
    return Projected(index, torch.stack([u, v], 1), conics, opacities, colors, z, ext)


def _screen_covariance(x, y, z, quats, log_scales, R, camera):
    """Low-passed 2D covariance entries (xx, xy, yy) by EWA splatting, from camera-space centres."""
    lx0, lx1, ly0, ly1 = frustum_limits(camera)
    tx, ty = torch.clamp(x / z, lx0, lx1), torch.clamp(y / z, ly0, ly1)
    # Rows of J W, with J = [[fx/z, 0, -fx tx/z], [0, fy/z, -fy ty/z]] (tx, ty the clamped x/z, y/z).
    W = R.tolist()
    sx, sy = camera.fx / z, camera.fy / z
    jw0 = [sx * (W[0][k] - tx * W[2][k]) for k in range(3)]
    jw1 = [sy * (W[1][k] - ty * W[2][k]) for k in range(3)]
    # Sigma = (Rq S)(Rq S)^T, so J W Sigma W^T J^T = T T^T with T = J W Rq S: no 3x3 covariance needed.
    rq = quat_to_rotmat(quats)
    scale = torch.exp(log_scales).unbind(1)
    t0 = [(jw0[0] * rq[0][j] + jw0[1] * rq[1][j] + jw0[2] * rq[2][j]) * scale[j] for j in range(3)]
    t1 = [(jw1[0] * rq[0][j] + jw1[1] * rq[1][j] + jw1[2] * rq[2][j]) * scale[j] for j in range(3)]
    cxx = t0[0] * t0[0] + t0[1] * t0[1] + t0[2] * t0[2] + LOWPASS
    cxy = t0[0] * t1[0] + t0[1] * t1[1] + t0[2] * t1[2]
    cyy = t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2] + LOWPASS
    return cxx, cxy, cyy


def _sh_colors(sh_dc: torch.Tensor, sh_rest: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """gspc.render.sh.sh_to_color, cheaper: no (N, B, 3) concatenation of the coefficients, and the
    higher bands' sum (and its gradient) by batched matmul, not broadcast products (bench/render.md, "Moved
    from code comments"). The float64 reference renderer keeps sh_to_color as the oracle."""
    basis = sh_basis(dirs, degree)
    rgb = C0 * sh_dc
    if degree > 0:
        rgb = rgb + _BandSum.apply(basis[:, 1:], sh_rest[:, : basis.shape[1] - 1])
    return torch.clamp_min(rgb + 0.5, 0.0)


class _BandSum(torch.autograd.Function):
    """sum_k basis[n, k] * coeffs[n, k, :] -> (N, 3), for basis (N, K) and coeffs (N, K, 3)."""

    @staticmethod
    def forward(ctx, basis, coeffs):
        ctx.save_for_backward(basis, coeffs)
        return torch.bmm(basis[:, None, :], coeffs).squeeze(1)

    @staticmethod
    def backward(ctx, grad):
        basis, coeffs = ctx.saved_tensors
        d_basis = torch.bmm(coeffs, grad[:, :, None]).squeeze(2) if ctx.needs_input_grad[0] else None
        d_coeffs = basis[:, :, None] * grad[:, None, :] if ctx.needs_input_grad[1] else None
        return d_basis, d_coeffs


class _ProjectCompiled(torch.autograd.Function):
    """project() by the compiled CPU kernels of project_cpu.py; outputs in the inputs' dtype."""

    @staticmethod
    def forward(ctx, means, quats, log_scales, logits, sh_dc, sh_rest, camera: Camera, degree: int):
        from gspc.render import project_cpu as kern

        arrays = tuple(
            x.detach().contiguous().numpy() for x in (means, quats, log_scales, logits, sh_dc, sh_rest)
        )
        rot, t, centre = (x.numpy() for x in camera_tensors(camera, torch.zeros((), dtype=torch.float64)))
        intrinsics = (camera.fx, camera.fy, camera.cx, camera.cy)
        cam = kern.camera_numbers(
            rot, t, centre, intrinsics, frustum_limits(camera), (camera.width, camera.height)
        )
        outs = [
            torch.from_numpy(a) for a in kern.project_forward(arrays, cam, degree, torch.get_num_threads())
        ]
        ctx.mark_non_differentiable(outs[-1])
        ctx.saved = (arrays, cam, degree)
        return tuple(outs)

    @staticmethod
    def backward(ctx, g_means2d, g_conics, g_opacities, g_colors, g_depths, _g_extents):
        from gspc.render import project_cpu as kern

        arrays, cam, degree = ctx.saved
        n = len(arrays[0])
        outs = [
            np.zeros((n, k)) if g is None else g.detach().reshape(n, k).numpy()
            for g, k in ((g_means2d, 2), (g_conics, 3), (g_opacities, 1), (g_colors, 3), (g_depths, 1))
        ]
        rows, grad_out = kern.output_gradients(*outs, torch.get_num_threads())
        grads = kern.project_backward(arrays, cam, degree, rows, grad_out, torch.get_num_threads())
        return (*(torch.from_numpy(g) for g in grads), None, None)
