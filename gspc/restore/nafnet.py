"""NAFNet (Chen et al., "Simple Baselines for Image Restoration", 2022) as gspc's residual restorer.

Input: (B, 6, H, W) = degraded render I~ (channels 0-2) concatenated with the decoded side
information R~ (channels 3-5). Output: (B, 3, H, W) predicted residual R^, so I^ = I~ + R^.

With ``predict_correction=True`` (default) the net predicts a correction on top of the side
information, R^ = R~ + net(x). The residual scales (beta, gamma) of every block and the final
convolution start at zero, so an untrained (freshly constructed) net outputs net(x) = 0 exactly
and the restorer reduces to the paper's side-information-only mode, I^ = I~ + R~.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class LayerNorm2d(nn.Module):
    """LayerNorm over the channel dimension of an NCHW tensor, per pixel."""

    def __init__(self, channels: int, eps: float = 1e-6):
        super().__init__()
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))
        self.eps = eps

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mu = x.mean(1, keepdim=True)
        var = (x - mu).pow(2).mean(1, keepdim=True)
        y = (x - mu) / torch.sqrt(var + self.eps)
        return y * self.weight[None, :, None, None] + self.bias[None, :, None, None]


class SimpleGate(nn.Module):
    """Split channels in two halves and multiply them: a nonlinearity without activation functions."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        a, b = x.chunk(2, dim=1)
        return a * b


class NAFBlock(nn.Module):
    def __init__(self, c: int, expand: int = 2, ffn_expand: int = 2):
        super().__init__()
        dw = c * expand
        self.norm1 = LayerNorm2d(c)
        self.conv1 = nn.Conv2d(c, dw, 1)
        self.conv2 = nn.Conv2d(dw, dw, 3, padding=1, groups=dw)
        self.gate = SimpleGate()
        # Simplified channel attention: global average pool, then a 1x1 conv, used as a scale.
        self.sca = nn.Sequential(nn.AdaptiveAvgPool2d(1), nn.Conv2d(dw // 2, dw // 2, 1))
        self.conv3 = nn.Conv2d(dw // 2, c, 1)
        ffn = c * ffn_expand
        self.norm2 = LayerNorm2d(c)
        self.conv4 = nn.Conv2d(c, ffn, 1)
        self.conv5 = nn.Conv2d(ffn // 2, c, 1)
        # Zero residual scales: every block starts as the identity.
        self.beta = nn.Parameter(torch.zeros(1, c, 1, 1))
        self.gamma = nn.Parameter(torch.zeros(1, c, 1, 1))

    def forward(self, inp: torch.Tensor) -> torch.Tensor:
        x = self.gate(self.conv2(self.conv1(self.norm1(inp))))
        x = self.conv3(x * self.sca(x))
        y = inp + x * self.beta
        x = self.conv5(self.gate(self.conv4(self.norm2(y))))
        return y + x * self.gamma


class NAFNet(nn.Module):
    """U-Net of NAFBlocks; ``enc_blocks``/``dec_blocks`` give the block count per level."""

    def __init__(
        self,
        in_channels: int = 6,
        out_channels: int = 3,
        width: int = 16,
        enc_blocks: tuple[int, ...] | list[int] = (1, 1, 1),
        middle_blocks: int = 1,
        dec_blocks: tuple[int, ...] | list[int] = (1, 1, 1),
        predict_correction: bool = True,
    ):
        super().__init__()
        if len(enc_blocks) != len(dec_blocks):
            raise ValueError("enc_blocks and dec_blocks need one entry per level each")
        if predict_correction and (in_channels < 6 or out_channels != 3):
            raise ValueError("predict_correction needs R~ in input channels 3-5 and 3 output channels")
        self.predict_correction = predict_correction
        self.intro = nn.Conv2d(in_channels, width, 3, padding=1)
        self.encoders, self.downs, self.ups, self.decoders = (nn.ModuleList() for _ in range(4))
        c = width
        for n in enc_blocks:
            self.encoders.append(nn.Sequential(*[NAFBlock(c) for _ in range(n)]))
            self.downs.append(nn.Conv2d(c, 2 * c, 2, stride=2))
            c *= 2
        self.middle = nn.Sequential(*[NAFBlock(c) for _ in range(middle_blocks)])
        for n in dec_blocks:
            self.ups.append(nn.Sequential(nn.Conv2d(c, 2 * c, 1, bias=False), nn.PixelShuffle(2)))
            c //= 2
            self.decoders.append(nn.Sequential(*[NAFBlock(c) for _ in range(n)]))
        self.ending = nn.Conv2d(width, out_channels, 3, padding=1)
        # Zero final conv: an untrained net predicts exactly no correction.
        nn.init.zeros_(self.ending.weight)
        nn.init.zeros_(self.ending.bias)
        self.multiple = 2 ** len(enc_blocks)

    def forward(self, inp: torch.Tensor) -> torch.Tensor:
        h, w = inp.shape[-2:]
        x = self.intro(pad_to_multiple(inp, self.multiple))
        skips = []
        for enc, down in zip(self.encoders, self.downs, strict=True):
            x = enc(x)
            skips.append(x)
            x = down(x)
        x = self.middle(x)
        for dec, up, skip in zip(self.decoders, self.ups, reversed(skips), strict=True):
            x = dec(up(x) + skip)
        out = self.ending(x)[..., :h, :w]
        return inp[:, 3:6] + out if self.predict_correction else out


def pad_to_multiple(x: torch.Tensor, multiple: int) -> torch.Tensor:
    """Pad the bottom/right of an NCHW tensor (edge replication) to sizes divisible by ``multiple``."""
    h, w = x.shape[-2:]
    ph, pw = (-h) % multiple, (-w) % multiple
    if ph == 0 and pw == 0:
        return x
    return F.pad(x, (0, pw, 0, ph), mode="replicate")


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
