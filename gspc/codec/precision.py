"""Per-Gaussian precision (attribute codec version 4, spec 10.13): which quantiser class and SH degree each
Gaussian gets, and which Gaussians are worth their bytes at all.

The decoder reads a :class:`PrecisionMap` from the ``PREC`` chunk and never recomputes it. The encoder plans
one (:func:`plan_precision`) from a :class:`Significance`, what gspc/encoder/significance.py measured of each
Gaussian over the encoder's views, and the rate's :class:`PrecisionParams`:

- **classes**: a Gaussian's expected contribution to the views' squared error from quantisation is about
  ``sum_g (sensitivity_g x step_g)^2`` over its attribute groups. Bit allocation under a rate constraint
  gives each Gaussian a step multiplier proportional to ``1 / sqrt`` of that (each halving of a step costs
  about one bit per component): so classes are powers of two of the rate's steps, the exponent following
  half the log2 of the Gaussian's sensitivity relative to the scene's median, within the params' range.
- **SH degree**: a band is kept where dropping it would change the views (its first-order change of the
  renders, ``sh_band_change``) by more than its coded step does;
- **removal**: a Gaussian whose blending weight over the views is below a fraction of a pixel per view
  at this rate is dropped (never at rates finer than the params allow).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import msgpack
import numpy as np

from gspc.codec.entropy import decode_matrix, encode_matrix, matrix_table_entries
from gspc.errors import CodecError, ValueRangeError
from gspc.format.attribute_section import AttributeSection
from gspc.limits import max_model_entries

# The attribute groups whose steps the classes scale, with the Significance gradient each is weighed by.
CLASSED_GROUPS = ("opacities", "log_scales", "quats", "sh_dc", "sh_rest")


@dataclass(frozen=True)
class Significance:
    """Per input Gaussian, what it does to the encoder's views (gspc/encoder/significance.py), each float64.

    ``weight``: sum over views of its blending weight sum_pixels alpha T, each view's as a fraction of the
    view's pixels. ``gradient``: attribute name -> sum over views of |d sum(image) / d attribute| (summed over
    the attribute's components). ``sh_band_change``: (N, D) sum over views of |the first-order change of
    sum(image) when SH band b + 1 is set to zero|. ``views``: how many views were summed.
    """

    weight: np.ndarray
    gradient: dict[str, np.ndarray]
    sh_band_change: np.ndarray
    views: int

    def ranking(self, measure: str) -> np.ndarray:
        """Gaussian indices, most significant first (ties: lower index first), for "weight" or
        "gradient:<attribute>"."""
        values = self.weight if measure == "weight" else self.gradient[measure.split(":", 1)[1]]
        return np.lexsort((np.arange(len(values)), -values))


@dataclass(frozen=True)
class PrecisionParams:
    """How the encoder spends precision per Gaussian (an encoder choice: none of it is in the file).

    Class step multipliers are ``2^e`` for integer ``e`` in ``exponents`` (``e = 0``: the rate's own steps,
    class 0); a Gaussian's ``e`` is ``round(bias - log2(sensitivity / median) / 2)``. ``sh_keep``: a band is
    kept where its change of the views is at least this many of its coded steps (0 keeps every band).
    ``prune_pixels``: a Gaussian whose mean blending weight per view is below this x lambda pixels' worth (of
    a 256 x 256 view) is removed (0: never).
    """

    exponents: tuple[int, int] = (-1, 2)  # (finest, coarsest)
    bias: float = 0.0
    sh_keep: float = 0.0
    prune_pixels: float = 0.0
    groups: tuple[str, ...] = field(default=CLASSED_GROUPS)


@dataclass(frozen=True)
class PrecisionMap:
    """Per Gaussian in decoded order: its precision class (0 .. C - 1) and its SH degree (0 .. sh_degree)."""

    classes: np.ndarray  # (N,) int64
    degrees: np.ndarray  # (N,) int64

    def rows(self, k: int) -> np.ndarray:
        """The Gaussians of class ``k``, in decoded order."""
        return np.flatnonzero(self.classes == k)


def encode_precision(pmap: PrecisionMap, sh_degree: int) -> bytes:
    """The PREC payload: one ECM N x 1 of classes, N x 2 with the SH degrees beside them at SH degree > 0."""
    cols = [pmap.classes] if sh_degree == 0 else [pmap.classes, pmap.degrees]
    return encode_matrix(np.stack(cols, 1).astype(np.int64))


def decode_precision(payload: bytes, section: AttributeSection) -> PrecisionMap:
    """The PREC payload of a version-4 section, each value checked against the section."""
    n, degree = section.n, section.sh_degree
    m = decode_matrix(payload, (n, 1 if degree == 0 else 2))
    classes = m[:, 0].astype(np.int64)
    if ((classes < 0) | (classes >= len(section.all_classes))).any():
        raise CodecError(f"chunk PREC names a precision class outside 0..{len(section.all_classes) - 1}")
    degrees = np.zeros(n, np.int64) if degree == 0 else m[:, 1].astype(np.int64)
    if ((degrees < 0) | (degrees > degree)).any():
        raise CodecError(f"chunk PREC names an SH degree outside 0..{degree}")
    return PrecisionMap(classes, degrees)


def pack_bins(parts: list[bytes]) -> bytes:
    """A chunk of one matrix per bin (spec 10.13); never one the decoder refuses for its tables (spec 10.10):
    tables wider than the chunk's bytes warrant come from steps far finer than the values' spread."""
    payload = msgpack.packb(parts, use_bin_type=True)
    entries = sum(matrix_table_entries(p) for p in parts)
    if entries > max_model_entries(len(payload)):
        raise ValueRangeError(
            f"a chunk's matrices need {entries:,} table entries for {len(payload):,} bytes, more than a "
            "decoder accepts; a larger lambda codes it"
        )
    return payload


def unpack_bins(payload: bytes, name: str, count: int) -> list[bytes]:
    """A chunk that is a msgpack array of exactly ``count`` bins (spec 10.13)."""
    try:
        parts = msgpack.unpackb(payload, raw=False)
    except Exception:
        raise CodecError(f"chunk {name} is malformed") from None
    if not (isinstance(parts, list) and len(parts) == count and all(isinstance(p, bytes) for p in parts)):
        raise CodecError(f"chunk {name} is not an array of {count} msgpack bins")
    # The chunk's matrices share one table bound (spec 10.10), checked before any table is built: each
    # matrix's own bound has a floor, and 16 classes would multiply it (a 10 KB file took 30 s).
    entries, limit = sum(matrix_table_entries(p) for p in parts), max_model_entries(len(payload))
    if entries > limit:
        raise CodecError(
            f"chunk {name}'s entropy models build {entries:,} table entries from {len(payload):,} bytes "
            f"(limit {limit:,})"
        )
    return parts


# ---------------------------------------------------------------------------------------------
# The encoder's plan


def sensitivity(
    sig: Significance, rows: np.ndarray, steps: dict[str, float], groups: tuple[str, ...]
) -> np.ndarray:
    """(len(rows),) sum over ``groups`` of (gradient x the group's step)^2: how much a Gaussian's quantisation
    at these steps moves the views, to first order."""
    out = np.zeros(len(rows))
    for g in groups:
        out += (sig.gradient[g][rows] * steps[g]) ** 2
    return out


def class_exponents(sens: np.ndarray, params: PrecisionParams) -> np.ndarray:
    """Each Gaussian's step exponent ``e`` (multiplier 2^e) from its sensitivity (see PrecisionParams)."""
    lo, hi = params.exponents
    positive = sens[sens > 0]
    if positive.size == 0:
        return np.full(len(sens), hi, np.int64)
    median = float(np.median(positive))
    rel = np.log2(np.maximum(sens, median * 2.0**-60) / median)
    return np.clip(np.rint(params.bias - rel / 2), lo, hi).astype(np.int64)


def sh_degrees(
    change: np.ndarray, band_steps: np.ndarray, multipliers: np.ndarray, sh_keep: float
) -> np.ndarray:
    """Each Gaussian's SH degree: the highest band whose first-order change of the views (``change``, N x D)
    is at least ``sh_keep`` x its coded step (``band_steps`` (D,) x the Gaussian's class multiplier); every
    band below it is kept with it."""
    n, d = change.shape
    if sh_keep <= 0 or d == 0:
        return np.full(n, d, np.int64)
    keep = change >= sh_keep * band_steps[None, :] * multipliers[:, None]
    highest = np.where(keep.any(1), d - np.argmax(keep[:, ::-1], axis=1), 0)
    return highest.astype(np.int64)


def prune_by_weight(sig: Significance, lam: float, params: PrecisionParams) -> np.ndarray:
    """Per input Gaussian: worth keeping at this rate (blending weight per view above the params' floor)."""
    if params.prune_pixels <= 0:
        return np.ones(len(sig.weight), bool)
    per_view = sig.weight / max(sig.views, 1) * (256 * 256)  # pixels' worth of a 256 x 256 view
    return per_view >= params.prune_pixels * lam


def band_of(k: int) -> int:
    """The SH band (1..3) of rest coefficient ``k`` (0..14)."""
    return int(math.isqrt(k + 1))
