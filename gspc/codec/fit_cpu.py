"""entropy.py's model fit compiled for the CPU (numba): every context's cheapest model in one pass.

Why: the encoder fits 15 contexts x up to four predictors for every column of every matrix it codes, some
1,700 fits per coding of a 100k-Gaussian capture, each over a few hundred symbols. In NumPy most of a fit is
fixed cost per context (a 131 x 22 grid of rates, then a window's weights and two cross-entropies), which
takes a large share of a coding (bench/speed.md, "The attribute codec's model fit compiled"), and the
removal search codes a scene several times over.

The arithmetic is the NumPy fit's, operation for operation, so the specs and the float costs are the same bit
for bit (tests/test_entropy.py keeps that fit as its reference): products and differences of float64 in the
same order, ``np.log2`` (numba's agrees with NumPy's), integer-valued weights whose sums are exact in any
order, and the sums of cross-entropy terms taken pairwise as NumPy's ``sum`` takes them. Only the encoder
runs it; the decoder's tables come from entropy.py's ``model_weights``, which the geometric weights here
repeat."""

from __future__ import annotations

import numba
import numpy as np

from gspc.render.kernels import JIT

# NumPy's pairwise summation: runs of up to this length are summed in eight interleaved partial sums.
_PAIRWISE_BLOCK = 128


