"""Named quality presets: ONE table for the whole encoder (attribute codec + side information).

Like CompressAI's zoo: a preset is a name for a complete, versioned configuration, built by keyword; the
command line's options override single fields (gspc/options.py). This module imports no torch.
"""

from __future__ import annotations

from dataclasses import dataclass

from gspc.codec.params import CodecParams
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


# Attribute rate points: lam 1 (14 position bits) and lam 8 (11 position bits; <= 10 B/G on the SH-3 lego
# fit; gspc/codec/params.py).
# Side information measured on the lego fit (tools/bench_pipeline.py): at the low preset, residuals at half
# resolution and distance 8 (~24 KB for 35 views) beat spending those bytes on attributes; at the high preset
# residuals mostly fall under the skip threshold and cost nothing.
# Refinement at the low preset (inside the quantisation cells, gspc/reconstruct.py's schedule): on the lego
# fit 300 iterations gain 3.7 dB over the coded scene, as much as 1000 at the schedule before (INRIA's rates
# throughout: 300 gained 2.6, 1000 3.5, 3000 3.3 then: bench/pipeline.md); on the statue massa 255 gain more
# than 852 (bench/refine.md). The high preset's side information is mostly skipped (residuals under the
# threshold); its length was cut in the same proportion.
# The encoder also weighs residuals at half this resolution (gspc/encoder/policy.py, REFINE_TRANSFER).
QUALITY: dict[str, Preset] = {
    "low": Preset(
        attributes=CodecParams(lam=8.0),
        residual_codec="jxl",
        residual_distance=8.0,
        residual_scale=2,
        refine_iterations=300,
    ),
    "high": Preset(
        attributes=CodecParams(lam=1.0),
        residual_codec="jxl",
        residual_distance=4.0,
        residual_scale=1,
        refine_iterations=100,
    ),
}


# Refinement costs about Gaussians x iterations (an iteration renders every Gaussian a view holds, and Adam
# steps every attribute: bench/scale.md). A scene larger than REFINE_WORK / (the preset's iterations)
# Gaussians gets REFINE_WORK / N iterations instead, never fewer than MIN_SCALED_ITERATIONS: 150 at 100k
# Gaussians, 50 from 300k (bench/scale_pipeline.md measures time and quality against iterations). It was
# 5e7 with the preset's 1000 iterations: cut with them, so every scene gets 0.3x the iterations it had.
REFINE_WORK = 15_000_000
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
