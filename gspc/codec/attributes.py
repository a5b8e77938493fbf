"""gspc's attribute codec: positions plus quantised, context-coded attributes, bit-exact on any CPU.

Chunks (bytes, stored by the container under these types):
- ``POSN`` Morton-ordered voxels (see :mod:`gspc.codec.positions`); the decoded order is curve order.
- ``OPAC`` activated opacity ``alpha`` quantised to ``L`` levels: ``q = round(alpha * L)``; decoded
  ``logit(clamp(q / L, 1/(4L), 1 - 1/(4L)))`` with a log built from +, -, *, / only.
- ``SCAL`` natural-log scales, ``q = round(log_scale / step)``, decoded ``q * step``.
- ``ROTN`` unit quaternion, smallest three: [index of the largest |component| (made positive),
  the other three in w, x, y, z order quantised over [-1/sqrt2, 1/sqrt2] in ``M`` steps]; the
  largest is ``sqrt(1 - sum of squares)``. Rotation error bound: :func:`rotation_error_bound`.
- ``SHDC`` ``q = round(dc / step)``; ``SHRS`` per-Gaussian flag (any non-zero SH rest symbol), then
  only flagged Gaussians' SH rest, coefficient-major, steps growing with degree. No SHRS at degree 0.
Each chunk is an :func:`gspc.codec.entropy.encode_matrix` payload (SHRS: a msgpack pair). Each attribute's
quantiser (quantise, exact dequantise and cell together) is in :mod:`gspc.codec.quantisers`.
The byte layouts are specified in spec/gspc-format.md, section 10.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import msgpack
import numpy as np
import torch

from gspc.codec import positions as pos
from gspc.codec.entropy import SYMBOL_LIMIT, decode_matrix, encode_matrix
from gspc.codec.params import CodecParams
from gspc.codec.precision import (
    Plan,
    PrecisionMap,
    RateSteps,
    Significance,
    decode_precision,
    encode_precision,
    pack_bins,
    plan_precision,
    unpack_bins,
)
from gspc.codec.quantisers import (
    OPACITY_FLOOR,
    SQRT_HALF,
    AttributeQuantisers,
    SmallestThreeQuantiser,
    out_of_range,
)
from gspc.errors import CodecError, InputError, NothingCodedError, ValueRangeError
from gspc.format.attribute_section import (
    AttributeSection,
    ClassSteps,
    PositionGrid,
    check_attribute_chunks,
)
from gspc.format.chunks import ATTRIBUTE_TYPES, OPAC, POSN, PREC, ROTN, SCAL, SHDC, SHRS
from gspc.scene import GaussianScene, num_sh_rest


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
        """G~, from decode_attributes on the chunks; decoded when first read (a lambda search reads only the
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


def rotation_error_bound(levels: int) -> float:
    """Largest rotation angle (radians) between a unit quaternion and its decoded version."""
    return SmallestThreeQuantiser(levels).error_bound()


def _np(t: torch.Tensor, rows: np.ndarray) -> np.ndarray:
    """``t[rows]`` as float64 numpy (rows picked first: the SH rest of a million Gaussians is 180 MB in
    float32, twice that in float64)."""
    return t.detach().cpu().numpy()[rows].astype(np.float64)


@dataclass(frozen=True)
class GroupChunk:
    """One attribute group's chunk (spec 10.2 to 10.5): both directions walk :data:`GROUP_CHUNKS`."""

    chunk: str  # the chunk type
    attribute: str  # the GaussianScene field it codes
    quantiser: str  # the AttributeQuantisers field that quantises it
    columns: int  # of its matrix
    checked: str | None = None  # the ClassSteps step whose range the encoder checks (with its name below)
    name: str = ""


GROUP_CHUNKS = (
    GroupChunk(OPAC, "opacities", "opacity", 1),
    GroupChunk(SCAL, "log_scales", "scale", 3, "scale_step", "log scale"),
    GroupChunk(ROTN, "quats", "rotation", 4),
    GroupChunk(SHDC, "sh_dc", "dc", 3, "dc_step", "SH DC"),
)
GROUP_TYPES = tuple(g.chunk for g in GROUP_CHUNKS)


def _quantised(
    g: GroupChunk,
    scene: GaussianScene,
    rows: np.ndarray,
    quant: AttributeQuantisers,
    steps: ClassSteps,
    lam: float,
) -> np.ndarray:
    """The symbols of group ``g`` for ``rows`` of the scene, (len(rows), g.columns); ValueRangeError where a
    value is beyond what the class's step codes."""
    values = _np(getattr(scene, g.attribute), rows)
    if g.checked is not None:
        _check_range(g.name, values, getattr(steps, g.checked), lam)
    return getattr(quant, g.quantiser).quantise(values).reshape(len(rows), g.columns)


def _dequantised(g: GroupChunk, quant: AttributeQuantisers, q: np.ndarray) -> np.ndarray:
    """Group ``g``'s decoded values from its (m, g.columns) matrix (opacity: a vector)."""
    return getattr(quant, g.quantiser).dequantise(q[:, 0] if g.columns == 1 else q)


def _sh_steps(params: CodecParams, degree: int) -> list[float]:
    """Step of every SH rest coefficient (index k = 0 .. K-1), growing with its degree."""
    steps = []
    for k in range(num_sh_rest(degree)):
        deg = int(math.isqrt(k + 1))  # k = 0..2 degree 1, 3..7 degree 2, 8..14 degree 3
        growth = params.sh_degree_growth ** (deg - 1)
        steps.append(float(params.sh_step * params.lam**params.sh_lam_exponent * growth))
    return steps


# ---------------------------------------------------------------------------------------------
# Codec


def prune_mask(scene: GaussianScene, params: CodecParams, visible: np.ndarray | None) -> np.ndarray:
    """Gaussians worth coding: visible to some view and at least 1/255 opaque, unless flags keep them."""
    keep = np.ones(scene.num_gaussians, bool)
    if not params.keep_transparent:
        keep &= torch.sigmoid(scene.opacities.detach().double()).cpu().numpy() >= OPACITY_FLOOR
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

    # Even levels make a zero component exact: axis-aligned Gaussians are common and odd levels cost
    # them half a step of rotation error (lego: +1.2 dB at equal bytes).
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
) -> EncodedAttributes:
    """Encode a scene; ``decoded`` is what :func:`decode_attributes` returns for these chunks. With
    ``params.precision`` and the ``significance`` of the scene's Gaussians, per-Gaussian precision
    (version 4, gspc/codec/precision.py); otherwise every Gaussian at the rate's steps. ``planned_on``: the
    scene (of the same Gaussians) whose opacities and sizes decide which Gaussians are coded, their classes
    and the far set (default: ``scene``): the encoder's tuning codes moved values under the original's plan
    (gspc/encoder/tuning.py)."""
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
        # plan gives finer steps needs its position as much finer (a shell of sky-sized Gaussians: +3.7 dB).
        sizes = sizes * 2.0 ** np.minimum(plan.exponent[keep_idx], 0).astype(np.float64)
    try:
        voxels, order, grid = pos.curve_order(means, params.position_precision, sizes)
    except CodecError as err:  # a grid the format's bounds refuse (spec 10.1)
        raise InputError(f"the scene's positions cannot be coded: {err}") from None
    kept = keep_idx[order]
    if plan is not None:
        chunks, section = _encode_classed(scene, params, plan, kept, grid)
        chunks = {POSN: pos.encode_positions(voxels, grid), **chunks}
    else:
        chunks, section = _encode_uniform(scene, params, kept, grid)
        chunks = {POSN: pos.encode_positions(voxels, grid), **chunks}
    chunks = {t: chunks[t] for t in ATTRIBUTE_TYPES if t in chunks}  # the order the file holds them in
    return EncodedAttributes(chunks=chunks, section=section, kept=kept, lam=params.lam)


