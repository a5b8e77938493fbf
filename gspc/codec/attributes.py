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
  only flagged Gaussians' SH rest, coefficient-major, steps growing with degree. No SHRS at degree 0. At
  version 5 ``SHRS`` is a codebook instead: its entries at class 0's steps, then each Gaussian's entry.
Each chunk is an :func:`gspc.codec.entropy.encode_matrix` payload (SHRS: a msgpack pair). Each attribute's
quantiser (quantise, exact dequantise and cell together) is in :mod:`gspc.codec.quantisers`.
The byte layouts are specified in spec/gspc-format.md, section 10. Which Gaussians are coded, at which
steps, in which classes, is the encoder's choice (gspc/encoder/coding.py); this module writes and reads
what it chose.
"""

from __future__ import annotations

from dataclasses import dataclass

import msgpack
import numpy as np
import torch

from gspc.codec import positions as pos
from gspc.codec.entropy import SYMBOL_LIMIT, decode_matrix, encode_matrix
from gspc.codec.precision import (
    PrecisionMap,
    decode_precision,
    encode_precision,
    pack_bins,
    unpack_bins,
)
from gspc.codec.quantisers import AttributeQuantisers, SmallestThreeQuantiser, out_of_range
from gspc.errors import CodecError, ValueRangeError
from gspc.format.attribute_section import (
    AttributeSection,
    ClassSteps,
    PositionGrid,
    check_attribute_chunks,
)
from gspc.format.chunks import ATTRIBUTE_TYPES, OPAC, POSN, PREC, ROTN, SCAL, SHDC, SHRS
from gspc.limits import DecodeBudget
from gspc.scene import GaussianScene, num_sh_rest


def rotation_error_bound(levels: int) -> float:
    """Largest rotation angle (radians) between a unit quaternion and its decoded version."""
    return SmallestThreeQuantiser(levels).error_bound()


def _np(t: torch.Tensor, rows: np.ndarray) -> np.ndarray:
    """``t[rows]`` as float64 numpy (rows picked first: a large scene's SH rest doubles in float64)."""
    return t.detach().cpu().numpy()[rows].astype(np.float64)


@dataclass(frozen=True)
class SHCodebook:
    """The SH rest by codebook (version 5, spec 10.16), as the encoder chose it: ``entries`` the symbols of
    each entry (K x 3k, columns as SHRS's, at class 0's ``sh_steps``) and ``index`` each input Gaussian's
    entry (-1 where it has none)."""

    entries: np.ndarray
    index: np.ndarray


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
    g: GroupChunk, scene: GaussianScene, rows: np.ndarray, quant: AttributeQuantisers, steps: ClassSteps
) -> np.ndarray:
    """The symbols of group ``g`` for ``rows`` of the scene, (len(rows), g.columns); ValueRangeError where a
    value is beyond what the class's step codes."""
    values = _np(getattr(scene, g.attribute), rows)
    if g.checked is not None:
        check_range(g.name, values, getattr(steps, g.checked))
    return getattr(quant, g.quantiser).quantise(values).reshape(len(rows), g.columns)


def _dequantised(g: GroupChunk, quant: AttributeQuantisers, q: np.ndarray) -> np.ndarray:
    """Group ``g``'s decoded values from its (m, g.columns) matrix (opacity: a vector)."""
    return getattr(quant, g.quantiser).dequantise(q[:, 0] if g.columns == 1 else q)


class OutOfRange(ValueRangeError):
    """A value beyond what a class's steps code (the encoder says which rate: gspc/encoder/coding.py)."""

    def __init__(self, name: str, count: int, worst: float, limit: float, finest: bool) -> None:
        self.name, self.count, self.worst, self.limit, self.finest = name, count, worst, limit, finest
        at = " for the finest coefficient" if finest else ""
        super().__init__(
            f"{count} Gaussian(s) have {name} values up to {worst:.3g}, beyond what the steps code "
            f"(+-{limit:.3g}{at})"
        )


def check_range(name: str, values: np.ndarray, steps, rows: np.ndarray | None = None) -> None:
    """OutOfRange naming the attribute where a value of ``rows`` (all by default) is too large to code."""
    count, worst = out_of_range(values, steps, rows)
    if count:
        limit = SYMBOL_LIMIT * float(np.min(steps))
        raise OutOfRange(name, count, worst, limit, np.size(steps) > 1)


