"""significance.py's per-view sums compiled for the CPU (numba): one pass over each gradient.

Why: in PyTorch a view's sums are whole-tensor passes (absolute values, sums, the SH rest's products with
its coefficients widened to float64 and summed per band over strided slices), and at a million Gaussians of
SH degree 3 they cost more than the view's render forward and backward (bench/speed.md, "The significance
measure's per-view sums compiled"). Here each Gaussian's sums stay in registers. Products are taken in the
inputs' dtype and summed in float64 (the bands' sums equal PyTorch's float64 ones; the groups' absolute
sums differ from float32 ones by round-off).
"""

from __future__ import annotations

import numba
import numpy as np

from gspc.render.kernels import JIT


@numba.njit(**JIT)
def abs_row_sums(rows: np.ndarray, drawn: np.ndarray) -> np.ndarray:
    """(N, K) -> (N,) float64: sum_k |rows[i, k]| for i in ``drawn``, 0 elsewhere (the rows that are all
    zero: a view's never-drawn Gaussians have no gradient)."""
    n, k = rows.shape
    out = np.zeros(n)
    for i in drawn:
        s = 0.0
        for j in range(k):
            s += abs(rows[i, j])
        out[i] = s
    return out


@numba.njit(**JIT)
def band_changes(grad: np.ndarray, coef: np.ndarray, degree: int, drawn: np.ndarray) -> np.ndarray:
    """(N, R, C) SH-rest gradient and coefficients -> (N, degree) float64: per band b = 1..degree,
    |sum over the band's coefficients (rows b^2 - 1 .. (b + 1)^2 - 2) and channels of grad x coef|, for
    the Gaussians in ``drawn`` (0 for the rest, whose gradient is 0)."""
    n, _, channels = grad.shape
    out = np.zeros((n, degree))
    for i in drawn:
        for b in range(1, degree + 1):
            s = 0.0
            for r in range(b * b - 1, (b + 1) * (b + 1) - 1):
                for c in range(channels):
                    s += grad[i, r, c] * coef[i, r, c]
            out[i, b - 1] = abs(s)
    return out
