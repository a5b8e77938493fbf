"""Real spherical harmonics up to degree 3, in INRIA 3DGS's basis order and sign convention.

Colour = max(sum_k sh[k] * Y_k(dir) + 0.5, 0) where ``dir`` is the unit vector from the camera
centre to the Gaussian. Coefficient 0 is ``sh_dc``; 1.. are ``sh_rest`` (coefficient-major).
"""

from __future__ import annotations

import torch

from gspc.scene import SH_C0 as C0  # the degree-0 constant has one home

C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Basis functions Y_k at unit directions ``dirs`` (N, 3) -> (N, (degree + 1) ** 2)."""
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [
            C2[0] * x * y,
            C2[1] * y * z,
            C2[2] * (2.0 * zz - xx - yy),
            C2[3] * x * z,
            C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            C3[0] * y * (3.0 * xx - yy),
            C3[1] * x * y * z,
            C3[2] * y * (4.0 * zz - xx - yy),
            C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            C3[4] * x * (4.0 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(out, dim=-1)


def sh_to_color(sh_dc: torch.Tensor, sh_rest: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """RGB (N, 3) = max(SH_eval + 0.5, 0) using bands up to ``degree`` (``sh_rest`` may hold more)."""
    basis = sh_basis(dirs, degree)  # (N, B)
    coeffs = torch.cat([sh_dc[:, None, :], sh_rest[:, : basis.shape[1] - 1, :]], dim=1)  # (N, B, 3)
    rgb = (basis[:, :, None] * coeffs).sum(dim=1)
    return torch.clamp_min(rgb + 0.5, 0.0)
