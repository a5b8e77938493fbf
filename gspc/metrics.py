"""Image quality metrics with the 3DGS evaluation conventions (8-bit renders, PSNR and SSIM as in INRIA 3DGS).

Images are torch tensors of shape (H, W, 3) or (B, H, W, 3), float in [0, 1]. PSNR and SSIM
return one value per image: a 0-dim tensor for a single image, shape (B,) for a batch. SSIM is
differentiable (the refinement loss uses it). The evaluator quantises renders and references
with :func:`quantize8` before scoring.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import torch
import torch.nn.functional as F

from gspc.device import float32_math
from gspc.errors import GspcError, InputError

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def quantize8(img: torch.Tensor) -> torch.Tensor:
    """Clamp to [0, 1] and round to the nearest k / 255, as an 8-bit image file would."""
    return torch.round(img.clamp(0.0, 1.0) * 255.0) / 255.0


def _check_pair(a: torch.Tensor, b: torch.Tensor) -> None:
    if a.shape != b.shape:
        raise InputError(f"images differ in shape: {tuple(a.shape)} vs {tuple(b.shape)}")
    if a.dim() not in (3, 4):
        raise InputError(f"expected an (H, W, C) image or a (B, H, W, C) batch, got shape {tuple(a.shape)}")


def mse(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean squared error per image."""
    _check_pair(a, b)
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
    _check_pair(a, b)
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


def ssim(a: torch.Tensor, b: torch.Tensor, padding: str = "same") -> torch.Tensor:
    """Mean SSIM per image: 11x11 Gaussian window, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2 (3DGS)."""
    m = ssim_map(a, b, padding).mean(dim=(1, 2, 3))
    return m if a.dim() == 4 else m[0]


# ---------------------------------------------------------------------------
# LPIPS (VGG16 variant), only with weights the user has on disk
# ---------------------------------------------------------------------------

LPIPS_ENV = "GSPC_LPIPS_WEIGHTS"
# VGG16 "features" layout: conv widths, "M" for 2x2 max pooling. Indices in the resulting
# nn.Sequential match torchvision's, so its checkpoint keys ("features.<i>.weight") load as they are.
_VGG16 = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)
# LPIPS reads the ReLU outputs that end each block: relu1_2, relu2_2, relu3_3, relu4_3, relu5_3.
_TAPS = (3, 8, 15, 22, 29)
_TAP_CHANNELS = (64, 128, 256, 512, 512)
# LPIPS's input normalisation for images in [-1, 1].
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)


class LPIPS(torch.nn.Module):
    """LPIPS with a VGG16 backbone: unit-normalised features at five depths, squared differences
    weighted per channel by non-negative linear layers, averaged over pixels, summed over depths.

    Build it once (``LPIPS.from_file``) when scoring many images. Its state-dict keys are
    torchvision's ``features.<i>.weight/bias`` and the ``lpips`` package's ``lin<k>.model.1.weight``.
    """

    def __init__(self) -> None:
        super().__init__()
        layers: list[torch.nn.Module] = []
        c_in = 3
        for v in _VGG16:
            if v == "M":
                layers.append(torch.nn.MaxPool2d(2, 2))
            else:
                layers += [torch.nn.Conv2d(c_in, v, 3, padding=1), torch.nn.ReLU()]
                c_in = v
        self.features = torch.nn.Sequential(*layers[: _TAPS[-1] + 1])
        for k, c in enumerate(_TAP_CHANNELS):
            # Nested as lin<k>.model.1 so the lpips package's weight file loads unchanged.
            lin = torch.nn.Module()
            lin.model = torch.nn.Sequential(torch.nn.Identity(), torch.nn.Conv2d(c, 1, 1, bias=False))
            self.add_module(f"lin{k}", lin)
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()

    @staticmethod
    def from_file(path: str | Path | None = None) -> LPIPS:
        """Load weights from ``path`` (a file, or a folder whose ``*.pth``/``*.pt`` files are merged),
        or from the file or folder named by $GSPC_LPIPS_WEIGHTS."""
        if path is None:
            path = os.environ.get(LPIPS_ENV)
        if not path:
            raise GspcError(
                "LPIPS needs VGG16 and LPIPS-linear weights on disk (they cannot be downloaded here): "
                f"pass weights_path or set ${LPIPS_ENV}"
            )
        path = Path(path)
        files = sorted([*path.glob("*.pth"), *path.glob("*.pt")]) if path.is_dir() else [path]
        if not files or not all(f.is_file() for f in files):
            raise InputError(f"LPIPS weights {path} do not exist")
        state: dict[str, torch.Tensor] = {}
        for f in files:
            try:
                sd = torch.load(f, map_location="cpu", weights_only=True)
            except Exception as e:  # torch raises many types for a bad file
                raise InputError(f"LPIPS weights {f} do not load: {e}") from None
            if not isinstance(sd, dict):
                raise InputError(f"LPIPS weights {f} are not a state dict")
            state.update(sd)
        model = LPIPS()
        wanted = model.state_dict()
        missing = [k for k in wanted if k not in state]
        if missing:
            raise InputError(f"LPIPS weights in {path} lack {len(missing)} tensor(s), e.g. {missing[0]!r}")
        for k, v in wanted.items():
            if tuple(state[k].shape) != tuple(v.shape):
                raise InputError(
                    f"LPIPS weight {k!r} has shape {tuple(state[k].shape)}, expected {tuple(v.shape)}"
                )
        model.load_state_dict({k: state[k] for k in wanted})
        return model

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        _check_pair(a, b)
        x = (a if a.dim() == 4 else a.unsqueeze(0)).permute(0, 3, 1, 2)
        y = (b if b.dim() == 4 else b.unsqueeze(0)).permute(0, 3, 1, 2)
        n = x.shape[0]
        dtype = self.shift.dtype
        h = (torch.cat([x, y]).to(dtype) * 2.0 - 1.0 - self.shift) / self.scale
        total = torch.zeros(n, dtype=dtype, device=h.device)
        k = 0
        for i, layer in enumerate(self.features):
            h = layer(h)
            if i in _TAPS:
                f = h / (h.pow(2).sum(dim=1, keepdim=True).sqrt() + 1e-10)
                d = (f[:n] - f[n:]) ** 2
                total = total + getattr(self, f"lin{k}").model(d).mean(dim=(1, 2, 3))
                k += 1
        return total if a.dim() == 4 else total[0]


def lpips(a: torch.Tensor, b: torch.Tensor, weights_path: str | Path | None = None) -> torch.Tensor:
    """LPIPS (VGG) per image. Needs weights on disk (``weights_path`` or $GSPC_LPIPS_WEIGHTS);
    raises GspcError otherwise. Loads them on every call: use :class:`LPIPS` for many images."""
    model = LPIPS.from_file(weights_path).to(a.device)
    with torch.no_grad():
        return model(a, b)


def psnr_from_mse(value: float) -> float:
    """PSNR in dB for a peak of 1 from an MSE (inf for zero)."""
    return math.inf if value <= 0 else -10.0 * math.log10(value)
