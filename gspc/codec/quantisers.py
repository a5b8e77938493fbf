"""The attribute codec's quantisers: each owns its quantise (encoder, float -> int), its exact dequantise
(decoder, int -> float32, the same on every machine) and its cell (the box of values that quantise to the
decoded one, which refinement stays inside: gspc/codec/cells.py).

Dequantisation runs in float64 with correctly rounded operations and casts to float32 at the end (spec 10.0).
Smallest-three quaternion decoding (:func:`place_largest`) is shared with the SOG and compressed-PLY readers
(gspc/io/), which store rotations the same way at other precisions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from gspc.codec.entropy import SYMBOL_LIMIT
from gspc.errors import CodecError
from gspc.format.attribute_section import AttributeSection, ClassSteps

SQRT_HALF = 0.7071067811865476  # float64 nearest to 1/sqrt(2)
_LN2 = 0.6931471805599453
OPACITY_FLOOR = 1.0 / 255.0  # the encoder prunes Gaussians under this alpha

Box = tuple[torch.Tensor, torch.Tensor]  # (lo, hi), shaped like the attribute
# The kept components (w, x, y, z order) when the one at each index is dropped.
OTHERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


def det_log(x: np.ndarray) -> np.ndarray:
    """Natural log of positive float64 values using only correctly rounded IEEE operations."""
    m, e = np.frexp(np.asarray(x, np.float64))
    small = m < SQRT_HALF
    m = np.where(small, m * 2.0, m)
    e = np.where(small, e - 1, e).astype(np.float64)
    t = (m - 1.0) / (m + 1.0)  # |t| <= 0.1716
    t2 = t * t
    acc = np.zeros_like(t)
    for k in range(27, 0, -2):  # atanh series, Horner from the highest term
        acc = acc * t2 + 1.0 / k
    return 2.0 * t * acc + e * _LN2


def place_largest(index: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4) float64 in w, x, y, z order from smallest-three form: the three kept
    components ``rest`` (n, 3) in order, and the dropped largest at ``index``, recomputed as
    ``sqrt(max(1 - ((a a + b b) + c c), 0))`` (this summation order is the spec's)."""
    ss = (rest[:, 0] * rest[:, 0] + rest[:, 1] * rest[:, 1]) + rest[:, 2] * rest[:, 2]
    out = np.zeros((len(rest), 4))
    out[np.arange(len(rest)), index] = np.sqrt(np.maximum(1.0 - ss, 0.0))
    np.put_along_axis(out, OTHERS[index], rest, axis=1)
    return out


def out_of_range(
    values: np.ndarray, steps: np.ndarray | float, rows: np.ndarray | None = None
) -> tuple[int, float]:
    """(how many, largest |value|) of the Gaussians ``values[rows]`` with a component beyond SYMBOL_LIMIT
    steps (``steps`` broadcasts against a block of rows): their symbols would outgrow an entropy model's
    window (gspc/codec/entropy.py), and a float beyond int64 would wrap when cast. In blocks of rows."""
    rows = np.arange(len(values)) if rows is None else np.asarray(rows)
    count, worst = 0, 0.0
    for a in range(0, len(rows), SH_REST_BLOCK):
        x = np.abs(values[rows[a : a + SH_REST_BLOCK]].astype(np.float64))
        over = (x / steps > SYMBOL_LIMIT).reshape(len(x), -1).any(axis=1)
        if over.any():
            count += int(over.sum())
            worst = max(worst, float(x[over].max()))
    return count, worst


def _around(x: torch.Tensor, half: torch.Tensor | float) -> Box:
    return x - half, x + half


@dataclass(frozen=True)
class UniformQuantiser:
    """``q = round(x / step)``, decoded ``q * step``; the cell is half a step either side."""

    step: float

    def quantise(self, x: np.ndarray) -> np.ndarray:
        return np.rint(x / self.step).astype(np.int64)

    def dequantise(self, q: np.ndarray) -> np.ndarray:
        return (q.astype(np.float64) * self.step).astype(np.float32)

    def cell(self, decoded: torch.Tensor) -> Box:
        return _around(decoded.detach().double(), self.step / 2)


