"""Rate control: the lambda that codes a scene in a number of bytes (``--target-size``, the removal search's
equal-bytes trials, the side-information check's rivals). An encoder choice: the file holds the steps it
reached, never the search.
"""

from __future__ import annotations

import math
import time

import numpy as np

from gspc.encoder.coding import EncodedAttributes, SharedGrid, class_steps, encode_attributes
from gspc.encoder.params import CodecParams
from gspc.encoder.precision_plan import Significance
from gspc.errors import NothingCodedError, ValueRangeError
from gspc.scene import GaussianScene

# Attribute bytes against lambda in log-log, the search's first guess before two sizes give a measured slope
# (the bird fit's curve, bench/precision.md).
LOG_BYTES_PER_LOG_LAMBDA = -0.4


def coded_with(enc: EncodedAttributes, params: CodecParams) -> bool:
    """Whether ``enc`` has the steps ``params`` give at its lambda (a search may start from it)."""
    return class_steps(params.with_lambda(enc.lam), enc.section.sh_degree) == enc.section.base_class()


def search_lambda(
    scene: GaussianScene,
    target_bytes: int,
    params: CodecParams,
    visible: np.ndarray | None = None,
    rel_tol: float = 0.03,
    max_iter: int = 12,
    first: EncodedAttributes | None = None,
    significance: Significance | None = None,
    deadline: float | None = None,
    grid: SharedGrid | None = None,
) -> EncodedAttributes:
    """The encoding with the smallest lambda whose size is at most ``target_bytes``.

    Searches log lambda by secant steps on log size within a bracket that bisection narrows when a step
    would not (each try is a whole encode: a million Gaussians take half a minute, so steps are few).
    Stops when a fit lands within ``rel_tol`` under the target, or when the lambdas under and over it are
    too close to part the window (the sizes jump over it there); if even the coarsest lambda tried is too
    big, returns that one (the caller reports the miss). ``first``: an encoding the caller already has, made
    with ``params`` and ``visible`` at any lambda (the search starts from its lambda). ``deadline``: a
    ``time.perf_counter()`` after which no further encode starts (the best so far is returned).
    """
    lo, hi = math.log(1e-3), math.log(1e3)  # log lambda: sizes above the target at lo, below at hi
    best: EncodedAttributes | None = None
    fallback: EncodedAttributes | None = None
    tried: list[tuple[float, float]] = []  # (log lambda, log size)
    # Aim at the middle of the accepted window [1 - rel_tol, 1] x target.
    x = math.log(first.lam if first is not None else params.lam)
    goal = math.log(target_bytes * (1.0 - 0.5 * rel_tol))
    for k in range(max_iter):
        if k > 0 and deadline is not None and time.perf_counter() >= deadline:
            break
        if k == 0 and first is not None:
            enc = first
        else:
            try:
                enc = encode_attributes(
                    scene, params.with_lambda(math.exp(x)), visible, significance, grid=grid
                )
            except ValueRangeError:
                # Too fine for the scene's largest values: a larger lambda, as if the size were too big.
                if x >= hi or (k == max_iter - 1 and best is None and fallback is None):
                    raise
                lo = max(lo, x)
                x = 0.5 * (lo + hi)
                continue
            except NothingCodedError:
                # So coarse that removal takes every Gaussian: a smaller lambda, as if too small.
                if x <= lo or (k == max_iter - 1 and best is None and fallback is None):
                    raise
                hi = min(hi, x)
                x = 0.5 * (lo + hi)
                continue
        size = enc.num_bytes
        tried.append((x, math.log(size)))
        if size <= target_bytes:
            if best is None or size > best.num_bytes:
                best = enc
            if size >= (1.0 - rel_tol) * target_bytes:
                break
            hi = min(hi, x)
        else:
            if fallback is None or size < fallback.num_bytes:
                fallback = enc
            lo = max(lo, x)
        if best is not None and (hi - lo) * -LOG_BYTES_PER_LOG_LAMBDA < 0.5 * rel_tol:
            # Lambdas this close code sizes half the window apart, unless the sizes jump (a threshold of
            # the precision plan crossed by many Gaussians at once): a window inside the jump has no lambda.
            break
        x = _next_log_lambda(lo, hi, tried, goal)
    return best if best is not None else fallback


def _next_log_lambda(lo: float, hi: float, tried: list[tuple[float, float]], goal: float) -> float:
    """The next log lambda: a secant step towards log size ``goal`` through the last two tries (the assumed
    slope after one), kept inside the bracket (lo, hi); bisection where it would leave it, or, once sizes
    on both sides of the target are known, hug one end (so a curved stretch cannot stall the search)."""
    x, y = tried[-1]
    slope = LOG_BYTES_PER_LOG_LAMBDA
    if len(tried) > 1 and tried[-2][0] != x:
        slope = min((y - tried[-2][1]) / (x - tried[-2][0]), -1e-3)
    guess = x + (goal - y) / slope
    bracketed = lo > math.log(1e-3) and hi < math.log(1e3)
    margin = 0.1 * (hi - lo) if bracketed else 0.0
    if not lo + margin < guess < hi - margin:
        return 0.5 * (lo + hi)
    return guess
