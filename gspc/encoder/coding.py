"""The encoder's coding of a scene at one rate: which Gaussians it codes, at which steps (the rate's, or
each one's precision class and SH degree as planned: gspc/encoder/precision_plan.py), in which order on which
grid; then the codec writes them (gspc/codec/attributes.py encode_section).

Every step is ``base_step * lam`` (gspc/encoder/params.py): the rate knob sets the steps, the plan their
classes, the codec the bits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import msgpack
import numpy as np
import torch

from gspc.codec import positions as pos
from gspc.codec.attributes import (
    DecodedSection,
    OutOfRange,
    SHCodebook,
    check_range,
    decode_section,
    encode_section,
)
from gspc.codec.precision import PrecisionMap
from gspc.codec.quantisers import OPACITY_FLOOR, SQRT_HALF
from gspc.encoder.codebook import codebook_entries, fit_codebook
from gspc.encoder.params import CodecParams
from gspc.encoder.precision_plan import Plan, RateSteps, Significance, plan_precision
from gspc.errors import CodecError, InputError, NothingCodedError, ValueRangeError
from gspc.format.attribute_section import AttributeSection, ClassSteps, PositionGrid
from gspc.scene import GaussianScene, num_sh_rest


@dataclass(frozen=True)
class SharedGrid:
    """The position grid of a whole scene, which each of its spatial tiles codes on (gspc/encoder/tiles.py):
    its frame (the grid at any precision, so a tile's rate and position offset move it as they move a
    scene's) and the median world size of its Gaussians inside the contraction's identity radius, which
    each tile's far set is chosen against (gspc/codec/positions.py far_set)."""

    frame: pos.GridFrame
    inside_size: float | None = None

    def at(self, precision: float) -> tuple[PositionGrid, float | None]:
        """The grid of ``precision`` bits per axis, and its far sets' reference precision."""
        grid = self.frame.grid(precision)
        if grid.contraction is None or self.inside_size is None:
            return grid, None
        return grid, self.inside_size / (max(grid.step) * grid.contraction.radius)


@dataclass
class EncodedAttributes:
    chunks: dict[str, bytes]
    section: AttributeSection  # the header section the file carries
    kept: np.ndarray  # indices into the input scene, in decoded (curve) order
    lam: float  # the rate knob it was coded at

    @cached_property
    def _decoded(self) -> DecodedSection:
        return decode_section(self.chunks, self.section)

    @property
    def decoded(self) -> GaussianScene:
        """G~, as the decoder decodes the chunks; decoded when first read (a lambda search reads only the
        sizes of the codings it passes over)."""
        return self._decoded.scene

    @property
    def precision(self) -> PrecisionMap | None:
        """Each Gaussian's class and SH degree at version 4 (what the decoder reads), else None."""
        return self._decoded.precision

    @property
    def num_bytes(self) -> int:
        """Chunk bytes plus the packed meta: what the container pays for this codec."""
        meta = msgpack.packb(self.section.to_dict(), use_bin_type=True)
        return sum(len(c) for c in self.chunks.values()) + len(meta)


def _np(t: torch.Tensor, rows: np.ndarray) -> np.ndarray:
    """``t[rows]`` as float64 numpy (rows picked first: a large scene's SH rest doubles in float64)."""
    return t.detach().cpu().numpy()[rows].astype(np.float64)


def _alpha(scene: GaussianScene) -> np.ndarray:
    return torch.sigmoid(scene.opacities.detach().double()).cpu().numpy()


def _sh_steps(params: CodecParams, degree: int) -> list[float]:
    """Step of every SH rest coefficient (index k = 0 .. K-1), growing with its degree."""
    steps = []
    for k in range(num_sh_rest(degree)):
        deg = int(math.isqrt(k + 1))  # k = 0..2 degree 1, 3..7 degree 2, 8..14 degree 3
        growth = params.sh_degree_growth ** (deg - 1)
        steps.append(float(params.sh_step * params.lam**params.sh_lam_exponent * growth))
    return steps


def faint_alpha(params: CodecParams) -> float:
    """Below this coded alpha a Gaussian carries no SH rest: its view-dependent colour hardly shows."""
    return min(0.5, params.sh_faint_alpha * params.lam)


def prune_mask(scene: GaussianScene, params: CodecParams, visible: np.ndarray | None) -> np.ndarray:
    """Gaussians worth coding: visible to some view and at least 1/255 opaque, unless flags keep them."""
    keep = np.ones(scene.num_gaussians, bool)
    if not params.keep_transparent:
        keep &= _alpha(scene) >= OPACITY_FLOOR
    if visible is not None and not params.keep_invisible:
        visible = np.asarray(visible, bool).reshape(-1)
        if visible.shape[0] != scene.num_gaussians:
            raise CodecError(
                f"visibility mask has {visible.shape[0]} entries for {scene.num_gaussians} Gaussians"
            )
        keep &= visible
    return keep


def class_steps(
    params: CodecParams, degree: int, exponent: int = 0, groups: tuple[str, ...] = ()
) -> ClassSteps:
    """The quantisers at ``params``' rate, the steps of ``groups`` times ``2^exponent``: a precision
    class."""
    lam = params.lam

    def m(group: str) -> float:
        return 2.0**exponent if group in groups else 1.0

    # Even levels make a zero component exact: axis-aligned Gaussians are common, and odd levels cost them
    # half a step of rotation error (bench/codec.md).
    rotation = params.rotation_step * params.geometry_lam * m("quats")
    return ClassSteps(
        opacity_levels=max(1, int(round(1.0 / (params.opacity_step * lam * m("opacities"))))),
        scale_step=float(params.scale_step * params.geometry_lam * m("log_scales")),
        rotation_levels=2 * max(1, int(math.ceil(SQRT_HALF / rotation))),
        dc_step=float(params.dc_step * lam * m("sh_dc")),
        sh_steps=tuple(s * m("sh_rest") for s in _sh_steps(params, degree)),
    )


def encode_attributes(
    scene: GaussianScene,
    params: CodecParams,
    visible: np.ndarray | None = None,
    significance: Significance | None = None,
    planned_on: GaussianScene | None = None,
    grid: SharedGrid | None = None,
) -> EncodedAttributes:
    """Encode a scene; ``decoded`` is what the decoder decodes from these chunks. With ``params.precision``
    and the ``significance`` of the scene's Gaussians, per-Gaussian precision (version 4,
    gspc/encoder/precision_plan.py); otherwise every Gaussian at the rate's steps. ``planned_on``: the scene
    (of the same Gaussians) whose opacities and sizes decide which Gaussians are coded, their classes and the
    far set (default: ``scene``): the encoder's tuning codes moved values under the original's plan
    (gspc/encoder/tuning.py). ``grid``: the grid of the scene this one is a tile of (default: its own,
    over its positions). ValueRangeError where a value is beyond what lambda codes."""
    try:
        return _encode(scene, params, visible, significance, planned_on, grid)
    except OutOfRange as e:
        at = " for the finest coefficient" if e.finest else ""
        raise ValueRangeError(
            f"{e.count} Gaussian(s) have {e.name} values up to {e.worst:.3g}, beyond what lambda "
            f"{params.lam:g} can code (+-{e.limit:.3g}{at}; a larger lambda raises the limit)"
        ) from None


def _encode(
    scene: GaussianScene,
    params: CodecParams,
    visible: np.ndarray | None,
    significance: Significance | None,
    planned_on: GaussianScene | None,
    shared: SharedGrid | None,
) -> EncodedAttributes:
    scene.validate()
    base = scene if planned_on is None else planned_on
    keep = prune_mask(base, params, visible)
    plan = None
    if params.precision is not None and significance is not None:
        # Values no rate can code are refused whether or not the plan would remove their Gaussian: removal
        # is an R-D choice, not a check of the input.
        _check_ranges(scene, class_steps(params, scene.sh_degree), params, np.flatnonzero(keep))
        plan = _plan(base, params, significance, keep)
        keep = plan.keep
    keep_idx = np.flatnonzero(keep)
    if keep_idx.size == 0:
        raise NothingCodedError(
            "every Gaussian was pruned (transparent or unseen); use the keep flags to code them"
        )
    means = _np(scene.means, keep_idx)
    sizes = np.exp(np.median(_np(base.log_scales, keep_idx).astype(np.float64), axis=1))
    if plan is not None:
        # The far set (spec 10.1) codes a Gaussian's position coarsely where its size allows; a Gaussian the
        # plan gives finer steps needs its position as much finer (bench/far_set.md).
        sizes = sizes * 2.0 ** np.minimum(plan.exponent[keep_idx], 0).astype(np.float64)
    try:
        if shared is None:
            voxels, order, grid = pos.curve_order(means, params.position_precision, sizes)
        else:
            on, reference = shared.at(params.position_precision)
            voxels, order, grid = pos.grid_order(means, on, sizes, reference)
    except CodecError as err:  # a grid the format's bounds refuse (spec 10.1)
        raise InputError(f"the scene's positions cannot be coded: {err}") from None
    kept = keep_idx[order]
    codebook = None
    if plan is None:
        classes, pmap = (class_steps(params, scene.sh_degree),), None
    else:
        classes, pmap = _classes(params, plan, kept, scene.sh_degree)
        if params.sh_codebook and scene.sh_degree > 0 and (pmap.degrees > 0).any():
            pmap, codebook = _codebook(scene, params, significance, kept, pmap, classes[0])
    chunks, section = encode_section(
        scene, kept, voxels, grid, classes, pmap, params.sh_deadzone, faint_alpha(params), codebook
    )
    return EncodedAttributes(chunks=chunks, section=section, kept=kept, lam=params.lam)


def _classes(
    params: CodecParams, plan: Plan, kept: np.ndarray, degree: int
) -> tuple[tuple[ClassSteps, ...], PrecisionMap]:
    """The classes the plan's exponents make (class 0 the rate's own steps, the others in increasing step)
    and each coded Gaussian's class and SH degree."""
    exponent = plan.exponent[kept]
    exps = [0, *sorted(set(np.unique(exponent).tolist()) - {0})]
    classes = np.zeros(len(kept), np.int64)
    for i, e in enumerate(exps):
        classes[exponent == e] = i
    steps = tuple(class_steps(params, degree, e, params.precision.groups) for e in exps)
    degrees = plan.degree[kept] if degree > 0 else np.zeros(len(kept), np.int64)
    return steps, PrecisionMap(classes, degrees)


def _codebook(
    scene: GaussianScene,
    params: CodecParams,
    sig: Significance,
    kept: np.ndarray,
    pmap: PrecisionMap,
    base: ClassSteps,
) -> tuple[PrecisionMap, SHCodebook]:
    """The SH rest by codebook (version 5): every Gaussian the plan gives any band takes all of its entry's
    (an index costs the same whatever the degree), entries at class 0's steps, as many as the rate asks
    (gspc/encoder/codebook.py) up to the parameters' most."""
    coded = pmap.degrees > 0
    degrees = np.where(coded, scene.sh_degree, 0).astype(pmap.degrees.dtype)
    rest = scene.sh_rest.detach().cpu().numpy()  # in range: _check_ranges checked every candidate's
    entries = codebook_entries(int(coded.sum()), params.lam, params.sh_codebook)
    book = fit_codebook(rest, kept[coded], sig.weight, entries, np.asarray(base.sh_steps))
    return PrecisionMap(pmap.classes, degrees), book


def _plan(scene: GaussianScene, params: CodecParams, sig: Significance, candidates: np.ndarray) -> Plan:
    """gspc/encoder/precision_plan.py's plan at this rate, for every input Gaussian."""
    base = class_steps(params, scene.sh_degree)
    steps = RateSteps(
        base.opacity_levels,
        base.scale_step,
        2.0 * SQRT_HALF / base.rotation_levels,
        base.dc_step,
        tuple(base.sh_steps[b * b - 1] for b in range(1, scene.sh_degree + 1)),
    )
    faint = faint_alpha(params)
    return plan_precision(sig, _alpha(scene), steps, params.precision, candidates, faint, params.lam)


def _check_ranges(scene: GaussianScene, steps: ClassSteps, params: CodecParams, rows: np.ndarray) -> None:
    """OutOfRange where any of ``rows`` has a log scale, DC or SH rest value beyond ``steps``' range."""
    check_range("log scale", _np(scene.log_scales, rows), steps.scale_step)
    check_range("SH DC", _np(scene.sh_dc, rows), steps.dc_step)
    if scene.sh_degree > 0:  # faint Gaussians' SH rest is dropped whatever it holds
        rows = rows[_alpha(scene)[rows] >= faint_alpha(params)]
        rest, sh = scene.sh_rest.detach().cpu().numpy(), np.asarray(steps.sh_steps)[None, :, None]
        check_range("SH rest", rest, sh, rows)
