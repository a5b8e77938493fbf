"""Coding to a fidelity (``--target-psnr``): the largest lambda, so the fewest bytes, whose coding renders at
least a target PSNR against the original's renders.

The measure is the one the encoder's removal search scores with (gspc/encoder/removal.py): views halfway
between some of its cameras and their nearest others, which its cameras do not hold and its choices are not
fitted to, in float (at high fidelity an 8-bit render rounds most of the error away). It is the fidelity of
the attributes as they decode; a file with side information decodes closer still after refinement.

A file without side information has its coded values tuned after the search (gspc/encoder/tuning.py), which
lifts the same bytes past the target: :func:`tuned_to_fidelity` then searches once more, for the target less
what the tuning added, so the tuned file lands near its target in fewer bytes.

The quality presets aim at a fidelity too (gspc/presets.py), within a size they state in bytes per Gaussian
given: a coding over it counts as too fine, and where no coding within it reaches the target the search ends
at the closest one within it, which :attr:`Fidelity.reached` says.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypeVar

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

T = TypeVar("T")

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
    # The most bytes a coding may take per Gaussian given (None: any): a preset's stated size. With it, a
    # target the search cannot reach ends at the closest coding within it instead of an error.
    max_bytes_per_gaussian: float | None = None


@dataclass(frozen=True)
class Fidelity:
    """What a fidelity search reached: the coding, its PSNR at ``views`` views, the codings it took."""

    encoded: EncodedAttributes
    psnr_db: float
    target_db: float
    views: int
    codings: int
    seconds: float
    max_bytes: int | None = None  # the size the search stayed within (None: any)
    # The coding's PSNR at the same views: the encoder scores the file it writes with it (the coding for no
    # side information, the tuned values) and reports that.
    score: Callable[[EncodedAttributes], float] = field(repr=False, compare=False, default=None)

    @property
    def reached(self) -> bool:
        return self.psnr_db >= self.target_db - 0.005  # what the summary shows as the target

    def summary(self) -> str:
        target = f"target {self.target_db:g} dB"
        if not self.reached and self.max_bytes is not None:
            target += f", not reached within the preset's size, {self.max_bytes:,} B"
        return (
            f"{self.psnr_db:.2f} dB at {self.views} views between the encoder's cameras ({target}; lambda "
            f"{self.encoded.lam:.3g}, {self.codings} codings, {self.seconds:.1f} s)"
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
    scoring views is at least ``fp.target_db`` (and whose bytes are within ``fp.max_bytes_per_gaussian``):
    secant steps on log lambda inside a bracket that bisection narrows. Where no coding reaches the target:
    the closest within that size, or InputError without one."""
    t0 = time.perf_counter()
    max_bytes = None
    if fp.max_bytes_per_gaussian is not None:
        max_bytes = int(fp.max_bytes_per_gaussian * scene.num_gaussians)
    views = scoring_views(cameras, scene.num_gaussians, rp)
    score = scorer(scene, views, background)
    lo, hi = math.log(MIN_LAMBDA), math.log(MAX_LAMBDA)  # finer (closer) at lo, coarser at hi
    best: tuple[EncodedAttributes, float] | None = None
    closest: tuple[EncodedAttributes, float] | None = None
    tried: list[tuple[float, float]] = []
    codings = 0
    smallest: EncodedAttributes | None = None  # the fewest bytes of the codings over the size
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
        if max_bytes is not None and enc.num_bytes > max_bytes:
            lo = max(lo, x)  # over the size: coarser, whatever it renders
            codings += 1
            if smallest is None or enc.num_bytes < smallest.num_bytes:
                smallest = enc
            if hi - lo < STOP_LOG_WIDTH:
                break
            x = _towards_size(lo, hi, x, enc.num_bytes / max_bytes)
            continue
        p = score(enc)
        codings += 1
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
    if best is None and max_bytes is not None:  # the preset's size reached first
        best = closest  # the closest coding within it
        if best is None and smallest is not None:  # none fits it: the smallest tried
            best = (smallest, score(smallest))
    if best is None:
        enc, p = closest if closest is not None else (None, float("nan"))
        raise InputError(
            f"--target-psnr {fp.target_db:g} dB cannot be reached: the closest coding tried renders "
            f"{p:.2f} dB" + (f" at lambda {enc.lam:.3g} ({enc.num_bytes:,} B)" if enc is not None else "")
        )
    seconds = time.perf_counter() - t0
    return Fidelity(best[0], best[1], fp.target_db, len(views), codings, seconds, max_bytes, score)


def tuned_to_fidelity(
    first: EncodedAttributes,
    fidelity: Fidelity,
    tolerance_db: float,
    tune: Callable[[EncodedAttributes], tuple[EncodedAttributes, T]],
    search: Callable[[float, float], EncodedAttributes],
) -> tuple[EncodedAttributes, T, float]:
    """(coding, its tuning's report, PSNR) of ``first`` (the search's coding, or one for no side
    information in its bytes) tuned by ``tune``; where the tuned
    coding renders more than ``tolerance_db`` past the target, ``search(target_db, lam)`` codes for the
    target less the tuning's gain (from lambda ``lam``) and that is tuned too, kept if it still reaches the
    target in fewer bytes (module docstring). Where tuning takes a coding that reached the target under it,
    the untuned coding is kept (no report: the tuning's values are not in the file)."""
    tuned, report = tune(first)
    untuned = fidelity.psnr_db if first is fidelity.encoded else fidelity.score(first)
    got = fidelity.score(tuned)
    if got < fidelity.target_db <= untuned:  # tuned at the cameras, it fell short between them
        return first, None, untuned
    gain = got - untuned
    if not fidelity.reached or got <= fidelity.target_db + tolerance_db or gain <= 0:
        return tuned, report, got
    again, report2 = tune(search(fidelity.target_db - gain, first.lam))
    got2 = fidelity.score(again)
    if got2 >= fidelity.target_db and again.num_bytes < tuned.num_bytes:
        return again, report2, got2
    return tuned, report, got


def _towards_size(lo: float, hi: float, x: float, excess: float) -> float:
    """The next log lambda after a coding ``excess`` times over the size: bytes fall about as a power of
    lambda near -1/2 on the benches' scenes (bench/precision.md, "Presets that aim at a fidelity"), so
    twice the log excess and a margin on, inside the bracket."""
    guess = x + 2.0 * math.log(excess) + 0.05
    return guess if guess < hi else 0.5 * (lo + hi)


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