@dataclass(frozen=True)
class OpacityQuantiser:
    """Activated opacity alpha in ``levels`` levels: ``q = round(alpha * L)``; decoded
    ``logit(clamp(q / L, 1/(4L), 1 - 1/(4L)))`` with :func:`det_log`."""

    levels: int

    def quantise(self, logits: np.ndarray) -> np.ndarray:
        alpha = 1.0 / (1.0 + np.exp(-logits))
        return np.rint(alpha * self.levels).astype(np.int64)

    def dequantise(self, q: np.ndarray) -> np.ndarray:
        a = q.astype(np.float64) / float(self.levels)
        a = np.clip(a, 0.25 / self.levels, 1.0 - 0.25 / self.levels)
        return (det_log(a) - det_log(1.0 - a)).astype(np.float32)

    def cell(self, decoded: torch.Tensor) -> Box:
        """alpha in [(q - 1/2) / L, (q + 1/2) / L], and pruning kept only alpha >= 1/255; as logits."""
        levels = self.levels
        q = torch.round(torch.sigmoid(decoded.detach().double()) * levels)
        lo = torch.clamp((q - 0.5) / levels, min=OPACITY_FLOOR)
        hi = torch.clamp((q + 0.5) / levels, max=1.0 - 1e-6)
        return torch.log(lo) - torch.log1p(-lo), torch.log(hi) - torch.log1p(-hi)


@dataclass(frozen=True)
class SmallestThreeQuantiser:
    """Unit quaternion as [index of the largest |component| (made positive), the other three in w, x, y, z
    order quantised over [-1/sqrt2, 1/sqrt2] in ``levels`` steps]; the largest is recomputed."""

    levels: int

    @property
    def step(self) -> float:
        return 2.0 * SQRT_HALF / self.levels

    def quantise(self, quats: np.ndarray) -> np.ndarray:
        q = quats / np.linalg.norm(quats, axis=1, keepdims=True)
        big = np.argmax(np.abs(q), axis=1)
        q = q * np.where(q[np.arange(len(q)), big] < 0, -1.0, 1.0)[:, None]
        rest = np.take_along_axis(q, OTHERS[big], axis=1)
        comp = np.clip(np.rint((rest + SQRT_HALF) / self.step), 0, self.levels).astype(np.int64)
        return np.concatenate([big[:, None].astype(np.int64), comp], axis=1)

    def dequantise(self, sym: np.ndarray) -> np.ndarray:
        big = sym[:, 0]
        if ((big < 0) | (big > 3)).any() or ((sym[:, 1:] < 0) | (sym[:, 1:] > self.levels)).any():
            raise CodecError("rotation symbols outside their range")
        rest = sym[:, 1:].astype(np.float64) * self.step - SQRT_HALF
        return place_largest(big, rest).astype(np.float32)

    def cell(self, decoded: torch.Tensor) -> Box:
        """The three smaller components within half a step, the largest within its derived error
        ``2 e (sqrt 3 + e)`` for a component error ``e`` (see :meth:`error_bound`); signed so the largest
        component is positive."""
        g = decoded.detach().double()
        unit = g / g.norm(dim=1, keepdim=True)
        big = unit.abs().argmax(dim=1, keepdim=True)
        unit = unit * torch.sign(unit.gather(1, big))
        e = 0.5 * self.step
        d = 2.0 * math.sqrt(3.0) * e * (math.sqrt(3.0) + math.sqrt(3.0) * e)
        # Where another component comes within two steps of the largest, the encoder may have called it
        # the largest: give it the largest's range too.
        near = unit.abs() >= unit.gather(1, big) - 2 * e
        lo, hi = _around(unit, torch.where(near, d, e))
        return lo.clamp(-1, 1), hi.clamp(-1, 1)

    def error_bound(self) -> float:
        """Largest rotation angle (radians) between a unit quaternion and its decoded version."""
        e = math.sqrt(3.0) * self.step / 2.0  # norm of the three components' rounding errors
        d = 2.0 * e * (math.sqrt(3.0) + e)  # error of the recomputed largest component (it is >= 1/2)
        chord = math.sqrt(e * e + d * d)
        return 4.0 * math.asin(min(1.0, chord / 2.0))


