"""The attribute codec's parameters; the named rate points that set them are in gspc/presets.py.

Every quantisation step is ``base_step * lam`` (scales and rotations: ``geometry_lam`` beyond lam 8, SH
rest: ``lam ** sh_lam_exponent``): ``lam`` is the one continuous rate knob (larger is smaller and coarser).
Position precision follows ``lam`` unless set: 14 bits per axis at lam = 1, one bit less per doubling of lam,
within 11..16, fractional in between (a step between two whole-bit grids). The base steps and the bit
schedule first equalised the marginal dB per byte of every group on donut (lam = 2, 6 views at 192 px); they
were then retuned at the lego fit's SPZ-equal point (~40 dB, lam ~ 7): one bit fewer for positions,
scale/rotation/DC steps x1.2-1.25 (bytes at equal PSNR vs SPZ-style 0.498 -> 0.479, tools/bench_codec.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from gspc.codec.precision import PrecisionParams
from gspc.errors import InputError


@dataclass(frozen=True)
class CodecParams:
    lam: float = 1.0
    position_bits: float | None = None  # None: follow lam (see position_precision)
    # Bits per axis added to that (negative: coarser); an encoder choice per scene at equal bytes
    # (gspc/encoder/removal.py): the captures want coarser positions than the statues.
    position_offset: float = 0.0
    keep_invisible: bool = False  # keep Gaussians no view sees
    keep_transparent: bool = False  # keep Gaussians with activated opacity below 1/255
    # Base steps at lam = 1, each in the domain where its error is least visible.
    opacity_step: float = 0.006  # activated opacity (alpha)
    scale_step: float = 0.021  # natural-log scale: a relative size error of +-1.05%
    rotation_step: float = 0.005  # smallest-three quaternion components
    dc_step: float = 0.0085  # SH DC coefficient (colour = 0.5 + 0.282 * dc)
    sh_step: float = 0.02  # SH rest coefficients of degree 1 ...
    sh_degree_growth: float = 1.2  # ... times this per further degree (lego: 1.2 beat 1.5 and 2)
    # SH rest steps grow as lam ** this, slower than the others: on an SH-3 lego fit, view-dependent
    # colour limits PSNR at low rates while geometry can coarsen further (bench/codec.md).
    sh_lam_exponent: float = 0.5
    sh_deadzone: float = 0.2  # rounding offset towards zero for SH rest (encoder-only R-D choice)
    # Gaussians whose decoded alpha is below this * lam (at most 0.5) get no SH rest (encoder-only
    # R-D choice): on the lego fit 40% of Gaussians are under 0.05 opaque and their view-dependent
    # colour is invisible, yet it cost a third of the SH rest bytes.
    sh_faint_alpha: float = 0.02
    # Beyond lam = geometry_knee, scale and rotation steps grow as sqrt(lam) instead of lam: a log-scale
    # step of 0.021 * lam inflates large Gaussians until the scene collapses (donut, lam 64: 22.8 dB, with
    # exact scales 36.3). Measured at equal bytes: donut +0.7 dB at lam 12 to +2.4 at lam 64; the lego fit,
    # which tolerates coarse geometry, -0.05 dB at lam 12-16 and -0.2 at lam 32-64.
    geometry_knee: float = 8.0
    geometry_lam_exponent: float = 0.5
    # A file the decoder decodes as it is (no side information, so no refinement) wants finer scales and
    # rotations at low rates: as lam^(1/4) from lam 6, per-Gaussian precision on, bytes at equal PSNR at lam
    # 10-16 -2..-10% on the bird fit, -1..-7% on lego and two statues (most at twice the views' size), the
    # same up to lam 6. A file the decoder refines wants the cells above: refinement recovers more in
    # them (lego example: 40.38 dB against 38.88 at 0.97x the bytes; bench/precision.md).
    unrefined_knee: float = 6.0
    unrefined_lam_exponent: float = 0.25
    # Per-Gaussian precision (attribute codec version 4, gspc/codec/precision.py) where the encoder has
    # measured what each Gaussian does to its views; None: every Gaussian at the rate's steps.
    precision: PrecisionParams | None = None

    @property
    def geometry_lam(self) -> float:
        """The multiplier of the scale and rotation base steps (``lam`` up to the knee)."""
        if self.lam <= self.geometry_knee:
            return self.lam
        return self.geometry_knee * (self.lam / self.geometry_knee) ** self.geometry_lam_exponent

    @property
    def position_precision(self) -> float:
        """Bits per axis ``p`` of the positions' grid over their extent (cubic voxels, as many as ``2^p - 1``
        steps per axis make: gspc/codec/positions.py). Fractional between whole bits, so that sizes follow
        lambda without a jump: rounded to whole bits, sizes jumped a few % at lam 2^(k + 1/2), and a
        --target-size window inside a jump had no lambda. At equal PSNR the rounded schedule's bytes were
        within 1.4% of these either way (lam 3-6, three statues, lego, the bird fit; bench/precision.md)."""
        rate = min(16.0, max(11.0, 14.0 - math.log2(self.lam)))
        bits = rate if self.position_bits is None else self.position_bits
        return max(1.0, float(bits) + self.position_offset)

    def unrefined(self) -> CodecParams:
        """These parameters for a file without side information (see ``unrefined_knee``); the uniform codec
        (no precision) keeps its steps."""
        if self.precision is None:
            return self
        knee, exponent = self.unrefined_knee, self.unrefined_lam_exponent
        return replace(self, geometry_knee=knee, geometry_lam_exponent=exponent)

    def with_lambda(self, lam: float) -> CodecParams:
        if not lam > 0:
            raise InputError(f"rate knob lambda must be positive, got {lam}")
        return replace(self, lam=float(lam))
