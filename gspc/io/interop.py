"""Float values other tools write that mean something valid, mapped at read time to what gspc can hold.

Readers of float attributes (the INRIA PLY reader) pass their columns through here before validation, so a
scene from splat-transform or spz-js loads, while values that mean nothing (NaN, an all-zero rotation, a
double too large for float32) are still refused by name. A quaternion is a direction whatever its length, so
one too small or too large for float32 arithmetic is made unit length rather than refused.
"""

from __future__ import annotations

import numpy as np

from gspc.errors import InputError

# splat-transform's compressed-PLY reader and spz-js write opacity logits of +inf / -inf for alpha 1 / 0.
# They become +-20: in float32, sigmoid(20) = 1 - 2e-9 rounds to exactly 1.0 (the spacing below 1 is 6e-8),
# and sigmoid(-20) = 2e-9 leaves 1 - alpha, the factor compositing multiplies transmittance by, at exactly
# 1.0, so the Gaussian is as invisible as alpha 0. A logit whose float32 alpha is exactly 0 would have to be
# below -103.9, where the renderer's log(alpha) (gspc/render/rasterize.py) becomes -inf; -20 keeps it finite.
OPACITY_LOGIT_LIMIT = 20.0

# Quaternions whose largest component is below TINY_QUATERNION or above HUGE_QUATERNION are rescaled to unit
# length in float64: their squared norm, which float32 code downstream computes to normalise them, would
# underflow (below about 1e-19 it is 0 in float32) or overflow (above about 1e19 it is infinite), so they
# would read as "all-zero" or turn into NaN though their direction is well defined.
TINY_QUATERNION = 1e-10
HUGE_QUATERNION = 1e10

FLOAT32_MAX = float(np.finfo(np.float32).max)


def finite_opacity_logits(logits: np.ndarray) -> np.ndarray:
    """``logits`` with +inf / -inf replaced by +-OPACITY_LOGIT_LIMIT (NaN left for validation to refuse)."""
    out = np.array(logits, dtype=np.float32, copy=True)
    out[np.isposinf(out)] = OPACITY_LOGIT_LIMIT
    out[np.isneginf(out)] = -OPACITY_LOGIT_LIMIT
    return out


def normalise_extreme_quaternions(quats: np.ndarray) -> np.ndarray:
    """``quats`` (N, 4) with finite rows that are tiny or huge (not zero) scaled to unit length; other rows
    unchanged."""
    out = np.array(quats, dtype=np.float32, copy=True)
    with np.errstate(invalid="ignore"):
        largest = np.abs(out).max(axis=1)
    extreme = (largest < TINY_QUATERNION) | (largest > HUGE_QUATERNION)
    extreme &= np.isfinite(out).all(axis=1) & (largest > 0)
    if extreme.any():
        q = out[extreme].astype(np.float64) / largest[extreme, None]  # exact scaling first: no under/overflow
        out[extreme] = q / np.linalg.norm(q, axis=1, keepdims=True)
    return out


def float32_column(values: np.ndarray, name: str, source: object) -> np.ndarray:
    """A PLY property as float32; InputError naming it where a finite value overflows float32."""
    values = np.asarray(values)
    if values.dtype.kind == "f" and values.dtype.itemsize > 4:
        finite = np.isfinite(values)
        over = finite & (np.abs(np.where(finite, values, 0.0)) > FLOAT32_MAX)
        if over.any():
            worst = float(np.abs(values[over]).max())
            raise InputError(
                f"{source}: property '{name}' has {int(over.sum())} value(s) beyond float32's range "
                f"(up to {worst:.3g}; float32 stops at {FLOAT32_MAX:.3g})"
            )
    return np.asarray(values, dtype=np.float32)