SH_REST_BLOCK = 1 << 16  # rows per block of SHRestQuantiser.quantise


@dataclass(frozen=True)
class SHRestQuantiser:
    """SH rest coefficients, one step per coefficient (``steps``, coefficient-major), rounded with a dead
    zone of ``deadzone`` extra steps towards zero (an encoder-only R-D choice)."""

    steps: tuple[float, ...]
    deadzone: float = 0.0

    def quantise(self, rest: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """(n, K, 3) -> (n, 3K) int32 symbols of ``rest[rows]`` (all rows without ``rows``); values within
        ``0.5 + deadzone`` steps of zero go to zero. The caller checks their range (:func:`out_of_range`)."""
        rows = np.arange(len(rest)) if rows is None else np.asarray(rows)
        out = np.empty((len(rows), 3 * len(self.steps)), np.int32)
        steps = np.asarray(self.steps)[None, :, None]
        # In blocks of rows, picked block by block: float64 temporaries of a whole SH-3 scene would set the
        # encoder's peak memory (bench/scale.md, "Reading").
        for a in range(0, len(rows), SH_REST_BLOCK):
            x = rest[rows[a : a + SH_REST_BLOCK]].astype(np.float64) / steps
            mag = np.maximum(np.floor(np.abs(x) + 0.5 - self.deadzone), 0.0)
            out[a : a + SH_REST_BLOCK] = (np.sign(x) * mag).reshape(len(x), -1)
        return out

    def dequantise(self, q: np.ndarray) -> np.ndarray:
        k = len(self.steps)
        steps = np.asarray(self.steps)[None, :, None]
        out = np.empty((len(q), k, 3), np.float32)
        for a in range(0, len(q), SH_REST_BLOCK):  # blocks: float64 of the whole is twice the output
            out[a : a + SH_REST_BLOCK] = q[a : a + SH_REST_BLOCK].reshape(-1, k, 3).astype(np.float64) * steps
        return out

    def cell(self, decoded: torch.Tensor, every_row_coded: bool = False) -> Box:
        """A whole step (the dead zone may round towards zero). Below version 4 a Gaussian without SH rest
        (all zero) may have been faint, whose SH rest the encoder drops whatever it was: no bound, unless
        ``every_row_coded`` (version 4 says which bands were coded: gspc/codec/cells.py)."""
        rest = decoded.detach().double()
        steps = torch.tensor([float(s) for s in self.steps], dtype=torch.float64, device=rest.device)
        half = steps[None, :, None].expand_as(rest)
        coded = (rest != 0).flatten(1).any(1)[:, None, None] | every_row_coded
        return _around(rest, torch.where(coded, half, torch.inf))


@dataclass(frozen=True)
class AttributeQuantisers:
    """Every attribute's quantiser, as an attribute codec header (spec 10.0) states them."""

    opacity: OpacityQuantiser
    scale: UniformQuantiser  # natural-log scales
    rotation: SmallestThreeQuantiser
    dc: UniformQuantiser
    sh_rest: SHRestQuantiser

    @classmethod
    def from_section(cls, section: AttributeSection, sh_deadzone: float = 0.0) -> AttributeQuantisers:
        """The quantisers an attribute codec header section states (checked where it was built); at version
        4, those of its class 0."""
        return cls.from_steps(section.base_class(), sh_deadzone)

    @classmethod
    def from_steps(cls, steps: ClassSteps, sh_deadzone: float = 0.0) -> AttributeQuantisers:
        """The quantisers of one precision class."""
        return cls(
            OpacityQuantiser(steps.opacity_levels),
            UniformQuantiser(steps.scale_step),
            SmallestThreeQuantiser(steps.rotation_levels),
            UniformQuantiser(steps.dc_step),
            SHRestQuantiser(steps.sh_steps, sh_deadzone),
        )