def _encode_uniform(
    scene: GaussianScene, params: CodecParams, kept: np.ndarray, grid: PositionGrid
) -> tuple[dict[str, bytes], AttributeSection]:
    """Versions 1 to 3: one class, every Gaussian at the rate's steps."""
    lam = params.lam
    base = class_steps(params, scene.sh_degree)
    section = AttributeSection.of_classes(int(kept.size), int(scene.sh_degree), grid, (base,), False)
    quant = AttributeQuantisers.from_section(section, params.sh_deadzone)
    symbols = {g.chunk: _quantised(g, scene, kept, quant, base, lam) for g in GROUP_CHUNKS}
    chunks = {t: encode_matrix(q) for t, q in symbols.items()}
    if scene.sh_degree > 0:
        opac_q = symbols[OPAC][:, 0]
        # Faint Gaussians' view-dependent colour hardly shows: drop it (flag 0), an encoder-only choice.
        faint = opac_q.astype(np.float64) < min(0.5, params.sh_faint_alpha * lam) * base.opacity_levels
        # Rows of the float32 SH rest are picked and widened block by block (int32 symbols: a million
        # Gaussians' 45 coefficients take 180 MB).
        rest, rows = scene.sh_rest.detach().cpu().numpy(), kept[~faint]
        _check_range("SH rest", rest, np.asarray(base.sh_steps)[None, :, None], lam, rows)
        q = quant.sh_rest.quantise(rest, rows)
        nonzero = (q != 0).any(axis=1)
        flags = np.zeros(kept.size, np.int64)
        flags[np.flatnonzero(~faint)[nonzero]] = 1
        chunks[SHRS] = msgpack.packb(
            [encode_matrix(flags[:, None]), encode_matrix(q[nonzero])], use_bin_type=True
        )
        del q, nonzero
    return chunks, section