def encode_section(
    scene: GaussianScene,
    kept: np.ndarray,
    voxels: np.ndarray,
    grid: PositionGrid,
    classes: tuple[ClassSteps, ...],
    pmap: PrecisionMap | None,
    sh_deadzone: float = 0.0,
    faint_alpha: float = 0.0,
    codebook: SHCodebook | None = None,
) -> tuple[dict[str, bytes], AttributeSection]:
    """The attribute chunks (in file order) and header section of ``scene``'s rows ``kept``, in curve order,
    their ``voxels`` on ``grid``. With a precision map (version 4, spec 10.13) each Gaussian has its class
    among ``classes`` and its SH degree; without one (versions 1 to 3) every Gaussian is at ``classes[0]``
    and those whose coded alpha is under ``faint_alpha`` carry no SH rest. ``sh_deadzone``: the SH rest's
    rounding offset towards zero. Both are the encoder's choices: the file holds their outcome. A
    ``codebook`` (with a precision map: version 5) codes the SH rest of every Gaussian of degree >= 1."""
    if pmap is not None:
        chunks, section = _encode_classed(scene, kept, grid, classes, pmap, sh_deadzone, codebook)
    else:
        chunks, section = _encode_uniform(scene, kept, grid, classes[0], sh_deadzone, faint_alpha)
    chunks = {POSN: pos.encode_positions(voxels, grid), **chunks}
    return {t: chunks[t] for t in ATTRIBUTE_TYPES if t in chunks}, section


def _encode_uniform(
    scene: GaussianScene,
    kept: np.ndarray,
    grid: PositionGrid,
    base: ClassSteps,
    sh_deadzone: float,
    faint_alpha: float,
) -> tuple[dict[str, bytes], AttributeSection]:
    """Versions 1 to 3: one class, every Gaussian at its steps."""
    section = AttributeSection.of_classes(int(kept.size), int(scene.sh_degree), grid, (base,), False)
    quant = AttributeQuantisers.from_section(section, sh_deadzone)
    symbols = {g.chunk: _quantised(g, scene, kept, quant, base) for g in GROUP_CHUNKS}
    chunks = {t: encode_matrix(q) for t, q in symbols.items()}
    if scene.sh_degree > 0:
        # Faint Gaussians' view-dependent colour hardly shows: the encoder drops it (flag 0).
        faint = symbols[OPAC][:, 0].astype(np.float64) < faint_alpha * base.opacity_levels
        # Rows of the float32 SH rest are picked and widened block by block (int32 symbols of every
        # coefficient of a large scene are hundreds of MB).
        rest, rows = scene.sh_rest.detach().cpu().numpy(), kept[~faint]
        check_range("SH rest", rest, np.asarray(base.sh_steps)[None, :, None], rows)
        q = quant.sh_rest.quantise(rest, rows)
        nonzero = (q != 0).any(axis=1)
        flags = np.zeros(kept.size, np.int64)
        flags[np.flatnonzero(~faint)[nonzero]] = 1
        chunks[SHRS] = msgpack.packb(
            [encode_matrix(flags[:, None]), encode_matrix(q[nonzero])], use_bin_type=True
        )
        del q, nonzero
    return chunks, section


def _encode_classed(
    scene: GaussianScene,
    kept: np.ndarray,
    grid: PositionGrid,
    class_list: tuple[ClassSteps, ...],
    pmap: PrecisionMap,
    sh_deadzone: float,
    codebook: SHCodebook | None,
) -> tuple[dict[str, bytes], AttributeSection]:
    """Version 4: each class's rows coded as matrices of their own, the SH rest band by band up to each
    Gaussian's degree; version 5: the SH rest by ``codebook``."""
    degree = scene.sh_degree
    n = int(kept.size)
    degrees = pmap.degrees
    entries = 0 if codebook is None else len(codebook.entries)
    section = AttributeSection.of_classes(n, int(degree), grid, tuple(class_list), True, entries)
    parts: dict[str, list[bytes]] = {t: [] for t in (*GROUP_TYPES, SHRS)}
    rest = scene.sh_rest.detach().cpu().numpy()
    for k, steps_k in enumerate(class_list):
        order = pmap.rows(k)
        rows = kept[order]
        quant = AttributeQuantisers.from_steps(steps_k, sh_deadzone)
        for g in GROUP_CHUNKS:
            parts[g.chunk].append(encode_matrix(_quantised(g, scene, rows, quant, steps_k)))
        if degree > 0 and codebook is None:  # each coefficient of the class's SH rest once; a band a slice
            deg = degrees[order]
            coded = rows[deg >= 1]
            check_range("SH rest", rest, np.asarray(steps_k.sh_steps)[None, :, None], coded)
            q, deg = quant.sh_rest.quantise(rest, coded), deg[deg >= 1]
            for b in range(1, degree + 1):
                parts[SHRS].append(encode_matrix(q[deg >= b, 3 * (b * b - 1) : 3 * ((b + 1) ** 2 - 1)]))
    if codebook is not None:
        index = codebook.index[kept[degrees >= 1]]
        if (index < 0).any() or (index >= entries).any():
            raise ValueError("a Gaussian with SH rest has no codebook entry")
        parts[SHRS] = [encode_matrix(codebook.entries), encode_matrix(index[:, None])]
    chunks = {PREC: encode_precision(pmap, degree)}
    chunks.update({t: pack_bins(p) for t, p in parts.items() if t != SHRS or degree > 0})
    return chunks, section


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


