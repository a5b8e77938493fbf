"""The attribute codec's parameters; the named rate points that set them are in gspc/presets.py.

Every quantisation step is ``base_step * lam`` (scales and rotations: ``geometry_lam`` beyond lam 8, SH
rest: ``lam ** sh_lam_exponent``): ``lam`` is the one continuous rate knob (larger is smaller and coarser).
Position precision follows ``lam`` unless set: 14 bits per axis at lam = 1, one bit less per doubling of lam,
within 11..16, fractional in between (a step between two whole-bit grids). The base steps and the bit
schedule give every group about the same dB per byte near SPZ's quality on the lego fit (bench/codec.md,
"Moved from code comments").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from gspc.encoder.precision_plan import PrecisionParams
from gspc.errors import InputError


@dataclass(frozen=True)
class SHRules:
    """How the encoder drops view-dependent colour, each an encoder-only choice: a Gaussian's SH band is kept
    where it moves the views by ``keep`` of its coded steps (PrecisionParams.sh_keep; 0: every band), the SH
    rest rounds ``deadzone`` extra steps towards zero (CodecParams.sh_deadzone), and a Gaussian whose alpha
    is under ``faint_alpha`` x lambda carries none (CodecParams.sh_faint_alpha; 0: every Gaussian has
    one). ``codebook``: the SH rest by a codebook of at most this many entries (CodecParams.sh_codebook; 0:
    none; how many the rate asks for: gspc/encoder/codebook.py), each Gaussian that keeps any band taking
    all of its entry's."""

    keep: float
    deadzone: float
    faint_alpha: float
    codebook: int = 0

    def words(self) -> str:
        bands = "every SH band kept" if self.keep == 0 else f"SH bands kept from {self.keep:g} steps"
        faint = ", faint Gaussians' too" if self.faint_alpha == 0 else ""
        if self.codebook:
            return f"SH rest by a codebook of up to {self.codebook:,} entries{faint}"
        zone = "no" if self.deadzone == 0 else f"a {self.deadzone:g}"
        return f"{bands}{faint}, {zone} dead zone"


@dataclass(frozen=True)
class CodecParams:
    lam: float = 1.0
    position_bits: float | None = None  # None: follow lam (see position_precision)
    # Bits per axis added to that (negative: coarser); an encoder choice per scene at equal bytes
    # (gspc/encoder/removal.py): the captures want coarser positions than the statues (bench/precision.md,
    # "Position precision chosen per scene").
    position_offset: float = 0.0
    keep_invisible: bool = False  # keep Gaussians no view sees
    keep_transparent: bool = False  # keep Gaussians with activated opacity below 1/255
    # Base steps at lam = 1, each in the domain where its error is least visible.
    opacity_step: float = 0.006  # activated opacity (alpha)
    scale_step: float = 0.021  # natural-log scale: a relative size error of half a step either way
    rotation_step: float = 0.005  # smallest-three quaternion components
    dc_step: float = 0.0085  # SH DC coefficient (colour = 0.5 + 0.282 * dc)
    sh_step: float = 0.02  # SH rest coefficients of degree 1 ...
    # ... times this per further degree (bench/codec.md, "Moved from code comments")
    sh_degree_growth: float = 1.2
    # SH rest steps grow as lam ** this, slower than the others: on an SH-3 lego fit, view-dependent
    # colour limits PSNR at low rates while geometry can coarsen further (bench/codec.md).
    sh_lam_exponent: float = 0.5
    sh_deadzone: float = 0.2  # rounding offset towards zero for SH rest (encoder-only R-D choice)
    # Gaussians whose decoded alpha is below this * lam (at most 0.5) get no SH rest (encoder-only
    # R-D choice): a nearly transparent Gaussian's view-dependent colour is invisible, and the lego fit holds
    # many of them (bench/codec.md, "Moved from code comments").
    sh_faint_alpha: float = 0.02
    # The SH rest by a codebook of at most this many entries, fewer at coarser rates (attribute codec version
    # 5, gspc/encoder/codebook.py; per-Gaussian precision only; 0: coefficient by coefficient): an encoder
    # choice per scene (gspc/encoder/removal.py).
    sh_codebook: int = 0
    # Beyond lam = geometry_knee, scale and rotation steps grow as sqrt(lam), not as lam: a log-scale step in
    # proportion to lam inflates large Gaussians until the scene collapses at coarse rates, and the slower
    # growth costs the lego fit, which tolerates coarse geometry, little (bench/codec.md, "Moved from code
    # comments").
    geometry_knee: float = 8.0
    geometry_lam_exponent: float = 0.5
    # A file the decoder decodes as it is (no side information, so no refinement) wants finer scales and
    # rotations at low rates (as lam^(1/4) from lam 6, per-Gaussian precision on); a file the decoder refines
    # wants the coarser cells above, in which refinement recovers more (bench/precision.md, "Geometry steps
    # beyond lambda 6").
    unrefined_knee: float = 6.0
    unrefined_lam_exponent: float = 0.25
    # Per-Gaussian precision (attribute codec version 4, gspc/encoder/precision_plan.py) where the encoder has
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
        lambda without a jump (a --target-size window inside a jump would have no lambda), at about the bytes
        of whole bits at equal PSNR (bench/precision.md, "Sensitivity per coded component")."""
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

    @property
    def sh_rules(self) -> SHRules | None:
        """The rules these parameters drop view-dependent colour by (None: no per-Gaussian precision)."""
        if self.precision is None:
            return None
        return SHRules(self.precision.sh_keep, self.sh_deadzone, self.sh_faint_alpha, self.sh_codebook)

    def with_sh_rules(self, rules: SHRules) -> CodecParams:
        """These parameters dropping view-dependent colour by ``rules`` (per-Gaussian precision only)."""
        if self.precision is None:
            raise InputError("SH rules need per-Gaussian precision")
        precision = replace(self.precision, sh_keep=rules.keep)
        faint, book = rules.faint_alpha, rules.codebook
        return replace(
            self, precision=precision, sh_deadzone=rules.deadzone, sh_faint_alpha=faint, sh_codebook=book
        )

    def with_lambda(self, lam: float) -> CodecParams:
        if not lam > 0:
            raise InputError(f"rate knob lambda must be positive, got {lam}")
        return replace(self, lam=float(lam))
