"""Per-Gaussian precision as a file holds it (attribute codec version 4, spec 10.13): each Gaussian's
quantiser class and SH degree (:class:`PrecisionMap`, the ``PREC`` chunk), and chunks of one matrix per class.

The decoder reads the map and never recomputes it; how the encoder plans it is gspc/encoder/precision_plan.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import msgpack
import numpy as np

from gspc.codec.entropy import decode_matrix, encode_matrix, matrix_table_entries
from gspc.errors import CodecError, ValueRangeError
from gspc.format.attribute_section import AttributeSection
from gspc.limits import DecodeBudget, max_model_entries


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


def decode_precision(
    payload: bytes, section: AttributeSection, budget: DecodeBudget | None = None
) -> PrecisionMap:
    """The PREC payload of a version-4 section, each value checked against the section."""
    n, degree = section.n, section.sh_degree
    m = decode_matrix(payload, (n, 1 if degree == 0 else 2), budget)
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


def unpack_bins(payload: bytes, name: str, count: int, budget: DecodeBudget | None = None) -> list[bytes]:
    """A chunk that is a msgpack array of exactly ``count`` bins (spec 10.13); its matrices' models spend
    ``budget`` here, once (their decode does not spend it again)."""
    try:
        parts = msgpack.unpackb(payload, raw=False)
    except Exception:
        raise CodecError(f"chunk {name} is malformed") from None
    if not (isinstance(parts, list) and len(parts) == count and all(isinstance(p, bytes) for p in parts)):
        raise CodecError(f"chunk {name} is not an array of {count} msgpack bins")
    # The chunk's matrices share one table bound (spec 10.10), checked before any table is built: each
    # matrix's own bound has a floor, and 16 classes would multiply it (bench/robustness.md, "Moved from code
    # comments").
    entries, limit = sum(matrix_table_entries(p, budget) for p in parts), max_model_entries(len(payload))
    if entries > limit:
        raise CodecError(
            f"chunk {name}'s entropy models build {entries:,} table entries from {len(payload):,} bytes "
            f"(limit {limit:,})"
        )
    return parts
