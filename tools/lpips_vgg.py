"""LPIPS (VGG16 variant) for the restorer's training loss (tools/train_restorer.py), only with weights the
user has on disk: nothing is downloaded. Not part of the gspc package, whose decoder never scores images.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from gspc.errors import GspcError, InputError
from gspc.metrics import check_pair

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
        check_pair(a, b)
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
