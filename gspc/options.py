"""The encoder's and decoder's options (:class:`EncodeOptions`, :class:`DecodeOptions`) and their range and
finiteness checks, run before any work (issue 15).

Each field carries its help text (and, where the command line spells it differently, its flag): gspc/cli.py
builds its options, defaults and help from these fields, so they are stated once. The CLI and the Python API
both validate through ``EncodeOptions.validate`` / ``DecodeOptions.validate``; ``render`` and ``eval`` use
the single checks. Each failure is an InputError that names the option as the command line spells it and the
value given. No torch here: ``gspc --help`` reads this module.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from numbers import Integral, Real
from typing import Any

from gspc.errors import InputError
from gspc.format.view_records import MAX_RESIDUAL_SCALE
from gspc.limits import (
    DEFAULT_TILE_SIZE,
    MAX_CAMERA_SIDE,
    MAX_LAMBDA,
    MAX_REFINE_ITERATIONS,
    MAX_SYNTH_VIEWS,
    MAX_TUNE_ITERATIONS,
    MIN_LAMBDA,
    MIN_MAX_SIDE,
    MIN_TARGET_SIZE,
    MIN_TILE_SIZE,
)
from gspc.presets import DEFAULT_RESTORER, QUALITY, quality_preset

MAX_TIME_BUDGET_S = 1e7  # about 4 months: anything larger is a typo
MAX_TILE_SIZE = 1 << 26  # a tile is one attribute section: at most its Gaussian count (spec 10.0)
MAX_WORKERS = 1024  # processes on one machine; more is a typo


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


def check_synth_views(value: Any, name: str = "--views") -> int:
    """A count of synthesised views (not the check's views: EncodeOptions.check_views)."""
    return check_int(name, value, 1, MAX_SYNTH_VIEWS)


def check_iterations(value: Any, name: str) -> int | None:
    return None if value is None else check_int(name, value, 0, MAX_REFINE_ITERATIONS)


def _check_name(name: str, value: Any) -> None:
    if not (isinstance(value, str) and value):
        raise InputError(f"{name} must be a name, got {value!r}")


def check_time_budget(value: Any) -> float | None:
    return None if value is None else check_real("--time-budget", value, 0.0, MAX_TIME_BUDGET_S, lo_open=True)


def check_encode_options(o: Any) -> None:
    """Every field of an EncodeOptions."""
    _check_name("--quality", o.quality)
    quality_preset(o.quality)
    if o.lam is not None:
        check_real("--lambda", o.lam, MIN_LAMBDA, MAX_LAMBDA)
    if o.target_size is not None:
        check_int("--target-size", o.target_size, MIN_TARGET_SIZE)
    if o.target_psnr is not None:
        check_real("--target-psnr", o.target_psnr, 10.0, 120.0)
    check_real("--views-fraction", o.views_fraction, 0.0, 1.0, lo_open=True)
    check_synth_views(o.synth_views)
    check_max_side(o.max_side)
    if o.residual_codec is not None:
        _check_name("residual_codec", o.residual_codec)
    if o.residual_distance is not None:
        check_real("residual_distance", o.residual_distance, 0.0, 25.0, lo_open=True)
    if o.residual_scale is not None:
        check_int("residual_scale", o.residual_scale, 1, MAX_RESIDUAL_SCALE)
    _check_name("--restorer", o.restorer)
    check_background(o.background)
    check_iterations(o.check_iterations, "--check-iterations")
    if o.tune_iterations is not None:
        check_int("--tune-iterations", o.tune_iterations, 0, MAX_TUNE_ITERATIONS)
    check_int("check_views", o.check_views, 1)
    check_real("check_margin_db", o.check_margin_db, -100.0, 100.0)
    check_time_budget(o.time_budget)
    if o.tile_size != 0:
        check_int("--tile-size", o.tile_size, MIN_TILE_SIZE, MAX_TILE_SIZE)
    if o.span_size != 0:
        check_int("--span-size", o.span_size, MIN_TILE_SIZE, MAX_TILE_SIZE)
    check_workers(o.workers)
    o.ray = check_ray(o.ray)
    # device: checked (DeviceError) by gspc/device.py check_device, also before any work (it needs torch)


def check_workers(value: Any) -> int | None:
    """``--workers``: None (the cores this process may use) or a whole number of processes, 1 or more."""
    return None if value is None else check_int("--workers", value, 1, MAX_WORKERS)


def check_ray(value: Any) -> str | None:
    """``--ray``: None (local processes), "auto" (a local Ray instance) or a running cluster's HOST:PORT
    (ray://HOST:PORT for Ray Client); whether one answers there is checked when the run starts."""
    if value is None or value == "auto":
        return value
    text = value.strip() if isinstance(value, str) else ""
    host, _, port = text.removeprefix("ray://").rpartition(":")
    if not (host and port.isdigit() and 0 < int(port) < 65536) or any(c.isspace() for c in host):
        raise InputError(f"--ray {value!r}: give 'auto' (a local Ray instance) or a cluster's HOST:PORT")
    return text


def check_region(value: Any) -> tuple[float, ...] | None:
    """``--region XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX``: six finite numbers, each minimum at most its maximum."""
    if value is None:
        return None
    shown = value if isinstance(value, str) else ",".join(str(v) for v in value)
    parts = value.split(",") if isinstance(value, str) else value
    try:
        box = tuple(float(v) for v in parts)
    except (TypeError, ValueError):
        raise InputError(f"--region {shown}: give six numbers XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX") from None
    if len(box) != 6 or not all(math.isfinite(v) for v in box):
        raise InputError(f"--region {shown}: give six finite numbers XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX")
    if any(box[a] > box[a + 3] for a in range(3)):
        raise InputError(f"--region {','.join(f'{v:g}' for v in box)}: a minimum is above its maximum")
    return box


def check_decode_options(o: Any) -> None:
    """Every field of a DecodeOptions."""
    check_iterations(o.iterations, "--iterations")
    if o.restorer is not None:
        _check_name("--restorer", o.restorer)
    # device: checked (DeviceError) by gspc/device.py check_device, also before any work (it needs torch)
    check_int("seed", o.seed, 0)
    check_real("lr_scale", o.lr_scale, 0.0, 1e3, lo_open=True)
    check_time_budget(o.time_budget)
    check_workers(o.workers)
    o.ray = check_ray(o.ray)
    o.region = check_region(o.region)


def knob(default: Any, help: str, flag: str | None = None) -> Any:
    """A dataclass field with the help text (and command-line flag, if not the field's name) the CLI shows."""
    return field(default=default, metadata={"help": help, "flag": flag})


def _per_preset(attr: str) -> str:
    return ", ".join(f"{name} {getattr(p, attr)}" for name, p in QUALITY.items())


@dataclass
class EncodeOptions:
    quality: str = knob(
        "low",
        f"preset: {', '.join(QUALITY)}, each a fidelity its attributes aim at within a size "
        f"({', '.join(f'{n} {p.target_db:g} dB' for n, p in QUALITY.items())}; gspc/presets.py)",
    )
    lam: float | None = knob(
        None, "continuous rate knob: code at this rate instead of the preset's fidelity target", "--lambda"
    )
    target_size: int | None = knob(
        None, "the file's size at most, side information included (searches lambda)"
    )
    target_psnr: float | None = knob(
        None,
        "the fidelity to aim for, in dB against the original's renders at views between the cameras: the "
        "fewest bytes that reach it (searches lambda; gspc/encoder/fidelity.py)",
    )
    views_fraction: float = knob(0.4, "fraction of views that carry side information")
    synth_views: int = knob(60, "views to synthesise when no cameras are given", "--views")
    max_side: int = knob(400, "longest side of the side-information views, in pixels")
    residual_codec: str | None = knob(None, "residual image codec (overrides the preset's)")
    residual_distance: float | None = knob(
        None, "residual rate knob, larger is coarser (overrides the preset's; gspc/codec/residuals.py)"
    )
    residual_scale: int | None = knob(None, "residuals at 1/scale resolution (overrides the preset's)")
    side_info: bool = knob(True, "store residual side information")
    restorer: str = knob(
        DEFAULT_RESTORER, "restorer the decoder should use ('none': I~ + R~; see gspc/restore/weights)"
    )
    keep_invisible: bool = knob(False, "keep Gaussians no view sees")
    precision: bool = knob(
        True,
        "spend precision per Gaussian as its effect on the views calls for, and remove those worth less than "
        "their bytes (attribute codec version 4; off: every Gaussian at the rate's steps, versions 1-3)",
    )
    removal_search: bool = knob(
        True,
        "try stronger removals and another position grid than the preset's, each in the same bytes, and keep "
        "one that views between the encoder's cameras show closer to the original (gspc/encoder/removal.py; "
        "off: the preset's)",
    )
    tune_iterations: int | None = knob(
        None,
        "iterations of tuning the coded values of a file without side information so that it decodes closer "
        f"at the encoder's cameras (default: the preset's, {_per_preset('tune_iterations')}; 0: none; "
        "gspc/encoder/tuning.py)",
    )
    background: tuple[float, float, float] = knob(
        (0.0, 0.0, 0.0), "render background RGB in [0, 1] (1 1 1 for scenes trained on white)"
    )
    # The encoder runs the decoder's refinement for this many iterations (None: the preset's) and keeps the
    # side information only if it beats, at views that carry none, the same bytes spent on attributes
    # (0: no check, keep it).
    check_iterations: int | None = knob(
        None,
        "refinement iterations the encoder runs to check that side information pays, and the decoder's "
        f"default (default: the preset's, {_per_preset('refine_iterations')}; 0: no check)",
    )
    check_views: int = knob(8, "views carrying no side information at which the check scores")
    # Side information must beat its rivals by this much at the check views: a tie within the noise of a few
    # sampled views can lose at the others (bench/pipeline.md, "Moved from code comments").
    check_margin_db: float = knob(0.15, "dB by which side information must beat its rivals at the check")
    time_budget: float | None = knob(
        None,
        "seconds the encode may take: the check's refinement is shortened to end in time (the length it ran "
        "is written to the file as the decoder's default; without this, large scenes get fewer iterations "
        "by a fixed rule, gspc/presets.py)",
    )
    device: str = knob("cpu", "cpu or cuda (renders, check, restorer; the attribute codec runs on the CPU)")
    tile_size: int = knob(
        DEFAULT_TILE_SIZE,
        "Gaussians per spatial tile: a larger scene is coded as tiles a decoder reads one at a time "
        "(0: one block whatever the size; bench/tiles.md)",
    )
    # Off by default: drawing them measured no better than a tile alone, for more encode and decode time
    # (bench/tiles.md, "Neighbours drawn").
    tile_neighbours: bool = knob(
        False,
        "a tile's side information shows the tiles next to it too, drawn and never refined (format 1.7; "
        "default: each tile's own Gaussians alone)",
    )
    span_size: int = knob(
        0,
        "side information shared by runs of neighbouring tiles of at most this many Gaussians in all, whose "
        "views are stored once and refined together (format 1.9; 0: each tile its own)",
    )
    workers: int | None = knob(
        None,
        "worker processes that code tiles side by side (default: the cores this process may use, "
        "as many as the available memory holds)",
    )
    ray: str | None = knob(
        None,
        "run the tasks on Ray ('auto': a local instance of --workers CPUs; HOST:PORT: the cluster `ray start "
        "--head` started there; needs gspc[ray]): the same bytes as local workers",
    )
    ship_inputs: bool = knob(
        False,
        "the driver reads each tile's Gaussians and sends them with its task (a cluster whose nodes cannot "
        "read the input path); default: each worker reads its tile from the file",
    )

    def validate(self) -> None:
        """InputError naming the first option out of range; called before any work."""
        check_encode_options(self)


@dataclass
class DecodeOptions:
    iterations: int | None = knob(
        None, "refinement iterations (default: what the encoder validated, stored in the file)"
    )
    restore: bool = knob(True, "restore the rendered views with the side information")
    refine: bool = knob(True, "refine the Gaussians against the restored views")
    restorer: str | None = knob(None, "restorer to use (default: the one the file names; 'none')")
    device: str = knob("cpu", "cpu or cuda")
    seed: int = knob(0, "refinement's random seed")
    lr_scale: float = knob(1.0, "multiplies every refinement learning rate")
    in_cells: bool = knob(True, "keep refined attributes inside their quantisation cells", "--cells")
    time_budget: float | None = knob(
        None,
        "seconds the decode may take before writing: refinement is shortened to end in time (its result "
        "then depends on this machine's speed)",
    )
    region: tuple[float, float, float, float, float, float] | None = knob(
        None, "decode only the tiles of a tiled file that meet this box: XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX"
    )
    workers: int | None = knob(
        None,
        "worker processes that decode tiles side by side (default: the cores this process may use, "
        "as many as the available memory holds)",
    )
    ray: str | None = knob(
        None, "decode the tiles on Ray ('auto': a local instance; HOST:PORT: a running cluster; gspc[ray])"
    )

    def validate(self) -> None:
        """InputError naming the first option out of range; called before any work."""
        check_decode_options(self)