def decode_section(
    chunks: dict[str, bytes], section: AttributeSection, budget: DecodeBudget | None = None
) -> DecodedSection:
    """:func:`decode_attributes`, with the precision map the PREC chunk holds (read once). ``budget``: what
    the file's decode may still spend, where the section is one of a tiled file's (spec 10.14)."""
    n, degree, grid = section.n, section.sh_degree, section.position
    check_attribute_chunks(chunks, section)
    voxels = pos.decode_positions(chunks[POSN], grid, n, budget)
    means = pos.positions(voxels, grid)
    pmap = decode_precision(chunks[PREC], section, budget) if section.precision else None
    if pmap is not None:
        values = _decode_classed(chunks, section, pmap, budget)
    else:
        values = _decode_uniform(chunks, section, budget)
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


def _decode_uniform(
    chunks: dict[str, bytes], section: AttributeSection, budget: DecodeBudget | None
) -> dict[str, np.ndarray]:
    """Versions 1 to 3: every attribute group at the section's one class, by scene attribute."""
    n, degree = section.n, section.sh_degree
    quant = AttributeQuantisers.from_section(section)
    out = {
        g.attribute: _dequantised(g, quant, decode_matrix(chunks[g.chunk], (n, g.columns), budget))
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
        flags = decode_matrix(flag_payload, (n, 1), budget)
        if ((flags != 0) & (flags != 1)).any():
            raise CodecError("chunk SHRS has a malformed flag matrix")
        flags = flags[:, 0].astype(bool)
        q = decode_matrix(rest_payload, (int(flags.sum()), 3 * k), budget)
        rest[flags] = quant.sh_rest.dequantise(q)
    out["sh_rest"] = rest
    return out


def _decode_classed(
    chunks: dict[str, bytes], section: AttributeSection, pmap: PrecisionMap, budget: DecodeBudget | None
) -> dict[str, np.ndarray]:
    """Version 4 (spec 10.13): every class's rows from their own matrices, SH rest band by band up to each
    Gaussian's degree; by scene attribute."""
    n, degree = section.n, section.sh_degree
    classes = section.all_classes
    out = {g.attribute: np.empty((n, g.columns) if g.columns > 1 else n, np.float32) for g in GROUP_CHUNKS}
    rest = np.zeros((n, num_sh_rest(degree), 3), np.float32)
    bins = {g.chunk: unpack_bins(chunks[g.chunk], g.chunk, len(classes), budget) for g in GROUP_CHUNKS}
    bands = 0 if section.codebook else degree  # the SH rest band by band, or by codebook (below)
    rest_bins = unpack_bins(chunks[SHRS], SHRS, len(classes) * bands, budget) if bands > 0 else []
    for k, steps_k in enumerate(classes):
        rows = pmap.rows(k)
        quant = AttributeQuantisers.from_steps(steps_k)
        for g in GROUP_CHUNKS:
            out[g.attribute][rows] = _dequantised(
                g, quant, decode_matrix(bins[g.chunk][k], (len(rows), g.columns))
            )
        for b in range(1, bands + 1):
            band_rows = rows[pmap.degrees[rows] >= b]
            q = decode_matrix(rest_bins[k * degree + b - 1], (len(band_rows), 3 * (2 * b + 1)))
            band = np.asarray(steps_k.sh_steps[b * b - 1 : (b + 1) ** 2 - 1])[None, :, None]
            rest[band_rows, b * b - 1 : (b + 1) ** 2 - 1] = (
                q.reshape(-1, 2 * b + 1, 3).astype(np.float64) * band
            )
    if section.codebook:
        _decode_codebook(chunks[SHRS], section, pmap, rest, budget)
    out["sh_rest"] = rest
    return out


def _decode_codebook(
    payload: bytes,
    section: AttributeSection,
    pmap: PrecisionMap,
    rest: np.ndarray,
    budget: DecodeBudget | None,
) -> None:
    """Version 5 (spec 10.16) into ``rest``: each Gaussian of degree >= 1 takes its entry's coefficients up
    to its degree, decoded at class 0's steps."""
    k, entries = rest.shape[1], section.codebook
    table_bin, index_bin = unpack_bins(payload, SHRS, 2, budget)
    table = decode_matrix(table_bin, (entries, 3 * k))
    coded = np.flatnonzero(pmap.degrees >= 1)
    index = decode_matrix(index_bin, (len(coded), 1))[:, 0]
    if ((index < 0) | (index >= entries)).any():
        raise CodecError(f"chunk SHRS has a codebook index outside 0..{entries - 1}")
    steps = np.asarray(section.sh_steps, np.float64)[None, :, None]
    values = (table.reshape(entries, k, 3).astype(np.float64) * steps).astype(np.float32)
    rest[coded] = values[index]
    degrees = pmap.degrees[coded]
    for b in range(1, section.sh_degree):  # bands above a Gaussian's degree are 0
        rest[coded[degrees == b], (b + 1) ** 2 - 1 :] = 0.0


def decoded_precision(chunks: dict[str, bytes], section: AttributeSection) -> PrecisionMap | None:
    """The per-Gaussian classes and SH degrees of a version-4 file (None below version 4)."""
    return decode_precision(chunks[PREC], section) if section.precision else None
