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
# Refinement at the low preset (inside the quantisation cells): on the lego fit 300 iterations gain 2.3 dB
# over the coded scene, 1000 gain 3.1 and 3000 gain 3.3 (bench/pipeline.md); 1000 is where side information
# clearly beats spending its bytes on attributes, at about 0.16 s per iteration for 20k Gaussians on one core.
# The encoder also weighs residuals at half this resolution (gspc/encoder/policy.py, REFINE_TRANSFER).
QUALITY: dict[str, Preset] = {
    "low": Preset(
        attributes=CodecParams(lam=8.0),
        residual_codec="jxl",
        residual_distance=8.0,
        residual_scale=2,
        refine_iterations=1000,
    ),
    "high": Preset(
        attributes=CodecParams(lam=1.0),
        residual_codec="jxl",
        residual_distance=4.0,
        residual_scale=1,
        refine_iterations=300,
    ),
}


# Refinement costs about Gaussians x iterations (an iteration renders every Gaussian a view holds, and Adam
# steps every attribute: bench/scale.md). A scene larger than REFINE_WORK / (the preset's iterations)
# Gaussians gets REFINE_WORK / N iterations instead, never fewer than MIN_SCALED_ITERATIONS: about 140 at
# 350k Gaussians and 50 at 1M, which keeps the default encode and decode of a million-Gaussian scene on one
# core within 20 minutes (bench/scale_pipeline.md measures time and quality against iterations).
REFINE_WORK = 50_000_000
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
