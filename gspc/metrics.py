"""Image quality metrics with the 3DGS evaluation conventions (8-bit renders, PSNR and SSIM as in INRIA 3DGS).

Images are torch tensors of shape (H, W, 3) or (B, H, W, 3), float in [0, 1]. PSNR and SSIM
return one value per image: a 0-dim tensor for a single image, shape (B,) for a batch. SSIM is
differentiable (the refinement loss uses it). The evaluator quantises renders and references
with :func:`quantize8` before scoring (:func:`mean_psnr`). LPIPS, which only the restorer's training uses,
is in tools/lpips_vgg.py.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from gspc.device import float32_math
from gspc.errors import InputError

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def quantize8(img: torch.Tensor) -> torch.Tensor:
    """Clamp to [0, 1] and round to the nearest k / 255, as an 8-bit image file would."""
    return torch.round(img.clamp(0.0, 1.0) * 255.0) / 255.0


def check_pair(a: torch.Tensor, b: torch.Tensor) -> None:
    if a.shape != b.shape:
        raise InputError(f"images differ in shape: {tuple(a.shape)} vs {tuple(b.shape)}")
    if a.dim() not in (3, 4):
        raise InputError(f"expected an (H, W, C) image or a (B, H, W, C) batch, got shape {tuple(a.shape)}")


def mse(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean squared error per image."""
    check_pair(a, b)
    return ((a - b) ** 2).mean(dim=(-3, -2, -1))


def psnr(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """PSNR in dB for a peak of 1, from each image's MSE (inf for identical images)."""
    return -10.0 * torch.log10(mse(a, b))


def _gaussian_1d(window: int, sigma: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    x = torch.arange(window, dtype=torch.float64) - window // 2
    g = torch.exp(-(x**2) / (2.0 * sigma**2))
    return (g / g.sum()).to(dtype=dtype, device=device)


@float32_math()  # no TF32 on CUDA: it moved SSIM's variances by ~1e-4
def _blur(x: torch.Tensor, g: torch.Tensor, padding: int) -> torch.Tensor:
    """Separable Gaussian filter of an (N, C, H, W) tensor, each channel on its own, zero padding."""
    c = x.shape[1]
    k = g.numel()
    x = F.conv2d(x, g.view(1, 1, k, 1).expand(c, 1, k, 1), padding=(padding, 0), groups=c)
    return F.conv2d(x, g.view(1, 1, 1, k).expand(c, 1, 1, k), padding=(0, padding), groups=c)


def ssim_map(a: torch.Tensor, b: torch.Tensor, padding: str = "same") -> torch.Tensor:
    """Per-pixel, per-channel SSIM as (B, C, H', W').

    ``padding="same"`` zero-pads by half the window, as INRIA 3DGS's ``ssim`` does (the border
    statistics see zeros); ``"valid"`` keeps only windows that lie inside the image.
    """
    check_pair(a, b)
    if padding not in ("same", "valid"):
        raise InputError(f"SSIM padding must be 'same' or 'valid', not {padding!r}")
    x = (a if a.dim() == 4 else a.unsqueeze(0)).permute(0, 3, 1, 2)
    y = (b if b.dim() == 4 else b.unsqueeze(0)).permute(0, 3, 1, 2)
    pad = SSIM_WINDOW // 2 if padding == "same" else 0
    if padding == "valid" and min(x.shape[-2:]) < SSIM_WINDOW:
        raise InputError(f"images of {x.shape[-2]}x{x.shape[-1]} are smaller than the SSIM window")
    g = _gaussian_1d(SSIM_WINDOW, SSIM_SIGMA, x.dtype, x.device)
    # One blur over all five statistics' inputs at once (stacked on the channel axis).
    c = x.shape[1]
    stats = _blur(torch.cat([x, y, x * x, y * y, x * y], dim=1), g, pad)
    mu_x, mu_y, xx, yy, xy = stats.split(c, dim=1)
    mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
    var_x, var_y, cov = xx - mu_xx, yy - mu_yy, xy - mu_xy
    num = (2.0 * mu_xy + SSIM_C1) * (2.0 * cov + SSIM_C2)
    den = (mu_xx + mu_yy + SSIM_C1) * (var_x + var_y + SSIM_C2)
    return num / den


def mean_psnr(images: Sequence[torch.Tensor], targets: Sequence[torch.Tensor], capped: bool = False) -> float:
    """Mean PSNR (dB) over image pairs, each quantised to 8 bits first (the 3DGS evaluation convention).
    ``capped``: each pair at most the PSNR of one sample one level off, so that a pair identical to 8 bits
    (an infinite PSNR) counts as the closest a difference can be, not as a mean that no change can move."""
    out = []
    for a, b in zip(images, targets):
        p = float(psnr(quantize8(a), quantize8(b)))
        out.append(min(p, 10.0 * math.log10(255.0**2 * a.numel())) if capped else p)
    return float(np.mean(out))


def ssim(a: torch.Tensor, b: torch.Tensor, padding: str = "same") -> torch.Tensor:
    """Mean SSIM per image: 11x11 Gaussian window, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2 (3DGS)."""
    m = ssim_map(a, b, padding).mean(dim=(1, 2, 3))
    return m if a.dim() == 4 else m[0]