def _plan(scene: GaussianScene, params: CodecParams, sig: Significance, candidates: np.ndarray) -> Plan:
    """gspc/codec/precision.py's plan at this rate, for every input Gaussian."""
    base = class_steps(params, scene.sh_degree)
    alpha = torch.sigmoid(scene.opacities.detach().double()).cpu().numpy()
    steps = RateSteps(
        base.opacity_levels,
        base.scale_step,
        2.0 * SQRT_HALF / base.rotation_levels,
        base.dc_step,
        tuple(base.sh_steps[b * b - 1] for b in range(1, scene.sh_degree + 1)),
    )
    faint = min(0.5, params.sh_faint_alpha * params.lam)
    return plan_precision(sig, alpha, steps, params.precision, candidates, faint, params.lam)


def _encode_classed(
    scene: GaussianScene, params: CodecParams, plan: Plan, kept: np.ndarray, grid: PositionGrid
) -> tuple[dict[str, bytes], AttributeSection]:
    """Version 4: each Gaussian's class and SH degree as planned (gspc/codec/precision.py), each class's
    rows coded as matrices of their own."""
    lam, prec, degree = params.lam, params.precision, scene.sh_degree
    exponent = plan.exponent[kept]
    # Class 0 is the rate's own steps; the others follow in increasing step.
    exps = [0, *sorted(set(np.unique(exponent).tolist()) - {0})]
    classes = np.zeros(len(kept), np.int64)
    for i, e in enumerate(exps):
        classes[exponent == e] = i
    class_list = [class_steps(params, degree, e, prec.groups) for e in exps]
    n = int(kept.size)
    degrees = plan.degree[kept] if degree > 0 else np.zeros(n, np.int64)
    pmap = PrecisionMap(classes, degrees)
    section = AttributeSection.of_classes(n, int(degree), grid, tuple(class_list), True)
    parts: dict[str, list[bytes]] = {t: [] for t in (*GROUP_TYPES, SHRS)}
    rest = scene.sh_rest.detach().cpu().numpy()
    for k, steps_k in enumerate(class_list):
        order = pmap.rows(k)
        rows = kept[order]
        quant = AttributeQuantisers.from_steps(steps_k, params.sh_deadzone)
        for g in GROUP_CHUNKS:
            parts[g.chunk].append(encode_matrix(_quantised(g, scene, rows, quant, steps_k, lam)))
        if degree > 0:  # every coefficient of the class's Gaussians with any SH rest, once; each band a slice
            deg = degrees[order]
            coded = rows[deg >= 1]
            _check_range("SH rest", rest, np.asarray(steps_k.sh_steps)[None, :, None], lam, coded)
            q, deg = quant.sh_rest.quantise(rest, coded), deg[deg >= 1]
            for b in range(1, degree + 1):
                parts[SHRS].append(encode_matrix(q[deg >= b, 3 * (b * b - 1) : 3 * ((b + 1) ** 2 - 1)]))
    chunks = {PREC: encode_precision(pmap, degree)}
    chunks.update({t: pack_bins(p) for t, p in parts.items() if t != SHRS or degree > 0})
    return chunks, section


