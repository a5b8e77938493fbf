"""Named quality presets: ONE table for the whole encoder (attribute codec + side information).

Like CompressAI's zoo: a preset is a name for a complete, versioned configuration, built by keyword; the
command line's options override single fields (gspc/options.py). This module imports no torch.
"""

from __future__ import annotations

from dataclasses import dataclass

from gspc.codec.params import CodecParams
from gspc.codec.precision import PrecisionParams
from gspc.errors import InputError

# The restorer an encoder names by default. Held out of its training, low preset, per restored view over
# I~ + R~: the real capture's 23 test views +0.84 dB, lego fit +0.33, statue massa +0.28 (bench/restorer.md).
# "none" is the paper's side-information-only mode.
DEFAULT_RESTORER = "nafnet-s16-v3"


@dataclass(frozen=True)
class Preset:
    attributes: CodecParams
    residual_codec: str = "jxl"  # one of gspc.codec.residuals.IMAGE_CODECS
    residual_distance: float = 4.0  # the residual image codecs' rate knob (larger is coarser)
    residual_scale: int = 1  # residuals coded at 1/scale resolution
    refine_iterations: int = 300  # the decoder's refinement, validated by the encoder's check
    # Iterations of the encoder's tuning of its coded values (gspc/encoder/tuning.py; 0: none). Four gave the
    # statue angel +1.29 / +1.50 dB (1x / 2x) at the low preset, eight +1.39 / +1.59 in twice the time; the
    # bird reached its byte limit in four (bench/tuning.md).
    tune_iterations: int = 4
    # The encoder's search then tries the position grid this many bits per axis finer (+) or coarser (-),
    # each in the same bytes, kept where views between its cameras show it closer (gspc/encoder/removal.py).
    # At the low preset the trained captures take a bit coarser and the statues keep the rate's grid; at the
    # high preset's rate the statues take a bit finer (four of five, at 0.96-0.99 of the bytes at equal PSNR
    # at 1x) and the captures keep it (bench/precision.md, "Position precision chosen per scene" and "The
    # high preset's positions chosen per scene too").
    position_offsets: tuple[float, ...] = (-1.0,)


