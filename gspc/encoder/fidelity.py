"""Coding to a fidelity (``--target-psnr``): the largest lambda, so the fewest bytes, whose coding renders at
least a target PSNR against the original's renders.

The measure is the one the encoder's removal search scores with (gspc/encoder/removal.py): views halfway
between some of its cameras and their nearest others, which its cameras do not hold and its choices are not
fitted to, in float (at high fidelity an 8-bit render rounds most of the error away). It is the fidelity of
the attributes as they decode; a file with side information decodes closer still after refinement.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from gspc.cameras import Camera
from gspc.encoder.coding import EncodedAttributes, SharedGrid, encode_attributes
from gspc.encoder.params import CodecParams
from gspc.encoder.precision_plan import Significance
from gspc.encoder.removal import RemovalParams, scorer, scoring_views
from gspc.errors import InputError, NothingCodedError, ValueRangeError
from gspc.limits import MAX_LAMBDA, MIN_LAMBDA
from gspc.progress import Progress
from gspc.scene import GaussianScene

# PSNR against log lambda is close to a line: the first guess's slope (dB per e-fold of lambda), before two
# codings measure it (bench/precision.md, "Coding to a fidelity").
DB_PER_LOG_LAMBDA = -4.0
# The search stops once the lambdas under and over the target are this close in log (1%).
STOP_LOG_WIDTH = 0.01


@dataclass(frozen=True)
class FidelityParams:
    target_db: float
    tolerance_db: float = 0.1  # a coding this far above the target ends the search
    max_codings: int = 10


@dataclass(frozen=True)
class Fidelity:
    """What a fidelity search reached: the coding, its PSNR at ``views`` views, the codings it took."""

    encoded: EncodedAttributes
    psnr_db: float
    target_db: float
    views: int
    codings: int
    seconds: float
    # The coding's PSNR at the same views: the encoder scores the file it writes with it (the coding for no
    # side information, the tuned values) and reports that.
    score: Callable[[EncodedAttributes], float] = field(repr=False, compare=False, default=None)

    def summary(self) -> str:
        return (
            f"{self.psnr_db:.2f} dB at {self.views} views between the encoder's cameras (target "
            f"{self.target_db:g} dB; lambda {self.encoded.lam:.3g}, {self.codings} codings, "
            f"{self.seconds:.1f} s)"
        )


def code_to_fidelity(
    scene: GaussianScene,
    params: CodecParams,
    visible: np.ndarray | None,
    significance: Significance | None,
    cameras: Sequence[Camera],
    background: Sequence[float],
    fp: FidelityParams,
    rp: RemovalParams = RemovalParams(),
    grid: SharedGrid | None = None,
    progress: Progress | None = None,
) -> Fidelity:
    """The coding of ``scene`` with ``params`` (at another lambda) of the fewest bytes whose PSNR at the
    scoring views is at least ``fp.target_db``: secant steps on log lambda inside a bracket that bisection
    narrows. InputError where even the finest lambda stays under the target."""
    t0 = time.perf_counter()
    views = scoring_views(cameras, scene.num_gaussians, rp)
    score = scorer(scene, views, background)
    lo, hi = math.log(MIN_LAMBDA), math.log(MAX_LAMBDA)  # finer (closer) at lo, coarser at hi
    best: tuple[EncodedAttributes, float] | None = None
    closest: tuple[EncodedAttributes, float] | None = None
    tried: list[tuple[float, float]] = []
    x = math.log(params.lam)
    for k in range(fp.max_codings):
        if progress:
            progress("fidelity", k, fp.max_codings)
        try:
            enc = encode_attributes(scene, params.with_lambda(math.exp(x)), visible, significance, grid=grid)
        except ValueRangeError:
            lo = max(lo, x)  # too fine for the scene's values: coarser
            x = 0.5 * (lo + hi)
            continue
        except NothingCodedError:
            hi = min(hi, x)  # so coarse that nothing is left: finer
            x = 0.5 * (lo + hi)
            continue
        p = score(enc)
        tried.append((x, p))
        if closest is None or p > closest[1]:
            closest = (enc, p)
        if p >= fp.target_db:
            if best is None or enc.lam > best[0].lam:
                best = (enc, p)
            if p <= fp.target_db + fp.tolerance_db:
                break
            lo = max(lo, x)
        else:
            hi = min(hi, x)
        if hi - lo < STOP_LOG_WIDTH:  # PSNR can jump with lambda (a removal or class threshold)
            break
        x = _next(lo, hi, tried, fp.target_db + 0.5 * fp.tolerance_db)
    if progress:
        progress("fidelity", fp.max_codings, fp.max_codings)
    if best is None:
        enc, p = closest if closest is not None else (None, float("nan"))
        raise InputError(
            f"--target-psnr {fp.target_db:g} dB cannot be reached: the closest coding tried renders "
            f"{p:.2f} dB" + (f" at lambda {enc.lam:.3g} ({enc.num_bytes:,} B)" if enc is not None else "")
        )
    seconds = time.perf_counter() - t0
    return Fidelity(best[0], best[1], fp.target_db, len(views), len(tried), seconds, score)


def _next(lo: float, hi: float, tried: list[tuple[float, float]], goal: float) -> float:
    """The next log lambda: a secant step towards ``goal`` dB through the last two codings (the assumed
    slope after one), inside the bracket; bisection where it would leave it."""
    x, y = tried[-1]
    slope = DB_PER_LOG_LAMBDA
    if len(tried) > 1 and tried[-2][0] != x:
        slope = min((y - tried[-2][1]) / (x - tried[-2][0]), -1e-3)
    guess = x + (goal - y) / slope
    bracketed = lo > math.log(MIN_LAMBDA) and hi < math.log(MAX_LAMBDA)
    margin = 0.1 * (hi - lo) if bracketed else 0.0
    return guess if lo + margin < guess < hi - margin else 0.5 * (lo + hi)
