"""The .gspc header fields that the pipeline and the CLI read, each checked for type and range.

The container (gspc/codec/container.py) guarantees only a msgpack map; every field below comes from an
untrusted file, so each is checked here before use and a bad one is refused with a CodecError that names the
field and its value (issue 15). Payload checks (counts against payload sizes, model tables) belong to the
codecs themselves (gspc/codec/attributes.py and friends).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gspc.errors import CodecError
from gspc.limits import (
    MAX_CAMERA_SIDE,
    MAX_REFINE_ITERATIONS,
    MAX_TOTAL_PIXELS,
    MAX_VIEW_PIXELS,
    PIXEL_FLOOR,
    PIXELS_PER_FILE_BYTE,
    view_pixel_budget,
)

DEFAULT_ITERATIONS = 300  # decoder refinement when the file names none (spec: side_info.refine_iterations)
UNNAMED_RESTORER = "none"  # the restorer when the file names none (the encoder names one)
_MAX_SH_DEGREE = 3


def _show(value: object) -> str:
    """A value for an error message, cut short: a hostile header may hold megabytes in one field."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_int(v: object) -> bool:
    return type(v) is int  # bool is an int subclass but not a msgpack integer


def _is_number(v: object) -> bool:
    return _is_int(v) or type(v) is float


def _map(parent: dict, key: str, where: str) -> dict:
    if key not in parent:
        raise CodecError(f"the .gspc header lacks {where}")
    v = parent[key]
    if not isinstance(v, dict):
        raise CodecError(f"the .gspc header's {where} is {_show(v)}, not a map")
    return v


def _int(
    parent: dict, key: str, where: str, lo: int, hi: int | None = None, default: int | None = None
) -> int:
    if key not in parent and default is not None:
        return default
    if key not in parent:
        raise CodecError(f"the .gspc header lacks {where}")
    v = parent[key]
    if not (_is_int(v) and v >= lo and (hi is None or v <= hi)):
        span = f"in {lo}..{hi}" if hi is not None else f">= {lo}"
        raise CodecError(f"the .gspc header's {where} is {_show(v)}, not an integer {span}")
    return v


def _finite(v: object, where: str, positive: bool = False) -> float:
    if not (_is_number(v) and math.isfinite(v) and (v > 0 or not positive)):
        want = "a positive finite number" if positive else "a finite number"
        raise CodecError(f"the .gspc header's {where} is {_show(v)}, not {want}")
    return float(v)


def _numbers(parent: dict, key: str, where: str, length: int, positive: bool = False) -> list[float]:
    if key not in parent:
        raise CodecError(f"the .gspc header lacks {where}")
    v = parent[key]
    if not (isinstance(v, list) and len(v) == length):
        raise CodecError(f"the .gspc header's {where} is {_show(v)}, not a list of {length} numbers")
    return [_finite(x, f"{where}[{i}]", positive) for i, x in enumerate(v)]


def check_attributes(meta: dict) -> None:
    """The attribute codec's section (spec 10.1): every field decode_attributes and the cells read."""
    where = "attributes"
    _int(meta, "version", f"{where}.version", 0)
    degree = _int(meta, "sh_degree", f"{where}.sh_degree", 0, _MAX_SH_DEGREE)
    _int(meta, "n", f"{where}.n", 1)
    grid = _map(meta, "position", f"{where}.position")
    _int(grid, "bits", f"{where}.position.bits", 1)
    _numbers(grid, "lo", f"{where}.position.lo", 3)
    _numbers(grid, "step", f"{where}.position.step", 3, positive=True)
    _int(meta, "opacity_levels", f"{where}.opacity_levels", 1)
    _int(meta, "rotation_levels", f"{where}.rotation_levels", 1)
    for key in ("scale_step", "dc_step"):
        if key not in meta:
            raise CodecError(f"the .gspc header lacks {where}.{key}")
        _finite(meta[key], f"{where}.{key}", positive=True)
    _numbers(meta, "sh_steps", f"{where}.sh_steps", (degree + 1) ** 2 - 1, positive=True)