# Attribute rate points: lam 1 (14 position bits) and lam 8 (11 position bits; <= 10 B/G on the SH-3 lego
# fit; gspc/codec/params.py).
# Side information measured on the lego fit (tools/bench_pipeline.py): at the low preset, residuals at half
# resolution and distance 8 (~24 KB for 35 views) beat spending those bytes on attributes; at the high preset
# residuals mostly fall under the skip threshold and cost nothing.
# Refinement at the low preset (inside the quantisation cells, gspc/reconstruct.py's schedule), held-out
# views against the original's renders (bench/refine.md): the lego fit 39.57 dB as coded, 43.23 after 300
# iterations, where the schedule before reached 43.05 in 1000 (42.13 in 300); the statue massa 48.51 as
# coded, 50.25 after 257, where 857 reached 50.05. The high preset's side information is mostly skipped
# (residuals under the threshold); its length was cut in the same proportion.
# The encoder also weighs residuals at half this resolution (gspc/encoder/policy.py, CheckPolicy).
# Per-Gaussian precision (attribute codec version 4, gspc/codec/precision.py), chosen codec alone on lego,
# the statue massa, the bird capture and massa inside shells of sky-sized Gaussians (bench/precision.md,
# "Choosing the presets' parameters"): step classes 2^-3 .. 2^2 of the rate's, centred 1.5 octaves coarse; SH
# bands kept where they move the views by 4 of their steps; Gaussians painting under lambda / 50 of the
# median's blending weight removed (a fifth at lambda 10; in proportion to lambda so that the finer rates
# reach SPZ's quality on every statue). Against the uniform codec at equal PSNR: the bird about 0.5x the
# bytes, lego 0.85x, massa 0.7x. A finest class of 2^-1 coded lego 10% smaller but lost 6 dB on the shells.
# The classed codec reaches a PSNR at other lambdas than the uniform one, and differently by scene; the low
# preset's lambda rose from 8 to 10 (the statues' whole files under 6 B/G). The high preset removes nothing
# and keeps more SH.
# Then (bench/precision.md, "Sensitivity per coded component, classes of their own size"): classes under 256
# Gaussians merge towards the rate's steps (lego -2.5% bytes at equal PSNR); at the low preset the SH rest
# counts per coefficient and each Gaussian per coded component (lego -5..-8%, the bird even over its curve)
# and the finest class is 2^-4 (the statues -1..-2%, the shells' object 1.5-1.7 dB closer at cover 1; 2^-5
# cost the bird 1-2%). At the high preset's rates the bird lost 5.7% counting per component: it counts as
# before. Beyond 2^-4 the low preset's classes go on at half the rule's pace, to 2^-7 (``tail``): a sky
# of large Gaussians sat at that floor, one class finer for it alone +1.1 dB for 1.4% more bytes
# (bench/precision.md). Removal at lambda x 3.5 / 100 of the median's weight (was 2 / 100) and lambda 8 (was
# 10): the bird, lego and the five statues 2-7% fewer bytes at equal PSNR; at the preset every statue codes
# 0.6-1.5% fewer bytes 0.3-0.7 dB closer (1x), the bird +1.5 dB for 1.9% more (bench/precision.md).
# That removal is the least a scene gets: the encoder tries two, four and eight times it, each in the same
# bytes, and keeps the strongest that views between its cameras show closer (gspc/encoder/removal.py; the
# bird and lego take eight times, the statues and shells keep this).
LOW_PRECISION = PrecisionParams(exponents=(-7, 2), bias=1.5, sh_keep=4.0, prune=0.035, min_class=256, tail=-4)
# The high preset's classes go on past 2^-3 at half the rule's pace as well, to 2^-7: at lambda 0.7-1 the
# bird, massa and trumpet code the same PSNR in 0.93-0.98 of the bytes, lego in 1.004-1.006, and massa inside
# shells of sky-sized Gaussians gains 4.8 dB (cover 1) and 1.8 dB (cover 0.1) for 1-2% more bytes; a tail
# from 2^-2 suited lego (0.98) but not the statues (1.005-1.03), a floor at 2^-5 without one neither the bird
# nor lego (1.02-1.03). Past lambda 3 the tail costs the bird 0.5-3% (the low preset's rates); a coarsest
# class of 2^3 fell off a cliff there (the bird 10 dB lower at lambda 8) (bench/precision.md, "The high
# preset's classes past 2^-3").
HIGH_PRECISION = PrecisionParams(
    exponents=(-7, 2), bias=1.0, sh_keep=2.0, prune=0.0, min_class=256, per_component=False, tail=-3
)
QUALITY: dict[str, Preset] = {
    "low": Preset(
        attributes=CodecParams(lam=8.0, precision=LOW_PRECISION),
        residual_codec="jxl",
        residual_distance=8.0,
        residual_scale=2,
        refine_iterations=300,
    ),
    "high": Preset(
        attributes=CodecParams(lam=1.0, precision=HIGH_PRECISION),
        residual_codec="jxl",
        residual_distance=4.0,
        residual_scale=1,
        refine_iterations=100,
        position_offsets=(1.0,),
    ),
}


# Refinement costs about Gaussians x iterations (an iteration renders every Gaussian a view holds, and Adam
# steps every attribute: bench/scale.md). A scene larger than REFINE_WORK / (the preset's iterations)
# Gaussians gets REFINE_WORK / N iterations instead, never fewer than MIN_SCALED_ITERATIONS: 300 up to 500k
# Gaussians, 150 at 1M, 50 from 3M. With gspc/reconstruct.py's schedule the 100k bird fit needs its 300: 153
# iterations reached 43.58 dB against the original's renders where the schedule before reached 44.71 in 511,
# and 300 reach 45.14 (bench/refine.md). The 1M scale scene (778,599 Gaussians coded) gained on held-out
# views 0.34, 0.54, 0.64 and 0.68 dB over its coded 40.87 at 50, 100, 150 and 200 iterations (the same
# per-step rates), about 0.65 CPU s each on one core (bench/scale_pipeline.md, "More iterations at 1M"):
# 30M, its budget before, gave it 50.
REFINE_WORK = 150_000_000
MIN_SCALED_ITERATIONS = 50


def refine_iterations_for(preset_iterations: int, num_gaussians: int) -> int:
    """The preset's refinement length for a scene of ``num_gaussians`` (see REFINE_WORK)."""
    if preset_iterations <= MIN_SCALED_ITERATIONS:
        return preset_iterations
    scaled = REFINE_WORK // max(num_gaussians, 1)
    return int(min(preset_iterations, max(MIN_SCALED_ITERATIONS, scaled)))


def quality_preset(name: str) -> Preset:
    try:
        return QUALITY[name]
    except KeyError:
        raise InputError(f"unknown quality preset {name!r}; choose one of {', '.join(QUALITY)}") from None
