"""Named quality presets: ONE table for the whole encoder (attribute codec + side information).

Like CompressAI's zoo: a preset is a name for a complete, versioned configuration, built by keyword; the
command line's options override single fields (gspc/options.py). This module imports no torch.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from gspc.encoder.params import CodecParams, SHRules
from gspc.encoder.precision_plan import PrecisionParams
from gspc.errors import InputError

# The restorer an encoder names by default: on scenes held out of its training it brings the restored views
# closer than I~ + R~ alone (bench/restorer.md, "Restoration of held-out views"). "none" is the paper's
# side-information-only mode.
DEFAULT_RESTORER = "nafnet-s16-v3"


@dataclass(frozen=True)
class Preset:
    # The rate its search starts at, and the rate --lambda replaces (which then codes at the rate, no search).
    attributes: CodecParams
    # The fidelity its attributes are coded to: PSNR in dB of the attributes as they decode against the
    # original's renders at views between the encoder's cameras (gspc/encoder/fidelity.py), searched for the
    # fewest bytes that reach it; None: coded at the rate.
    target_db: float | None = None
    # The size the search stays within, in bytes per Gaussian given: a scene whose target needs more is coded
    # at the closest fidelity within it, and its summary says so.
    max_bytes_per_gaussian: float = 64.0
    residual_codec: str = "jxl"  # one of gspc.codec.residuals.IMAGE_CODECS
    residual_distance: float = 4.0  # the residual image codecs' rate knob (larger is coarser)
    # Residuals coded at 1/scale resolution; the encoder's check also weighs them at twice this scale
    # (gspc/encoder/prepare.py, side_candidates).
    residual_scale: int = 1
    refine_iterations: int = 300  # the decoder's refinement, validated by the encoder's check
    # Iterations of the encoder's tuning of its coded values (gspc/encoder/tuning.py; 0: none): eight gain
    # little over four for twice the time (bench/tuning.md, "Gain and cost by scene").
    tune_iterations: int = 4
    # The encoder's search then tries the position grid this many bits per axis finer (+) or coarser (-),
    # each in the same bytes, kept where views between its cameras show it closer (gspc/encoder/removal.py):
    # at the low preset's rate the trained captures take a bit coarser, at the high preset's the statues a
    # bit finer (bench/precision.md, "Position precision chosen per scene" and "The high preset's positions
    # chosen per scene too").
    position_offsets: tuple[float, ...] = (-1.0,)
    # Then, where the scene has view-dependent colour, every SH band of every Gaussian (faint ones too)
    # without a dead zone, in the same bytes, kept where the same views show it closer: at the low preset's
    # rate, where keeping the faint Gaussians' too gained over every band alone (gspc/encoder/removal.py;
    # bench/precision.md, "SH choices checked per scene"); then the SH rest by a codebook of up to 4,096
    # entries (attribute codec version 5), kept the same way: the lego fit codes closer with it, the glossy
    # objects without (bench/precision.md, "The SH rest by codebook"). The high preset's finer steps keep
    # both off.
    sh_options: tuple[SHRules, ...] = (SHRules(0.0, 0.0, 0.0), SHRules(4.0, 0.0, 0.02, 4096))
    # Whether the encoder weighs side information at all: a file for viewers, which draw the attributes as
    # they decode (no restorer, no refinement), carries none and has its coded values tuned instead.
    side_info: bool = True


# The low preset's per-Gaussian precision (gspc/encoder/precision_plan.py), chosen codec alone on the
# captures, the statues and the shells of sky-sized Gaussians (bench/precision.md):
# - classes up to 2^2 of the rate's steps, centred 1.5 octaves coarse: fewer bytes at equal PSNR than the
#   uniform codec on every scene ("Choosing the presets' parameters"); a coarsest class of 2^3 cost more
#   ("The high preset's classes past 2^-3");
# - finer than 2^-4 at half the rule's pace (``tail``), to 2^-7: a sky of large Gaussians sat at a hard floor
#   there ("The shells' loss taken apart");
# - SH bands kept where they move the views by 4 of their coded steps ("Choosing the presets' parameters");
# - a class under 256 Gaussians merged towards the rate's steps: each class's models cost bytes whatever its
#   rows ("Sensitivity per coded component");
# - removal under 3.5 lambda / 100 of the median's blending weight, at lambda 8: the statues' bytes at
#   equal PSNR still fall there and turn at more ("The shells' loss taken apart"). It is the least a scene
#   gets: the encoder tries two, four and eight times it in the same bytes and keeps what views between its
#   cameras show closer, which the captures take (gspc/encoder/removal.py; "Removal chosen per scene").
LOW_PRECISION = PrecisionParams(exponents=(-7, 2), bias=1.5, sh_keep=4.0, prune=0.035, min_class=256, tail=-4)
# The high preset's classes go on past 2^-3 at half the rule's pace as well, to 2^-7: at its rates the bird
# and the statues code the same PSNR in fewer bytes and the shells' sky comes much closer; measured again
# there, no alternative to its bias or its whole-group count (per_component off) gains on every scene; it
# removes nothing (bench/precision.md, "The high preset's classes past 2^-3").
HIGH_PRECISION = PrecisionParams(
    exponents=(-7, 2), bias=1.0, sh_keep=2.0, prune=0.0, min_class=256, per_component=False, tail=-3
)
# Each preset aims at a fidelity (PSNR of the attributes as they decode, against the original's renders at
# views between the encoder's cameras): at one rate the benches' scenes lie far apart in it
# (bench/precision.md, "Presets that aim at a fidelity"). The measure is the attributes' because every
# decoder shows them (a viewer draws them as they decode; gspc's refinement only adds), and the views lie
# between the cameras because the encoder's choices are fitted to the cameras themselves. Targets 6 dB
# apart: each halves the previous one's RMS error. The stated sizes: low's about SPZ v4's bytes at SH 3,
# above what the glossy SH-3 object needs for its target (the same section); medium's and high's twice and
# four times it.
#
# The rates the searches start at, and what --lambda replaces: lam 8, 3 and 1 (11 and 14 position bits per
# axis at 8 and 1: gspc/encoder/params.py). At the low preset's rate, residuals at half resolution and
# distance 8 buy more than the same bytes spent on attributes; at the high preset's most fall under the skip
# threshold (bench/pipeline.md, "Moved from code comments"). The low preset's 300 refinement iterations
# follow gspc/reconstruct.py's schedule (bench/refine.md, "Summary"); the high preset has little side
# information to refine on, so it refines for a third as long. Medium is low's configuration aimed higher.
LOW = Preset(
    attributes=CodecParams(lam=8.0, precision=LOW_PRECISION),
    target_db=44.0,
    max_bytes_per_gaussian=32.0,
    residual_codec="jxl",
    residual_distance=8.0,
    residual_scale=2,
    refine_iterations=300,
)
QUALITY: dict[str, Preset] = {
    "low": LOW,
    "medium": replace(
        LOW, attributes=replace(LOW.attributes, lam=3.0), target_db=50.0, max_bytes_per_gaussian=64.0
    ),
    "high": Preset(
        attributes=CodecParams(lam=1.0, precision=HIGH_PRECISION),
        target_db=56.0,
        max_bytes_per_gaussian=128.0,
        residual_codec="jxl",
        residual_distance=4.0,
        residual_scale=1,
        refine_iterations=100,
        position_offsets=(1.0,),
        sh_options=(),
    ),
    # The low preset for viewers (web/, SPZ and glb outputs): what a viewer shows is the attributes as they
    # decode, so no side information and the values tuned for that (bench/web.md, "What a viewer shows").
    "web": replace(LOW, side_info=False),
}
# A preset's search ends at a coding this far above its target: within half a dB, in fewer codings than
# --target-psnr's tenth.
PRESET_TOLERANCE_DB = 0.5


# Refinement costs about Gaussians x iterations (an iteration renders every Gaussian a view holds, and Adam
# steps every attribute: bench/scale.md). A scene larger than REFINE_WORK / (the preset's iterations)
# Gaussians gets REFINE_WORK / N iterations instead, never fewer than MIN_SCALED_ITERATIONS: 300 up to 500k
# Gaussians, 150 at 1M, 50 from 3M. The 100k bird fit needs its full 300 (bench/refine.md, "bird fit"); the 1M
# scale scene still gains with every iteration up to 200 at the same per-step rates (bench/scale_pipeline.md,
# "More iterations at 1M").
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