def _background(side: dict) -> tuple[float, float, float]:
    where = "side_info.background"
    if "background" not in side:
        raise CodecError(f"the .gspc header lacks {where}")
    rgb = _numbers(side, "background", where, 3)
    if not all(0.0 <= v <= 1.0 for v in rgb):
        raise CodecError(f"the .gspc header's {where} is {_show(side['background'])}, not RGB in [0, 1]")
    return rgb[0], rgb[1], rgb[2]


def _restorer(side: dict) -> str:
    v = side.get("restorer", UNNAMED_RESTORER)
    if not (isinstance(v, str) and 0 < len(v) <= 200):
        raise CodecError(f"the .gspc header's side_info.restorer is {_show(v)}, not a restorer name")
    return v


@dataclass(frozen=True)
class DecodeHeader:
    """What the decoder takes from the header, checked."""

    attributes: dict  # the attribute codec's section, for decode_attributes and quantisation_cells
    side_info: dict  # the raw section, for side_views
    background: tuple[float, float, float]
    restorer: str
    refine_iterations: int


def parse(meta: dict) -> DecodeHeader:
    """The header sections gspc 1 writes (spec section 9), checked field by field; CodecError otherwise."""
    attributes = _map(meta, "attributes", "attributes section")
    check_attributes(attributes)
    side = _map(meta, "side_info", "side_info section")
    if "views" in side and not isinstance(side["views"], list):
        raise CodecError(f"the .gspc header's side_info.views is {_show(side['views'])}, not an array")
    if "scene" in meta:
        scene_summary(meta)
    iterations = _int(
        side, "refine_iterations", "side_info.refine_iterations", 0, MAX_REFINE_ITERATIONS, DEFAULT_ITERATIONS
    )
    return DecodeHeader(attributes, side, _background(side), _restorer(side), iterations)


def scene_summary(meta: dict) -> tuple[int, int | None]:
    """(Gaussian count, SH degree or None) of the optional ``scene`` section, for ``gspc info``.

    Missing fields give (0, None): files written by other tools may lack the section. Present ones must be
    well typed."""
    if "scene" not in meta:
        return 0, None
    scene = _map(meta, "scene", "scene section")
    n = _int(scene, "num_gaussians", "scene.num_gaussians", 0, None, 0)
    degree = _int(scene, "sh_degree", "scene.sh_degree", 0, _MAX_SH_DEGREE, -1)
    return n, None if degree < 0 else degree


def check_view_sizes(views: list, file_size: int) -> None:
    """Each side-information view's size, and all views' pixels together, against gspc/limits.py: run
    before any camera is built or anything rendered, so a small file cannot ask for gigapixels."""
    budget = view_pixel_budget(file_size)
    total = 0
    for k, v in enumerate(views):
        cam = v.get("camera") if isinstance(v, dict) else None
        if not isinstance(cam, dict):
            raise CodecError(f"side-information view {k} has camera {_show(cam)}, not a map")
        w, h = cam.get("width"), cam.get("height")
        for name, x in (("width", w), ("height", h)):
            if not (_is_int(x) and 1 <= x <= MAX_CAMERA_SIDE):
                raise CodecError(
                    f"side-information view {k} has camera {name} {_show(x)}, not an integer in "
                    f"1..{MAX_CAMERA_SIDE}"
                )
        if w * h > MAX_VIEW_PIXELS:
            raise CodecError(
                f"side-information view {k} is {w}x{h} = {w * h:,} pixels; the limit is {MAX_VIEW_PIXELS:,}"
            )
        total += w * h
    if total > budget:
        raise CodecError(
            f"side-information views ask for {total:,} pixels in a {file_size:,}-byte file; the limit is "
            f"{budget:,} (max({PIXEL_FLOOR:,}, {PIXELS_PER_FILE_BYTE} per file byte), at most "
            f"{MAX_TOTAL_PIXELS:,})"
        )