@numba.njit(inline="always", error_model="numpy")
def _block_sum(a: np.ndarray, lo: int, n: int) -> float:
    """NumPy's sum of a run of at most _PAIRWISE_BLOCK: eight interleaved partial sums, then the rest."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r = a[lo : lo + 8].copy()
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += a[lo + i + j]
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@numba.njit(inline="always", error_model="numpy")
def _pairwise_sum(a: np.ndarray, lo: int, n: int) -> float:
    """NumPy's float64 ``sum`` of ``a[lo : lo + n]``, in its order of additions: longer runs split in two
    at half their length rounded down to a multiple of 8, each half summed so, the two added. Walked with a
    stack, not by recursion (numba's cache cannot reload a recursive function)."""
    if n <= _PAIRWISE_BLOCK:
        return _block_sum(a, lo, n)
    starts = np.empty(64, np.int64)
    lengths = np.empty(64, np.int64)
    stage = np.zeros(64, np.int64)  # 0: left half next, 1: right half next, 2: both summed
    left = np.empty(64)
    top, starts[0], lengths[0], value = 0, lo, n, 0.0
    while top >= 0:
        run = lengths[top]
        if run <= _PAIRWISE_BLOCK:
            value = _block_sum(a, starts[top], run)
            top -= 1
            continue
        half = run // 2
        half -= half % 8
        if stage[top] == 0:
            stage[top] = 1
            starts[top + 1], lengths[top + 1], stage[top + 1] = starts[top], half, 0
            top += 1
        elif stage[top] == 1:
            stage[top], left[top] = 2, value
            starts[top + 1], lengths[top + 1], stage[top + 1] = starts[top] + half, run - half, 0
            top += 1
        else:
            value = left[top] + value
            top -= 1
    return value


@numba.njit(inline="always", error_model="numpy")
def _cross_entropy_bits(counts: np.ndarray, w: np.ndarray, terms: np.ndarray) -> float:
    """Bits to code ``counts`` with probabilities ``w / sum(w)`` (``w`` integer-valued, positive where counts
    are): minus the sum of count x log2 probability over the symbols seen; ``terms`` is scratch of at least
    the window's length."""
    total = 0.0
    for i in range(w.size):
        total += w[i]  # integers below 2^53: exact in any order
    m = 0
    for i in range(counts.size):
        if counts[i] > 0:
            terms[m] = float(counts[i]) * np.log2(w[i] / total)
            m += 1
    return -(0.0 + _pairwise_sum(terms, 0, m))


@numba.njit(**JIT)
def fit_sorted(
    ordered: np.ndarray,
    first: np.ndarray,
    count: np.ndarray,
    log2_z: np.ndarray,
    log2_boost: np.ndarray,
    log2_theta: np.ndarray,
    theta_positive: np.ndarray,
    thetas: np.ndarray,
    boosts: np.ndarray,
    weight_scale: float,
    empirical_max_window: int,
    empirical_scale: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each context's model from its symbols, ``ordered[first[k] : first[k] + count[k]]`` ascending.

    Returns (kind, head, bits, table_start, tables): per context the spec's kind (0 empty, 1 constant, 2
    geometric, 3 table), ``head`` = (lo, hi, centre, theta index, boost index) of kinds 1-3 (a constant's
    value in lo), its estimated bits, and a table's weights ``tables[table_start[k] : table_start[k + 1]]``.
    Divisors (error model "numpy", gspc/render/kernels.py): a window's weight total and its largest count,
    both at least 1 in a context with symbols.
    """
    contexts = count.size
    kind = np.zeros(contexts, np.int64)
    head = np.zeros((contexts, 5), np.int64)
    bits = np.zeros(contexts)
    table_start = np.zeros(contexts + 1, np.int64)
    tables = np.zeros(contexts * empirical_max_window, np.int64)
    window = np.zeros(empirical_max_window, np.int64)
    weights = np.zeros(empirical_max_window)
    powers = np.zeros(empirical_max_window)
    terms = np.zeros(empirical_max_window)
    used = 0
    for k in range(contexts):
        table_start[k] = used
        n = count[k]
        if n == 0:
            continue
        start = first[k]
        a, z = ordered[start], ordered[start + n - 1]
        if a == z:
            kind[k], head[k, 0], bits[k] = 1, a, 16.0
            continue
        c = ordered[start + n // 2]
        n0, dist = 0, 0
        for i in range(start, start + n):
            r = abs(ordered[i] - c)
            if r == 0:
                n0 += 1
            dist += r
        # The rate of every (theta, boost) on the infinite support, as entropy.py's grid: the first least.
        best, bu, bb = np.inf, 0, 0
        for u in range(log2_z.shape[0]):
            spread = float(dist) * log2_theta[u] if theta_positive[u] else -np.inf
            for b in range(log2_z.shape[1]):
                cost = float(n) * log2_z[u, b] - float(n0) * log2_boost[b] - spread
                if not np.isfinite(cost):
                    cost = np.inf
                if cost < best:
                    best, bu, bb = cost, u, b
        kind[k] = 2
        head[k, 0], head[k, 1], head[k, 2], head[k, 3], head[k, 4] = a, z, c, bu, bb
        best_bits = best + 64
        if z - a < empirical_max_window:
            size = z - a + 1
            counts = window[:size]
            counts[:] = 0
            most = 0
            for i in range(start, start + n):
                counts[ordered[i] - a] += 1
            for i in range(size):
                most = max(most, counts[i])
            # The geometric model's weights over the window (entropy.py's model_weights).
            reach = max(c - a, z - c)
            powers[0] = 1.0
            for d in range(1, reach + 1):
                powers[d] = powers[d - 1] * thetas[bu]
            w = weights[:size]
            for i in range(size):
                w[i] = max(np.floor(powers[abs(a + i - c)] * weight_scale), 1.0)
            w[c - a] = max(np.floor(w[c - a] * float(boosts[bb]) / 8.0), 1.0)
            best_bits = _cross_entropy_bits(counts, w, terms) + 64
            # An explicit table of the counts scaled to empirical_scale (every symbol seen at least 1).
            table_bytes = 0
            for i in range(size):
                e = max(counts[i] * empirical_scale // most, 1) if counts[i] > 0 else 0
                tables[used + i] = e
                w[i] = float(e)
                table_bytes += 1 if e < 128 else (2 if e < 256 else 3)
            emp_bits = _cross_entropy_bits(counts, w, terms) + (8.0 * float(table_bytes) + 32)
            if emp_bits < best_bits:
                kind[k], best_bits = 3, emp_bits
                used += size
        bits[k] = best_bits
    table_start[contexts] = used
    return kind, head, bits, table_start, tables