def _check_ranges(scene: GaussianScene, steps: ClassSteps, params: CodecParams, rows: np.ndarray) -> None:
    """ValueRangeError where any of ``rows`` has a log scale, DC or SH rest value beyond ``steps``' range."""
    _check_range("log scale", _np(scene.log_scales, rows), steps.scale_step, params.lam)
    _check_range("SH DC", _np(scene.sh_dc, rows), steps.dc_step, params.lam)
    if scene.sh_degree > 0:  # faint Gaussians' SH rest is dropped whatever it holds
        alpha = torch.sigmoid(scene.opacities.detach().double()).cpu().numpy()[rows]
        rows = rows[alpha >= min(0.5, params.sh_faint_alpha * params.lam)]
        rest, sh = scene.sh_rest.detach().cpu().numpy(), np.asarray(steps.sh_steps)[None, :, None]
        _check_range("SH rest", rest, sh, params.lam, rows)


def _check_range(name: str, values: np.ndarray, steps, lam: float, rows: np.ndarray | None = None) -> None:
    """ValueRangeError naming the attribute where a Gaussian's value is too large to code at this rate."""
    count, worst = out_of_range(values, steps, rows)
    if count:
        limit = SYMBOL_LIMIT * float(np.min(steps))
        finest = " for the finest coefficient" if np.size(steps) > 1 else ""
        raise ValueRangeError(
            f"{count} Gaussian(s) have {name} values up to {worst:.3g}, beyond what lambda {lam:g} can code "
            f"(+-{limit:.3g}{finest}; a larger lambda raises the limit)"
        )


def _matrix(chunks: dict[str, bytes], name: str, n: int, c: int) -> np.ndarray:
    return decode_matrix(chunks[name], (n, c))


def decode_attributes(chunks: dict[str, bytes], section: AttributeSection) -> GaussianScene:
    """Decode chunks to a float32 scene in curve order; identical on every machine. The header ``section``
    was checked where it was read (gspc/format/attribute_section.py); the payloads are checked here."""
    return decode_section(chunks, section).scene


@dataclass(frozen=True)
class DecodedSection:
    scene: GaussianScene  # in curve order
    precision: PrecisionMap | None  # each Gaussian's class and SH degree at version 4, else None


