"""Range and finiteness checks of every encode/decode option, run before any work (issue 15).

The CLI and the Python API both reach them through ``EncodeOptions.validate`` / ``DecodeOptions.validate``
(gspc/pipeline.py); ``render`` and ``eval`` use the single checks. Each failure is an InputError that names
the option as the command line spells it and the value given.
"""

from __future__ import annotations

import math
from numbers import Integral, Real
from typing import Any

from gspc.errors import InputError
from gspc.limits import (
    MAX_CAMERA_SIDE,
    MAX_LAMBDA,
    MAX_REFINE_ITERATIONS,
    MAX_SYNTH_VIEWS,
    MIN_LAMBDA,
    MIN_MAX_SIDE,
    MIN_TARGET_SIZE,
)
from gspc.presets import quality_preset

_MAX_RESIDUAL_SCALE = 16  # the SIDE chunk's scale field allows 1..16 (gspc/codec/sideinfo.py)


def check_int(name: str, value: Any, lo: int, hi: int | None = None) -> int:
    if (
        not (isinstance(value, Integral) and not isinstance(value, bool))
        or value < lo
        or (hi is not None and value > hi)
    ):
        span = f"in {lo}..{hi}" if hi is not None else f">= {lo}"
        raise InputError(f"{name} must be an integer {span}, got {value!r}")
    return int(value)


def check_real(name: str, value: Any, lo: float, hi: float, lo_open: bool = False) -> float:
    ok = isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(value)
    if ok:
        ok = (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        span = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise InputError(f"{name} must be a finite number in {span}, got {value!r}")
    return float(value)


def check_background(value: Any, name: str = "--background") -> tuple[float, float, float]:
    try:
        rgb = tuple(value)
    except TypeError:
        rgb = ()
    if len(rgb) != 3:
        raise InputError(f"{name} must be three numbers R G B in [0, 1], got {value!r}")
    return tuple(check_real(f"{name} {c}", v, 0.0, 1.0) for c, v in zip("RGB", rgb))  # type: ignore[return-value]


def check_max_side(value: Any, name: str = "--max-side") -> int:
    return check_int(name, value, MIN_MAX_SIDE, MAX_CAMERA_SIDE)


def check_views(value: Any, name: str = "--views") -> int:
    return check_int(name, value, 1, MAX_SYNTH_VIEWS)


def check_iterations(value: Any, name: str) -> int | None:
    return None if value is None else check_int(name, value, 0, MAX_REFINE_ITERATIONS)


def _check_name(name: str, value: Any) -> None:
    if not (isinstance(value, str) and value):
        raise InputError(f"{name} must be a name, got {value!r}")


def check_encode_options(o: Any) -> None:
    """Every field of an EncodeOptions."""
    _check_name("--quality", o.quality)
    quality_preset(o.quality)
    if o.lam is not None:
        check_real("--lambda", o.lam, MIN_LAMBDA, MAX_LAMBDA)
    if o.target_size is not None:
        check_int("--target-size", o.target_size, MIN_TARGET_SIZE)
    check_real("--views-fraction", o.views_fraction, 0.0, 1.0, lo_open=True)
    check_views(o.synth_views)
    check_max_side(o.max_side)
    if o.residual_codec is not None:
        _check_name("residual_codec", o.residual_codec)
    if o.residual_distance is not None:
        check_real("residual_distance", o.residual_distance, 0.0, 25.0, lo_open=True)
    if o.residual_scale is not None:
        check_int("residual_scale", o.residual_scale, 1, _MAX_RESIDUAL_SCALE)
    _check_name("--restorer", o.restorer)
    check_background(o.background)
    check_iterations(o.check_iterations, "--check-iterations")
    check_int("check_views", o.check_views, 1)
    check_real("check_margin_db", o.check_margin_db, -100.0, 100.0)


def check_decode_options(o: Any) -> None:
    """Every field of a DecodeOptions."""
    check_iterations(o.iterations, "--iterations")
    if o.restorer is not None:
        _check_name("--restorer", o.restorer)
    # device: checked (DeviceError) by gspc/pipeline.py _check_device, also before any work
    check_int("seed", o.seed, 0)
    check_real("lr_scale", o.lr_scale, 0.0, 1e3, lo_open=True)
