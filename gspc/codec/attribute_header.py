"""The attribute codec's header section (spec 10.0, ``meta["attributes"]``): its versions, limits and the
one check of its fields, run by the decoder (gspc/codec/attributes.py) and by the typed file header
(gspc/format/header.py) before any payload is touched. No torch here: ``gspc info`` reads headers.
"""

from __future__ import annotations

import math

from gspc.codec import positions as pos
from gspc.errors import CodecError

FORMAT_VERSION = 1
# Version 2: the position grid may lie in contracted space (positions.py, spec 10.1); written only then, so
# bounded scenes keep version 1 and their bytes. Version 3: a contracted grid with a far set coded on a
# coarser grid (positions.py); written only where one pays.
CONTRACTED_VERSION = 2
FAR_VERSION = 3
VERSIONS = (FORMAT_VERSION, CONTRACTED_VERSION, FAR_VERSION)
MAX_GAUSSIANS = 1 << 26
# A Gaussian whose every symbol has a one-value model costs no bits, so the count alone could ask for any
# allocation from a tiny file; spec 10.0 caps it at 64 per payload byte (real files: under 1 per byte).
GAUSSIANS_PER_BYTE = 64


def _is_int(x: object) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _is_step(x: object) -> bool:
    return isinstance(x, float) and math.isfinite(x) and x > 0


def check_attribute_header(meta: dict) -> None:
    """Every field of the attribute codec's section, typed and in range; CodecError naming the first bad."""
    try:
        version = meta["version"]
        if not _is_int(version) or version not in VERSIONS:
            raise CodecError(f"attribute codec version {version} is not supported")
        n, degree = meta["n"], meta["sh_degree"]
        grid = meta["position"]
        bits, lo, step = grid["bits"], list(grid["lo"]), list(grid["step"])
        opacity_levels, rot_levels = meta["opacity_levels"], meta["rotation_levels"]
        scale_step, dc_step = meta["scale_step"], meta["dc_step"]
        sh_steps = list(meta["sh_steps"])
        if (version != FORMAT_VERSION) != pos.is_contracted(grid) or ("centre" in grid) != ("radius" in grid):
            raise CodecError("attribute codec version and position grid disagree on contraction")
        if (version == FAR_VERSION) != ("far_count" in grid or "far_shift" in grid):
            raise CodecError("attribute codec version and position grid disagree on a far set")
        if pos.is_contracted(grid):
            centre, radius = list(grid["centre"]), grid["radius"]
            finite = all(isinstance(v, float) and math.isfinite(v) for v in (*centre, radius))
            if len(centre) != 3 or not finite or not radius > 0:
                raise CodecError("attribute codec header's position centre or radius is not finite")
        far = (grid["far_count"], grid["far_shift"]) if version == FAR_VERSION else None
    except (KeyError, TypeError, ValueError) as err:
        raise CodecError(f"attribute codec header is malformed ({err})") from None
    # Integers are msgpack integers and steps msgpack floats (spec 10.0): 300.0 Gaussians is refused.
    if not all(_is_int(v) for v in (n, degree, bits, opacity_levels, rot_levels)):
        raise CodecError(
            "attribute codec header has a count, degree, bit depth or level that is not an integer"
        )
    if not 1 <= n <= MAX_GAUSSIANS or not 0 <= degree <= 3 or len(sh_steps) != (degree + 1) ** 2 - 1:
        raise CodecError("attribute codec header has an impossible count, SH degree or step list")
    max_bits = pos.MAX_BITS if version == FORMAT_VERSION else pos.CONTRACTED_MAX_BITS
    # Levels up to 2^48, as every other integer of the codec (spec 10.0): each enters binary64 exactly.
    if not (1 <= opacity_levels <= 1 << 48 and 1 <= rot_levels <= 1 << 48) or not 1 <= bits <= max_bits:
        raise CodecError("attribute codec header has impossible quantiser levels")
    # The far set: at least one Gaussian on each curve, and a coarse grid of at least one bit.
    if far is not None and not (
        all(_is_int(v) for v in far) and 1 <= far[0] <= n - 1 and 1 <= far[1] <= bits - 1
    ):
        raise CodecError("attribute codec header has an impossible far set (far_count, far_shift)")
    if not all(_is_step(v) for v in (scale_step, dc_step, *sh_steps, *step)) or len(step) != 3:
        raise CodecError("attribute codec header has a step that is not a positive finite float")
    if len(lo) != 3 or not all(isinstance(v, float) and math.isfinite(v) for v in lo):
        raise CodecError("attribute codec header has a grid origin that is not 3 finite floats")