def decode_section(chunks: dict[str, bytes], section: AttributeSection) -> DecodedSection:
    """:func:`decode_attributes`, with the precision map the PREC chunk holds (read once)."""
    n, degree, grid = section.n, section.sh_degree, section.position
    check_attribute_chunks(chunks, section)
    voxels = pos.decode_positions(chunks[POSN], grid, n)
    means = pos.positions(voxels, grid)
    pmap = decode_precision(chunks[PREC], section) if section.precision else None
    values = _decode_classed(chunks, section, pmap) if pmap is not None else _decode_uniform(chunks, section)
    t = torch.from_numpy
    scene = GaussianScene(
        t(means),
        t(values["quats"]),
        t(values["log_scales"]),
        t(values["opacities"]),
        t(values["sh_dc"]),
        t(values["sh_rest"]),
        degree,
    )
    return DecodedSection(scene, pmap)


def _decode_uniform(chunks: dict[str, bytes], section: AttributeSection) -> dict[str, np.ndarray]:
    """Versions 1 to 3: every attribute group at the section's one class, by scene attribute."""
    n, degree = section.n, section.sh_degree
    quant = AttributeQuantisers.from_section(section)
    out = {
        g.attribute: _dequantised(g, quant, decode_matrix(chunks[g.chunk], (n, g.columns)))
        for g in GROUP_CHUNKS
    }
    k = num_sh_rest(degree)
    rest = np.zeros((n, k, 3), np.float32)
    if degree > 0:
        try:
            flag_payload, rest_payload = msgpack.unpackb(chunks[SHRS], raw=False)
        except Exception:
            raise CodecError("chunk SHRS is malformed") from None
        if not (isinstance(flag_payload, bytes) and isinstance(rest_payload, bytes)):
            raise CodecError("chunk SHRS is not a pair of msgpack bins")
        flags = decode_matrix(flag_payload, (n, 1))
        if ((flags != 0) & (flags != 1)).any():
            raise CodecError("chunk SHRS has a malformed flag matrix")
        flags = flags[:, 0].astype(bool)
        q = decode_matrix(rest_payload, (int(flags.sum()), 3 * k))
        rest[flags] = quant.sh_rest.dequantise(q)
    out["sh_rest"] = rest
    return out


def _decode_classed(
    chunks: dict[str, bytes], section: AttributeSection, pmap: PrecisionMap
) -> dict[str, np.ndarray]:
    """Version 4 (spec 10.13): every class's rows from their own matrices, SH rest band by band up to each
    Gaussian's degree; by scene attribute."""
    n, degree = section.n, section.sh_degree
    classes = section.all_classes
    out = {g.attribute: np.empty((n, g.columns) if g.columns > 1 else n, np.float32) for g in GROUP_CHUNKS}
    rest = np.zeros((n, num_sh_rest(degree), 3), np.float32)
    bins = {g.chunk: unpack_bins(chunks[g.chunk], g.chunk, len(classes)) for g in GROUP_CHUNKS}
    rest_bins = unpack_bins(chunks[SHRS], SHRS, len(classes) * degree) if degree > 0 else []
    for k, steps_k in enumerate(classes):
        rows = pmap.rows(k)
        quant = AttributeQuantisers.from_steps(steps_k)
        for g in GROUP_CHUNKS:
            out[g.attribute][rows] = _dequantised(
                g, quant, decode_matrix(bins[g.chunk][k], (len(rows), g.columns))
            )
        for b in range(1, degree + 1):
            band_rows = rows[pmap.degrees[rows] >= b]
            q = decode_matrix(rest_bins[k * degree + b - 1], (len(band_rows), 3 * (2 * b + 1)))
            band = np.asarray(steps_k.sh_steps[b * b - 1 : (b + 1) ** 2 - 1])[None, :, None]
            rest[band_rows, b * b - 1 : (b + 1) ** 2 - 1] = (
                q.reshape(-1, 2 * b + 1, 3).astype(np.float64) * band
            )
    out["sh_rest"] = rest
    return out


def decoded_precision(chunks: dict[str, bytes], section: AttributeSection) -> PrecisionMap | None:
    """The per-Gaussian classes and SH degrees of a version-4 file (None below version 4)."""
    return decode_precision(chunks[PREC], section) if section.precision else None
