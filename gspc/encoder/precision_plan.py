"""The encoder's plan of per-Gaussian precision (attribute codec version 4, spec 10.13): which quantiser class
and SH degree each Gaussian gets, and which Gaussians are worth their bytes at all.

The file holds the plan's outcome (gspc/codec/precision.py, PrecisionMap); the decoder never recomputes it.
The encoder plans one (:func:`plan_precision`) from a :class:`Significance`, what
gspc/encoder/significance.py measured of each Gaussian over the encoder's views, and the rate's
:class:`PrecisionParams`:

- **classes**: a Gaussian's expected contribution to the views' squared error from quantisation is about
  ``sum_g (sensitivity_g x step_g)^2`` over its attribute groups, and each halving of its steps costs about
  one bit per coded component. Bit allocation under a rate constraint gives each Gaussian a step multiplier
  proportional to ``1 / sqrt`` of that error per component: so classes are powers of two of the rate's
  steps, the exponent following half the log2 of the Gaussian's sensitivity per coded component relative to
  the scene's median, within the params' range. The SH rest's gradient sums over its coefficients (up to 45)
  and counts per coefficient: squared as a whole, it would count a Gaussian's view-dependent colour up to 45
  times over, and the Gaussians with SH bands would take the finest classes for bytes that buy nothing. The
  other groups' few components (1 to 4) count as one: counted per component as well, the statues cost more
  bytes (bench/precision.md, "Sensitivity per coded component"). Scenes of SH degree 0, and
  ``PrecisionParams.per_component`` off (the high preset, whose rates the bird codes in fewer bytes that
  way), weigh every group as a whole. Beyond a finest class (``PrecisionParams.tail``) the exponent follows
  the sensitivity at half the pace: the measure over-predicts the extreme ones, and a hard floor there left a
  sky of large Gaussians coarse (bench/precision.md, "The shells' loss taken apart").
- **SH degree**: a band is kept where dropping it would change the views (its first-order change of the
  renders, ``sh_band_change``) by more than its coded step does;
- **removal**: a Gaussian that paints a small fraction of what the median Gaussian paints over the views
  (its blending weight) is dropped: its bytes buy less than theirs. The fraction grows with lambda, the
  price of a byte in error: a fixed one capped the quality the finer rates reach (bench/precision.md). It
  never passes the median's own weight: half the Gaussians stay at any lambda.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gspc.errors import CodecError

# The attribute groups whose steps the classes scale, with the Significance gradient each is weighed by.
CLASSED_GROUPS = ("opacities", "log_scales", "quats", "sh_dc", "sh_rest")
# Components each group codes per Gaussian (rotations: the smallest three); the SH rest's follow its degree.
GROUP_COMPONENTS = {"opacities": 1, "log_scales": 3, "quats": 3, "sh_dc": 3}


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
    class 0); a Gaussian's ``e`` is ``round(bias - log2(sensitivity / median) / 2)``, and beyond ``tail``
    (None: no tail) it follows at half the pace (:func:`class_exponents`). ``sh_keep``: a band is
    kept where its change of the views is at least this many of its coded steps (0 keeps every band).
    ``prune``: a Gaussian whose blending weight over the views is below ``min(prune x lambda, prune_cap)``
    times the median Gaussian's is removed (0: never). ``min_class``: the fewest Gaussians a class other
    than 0 may hold; ``per_component``: how the class rule counts components (below).
    """

    exponents: tuple[int, int] = (-1, 2)  # (finest, coarsest)
    bias: float = 0.0
    # The measure over-predicts the most sensitive Gaussians' error: the coding of a sky of large Gaussians
    # costs the views far less squared error than its gradients predict, against the object inside it
    # (bench/precision.md, "The shells' loss taken apart"). Finer than ``tail`` the exponent takes one step
    # per two of the rule's.
    tail: int | None = None
    sh_keep: float = 0.0
    prune: float = 0.0
    # 1: at least half the measured Gaussians stay (below); the encoder's removal search measures more
    # (gspc/encoder/removal.py).
    prune_cap: float = 1.0
    groups: tuple[str, ...] = field(default=CLASSED_GROUPS)
    # A class of fewer Gaussians joins its neighbour towards the rate's own steps: each class codes its own
    # matrices, whose models cost bytes whatever their rows (bench/precision.md, "Sensitivity per coded
    # component").
    min_class: int = 0
    # The SH rest counted per coefficient and each Gaussian per coded component (the module's docstring);
    # off, every group counts as a whole, which the bird capture prefers at the high preset's rates and lego
    # does not (bench/precision.md, "Sensitivity per coded component").
    per_component: bool = True


@dataclass(frozen=True)
class Plan:
    """Per input Gaussian: worth coding at this rate (``keep``), its class's step exponent and SH degree."""

    keep: np.ndarray  # (N,) bool
    exponent: np.ndarray  # (N,) int64
    degree: np.ndarray  # (N,) int64


@dataclass(frozen=True)
class RateSteps:
    """The rate's own steps (class 0) of the groups the plan weighs, in the domain of the gradients."""

    opacity_levels: int
    scale_step: float
    rotation_step: float  # of a smallest-three component
    dc_step: float
    sh_band_steps: tuple[float, ...]  # band 1 .. D


def plan_precision(
    sig: Significance,
    alpha: np.ndarray,
    steps: RateSteps,
    params: PrecisionParams,
    candidates: np.ndarray,
    faint_alpha: float,
    lam: float,
) -> Plan:
    """The encoder's choice for every input Gaussian (``alpha`` its activated opacity; ``candidates``: those
    the codec would code at all). See the module's docstring; ``faint_alpha``: below it, no SH rest."""
    n = len(alpha)
    if len(sig.weight) != n:
        raise CodecError(f"significance of {len(sig.weight)} Gaussians for {n} Gaussians")
    # An opacity level is a step of alpha, so of the logit (the gradient's variable) 1 / (L alpha (1 -
    # alpha)).
    group_steps = {
        "opacities": 1.0 / (steps.opacity_levels * np.maximum(alpha * (1 - alpha), 1e-3)),
        "log_scales": steps.scale_step,
        "quats": steps.rotation_step,
        "sh_dc": steps.dc_step,
        "sh_rest": steps.sh_band_steps[0] if steps.sh_band_steps else 0.0,
    }
    d = len(steps.sh_band_steps)
    bands = np.asarray(steps.sh_band_steps)
    per_component = params.per_component and d > 0 and "sh_rest" in params.groups
    sens = np.zeros(n)
    for g in params.groups:
        whole = (sig.gradient[g] * group_steps[g]) ** 2
        # The SH rest's gradient sums over its coefficients: counted per coefficient.
        sens += whole / (3 * ((d + 1) ** 2 - 1)) if per_component and g == "sh_rest" else whole
    if per_component:
        sens /= _coded_components(sig, bands, params, alpha < faint_alpha)
    # The measure renders a sample of the encoder's views: a Gaussian none of them shows may still show in
    # the others, and a shell of sky-sized Gaussians went to removal and the coarsest class that way
    # (bench/precision.md, "Moved from code comments"). Unmeasured, it keeps the rate's own steps and every SH
    # band.
    measured = sig.weight > 0
    keep = candidates.copy()
    if params.prune > 0 and (keep & measured).any():
        # Blending weight, not a first-order change of the views: removing one of several Gaussians that
        # paint the same surface changes little, removing all of them removes the surface (bench/precision.md,
        # "Choosing the presets' parameters"); a weight is what a Gaussian paints, however redundant.
        # Capped, by default at the median's own weight, so at least half the measured Gaussians stay at any
        # lambda: uncapped, a coarse lambda removes every Gaussian of a small scene.
        floor = min(params.prune * lam, params.prune_cap) * float(np.median(sig.weight[keep & measured]))
        keep &= (sig.weight >= floor) | ~measured
    exponent = merge_small_classes(class_exponents(sens, params, keep & measured), keep & measured, params)
    exponent[~measured] = 0
    degree = np.full(n, d, np.int64)
    if d > 0:
        multipliers = 2.0 ** exponent.astype(np.float64) if "sh_rest" in params.groups else np.ones(n)
        degree = sh_degrees(sig.sh_band_change[:, :d], bands, multipliers, params.sh_keep)
        degree[~measured] = d
        degree[alpha < faint_alpha] = 0
    return Plan(keep, exponent, degree)


def _coded_components(
    sig: Significance, bands: np.ndarray, params: PrecisionParams, faint: np.ndarray
) -> np.ndarray:
    """Per Gaussian, the components a halving of its steps costs bits for: its classed groups', the SH rest's
    at the degree the rate's own steps keep (see the module's docstring)."""
    degree = sh_degrees(sig.sh_band_change[:, : len(bands)], bands, np.ones(len(faint)), params.sh_keep)
    degree[faint] = 0
    components = 3.0 * ((degree + 1) ** 2 - 1)
    for g in params.groups:
        components += GROUP_COMPONENTS.get(g, 0)
    return components


def class_exponents(sens: np.ndarray, params: PrecisionParams, among: np.ndarray | None = None) -> np.ndarray:
    """Each Gaussian's step exponent ``e`` (multiplier 2^e) from its sensitivity (see PrecisionParams),
    relative to the median of those ``among`` (all by default). Beyond ``params.tail`` the rule's ``t - k``
    becomes ``t - floor(k / 2)``: -5 -> -4, -6 and -7 -> -5, -8 and -9 -> -6 for a tail at -4."""
    lo, hi = params.exponents
    ref = sens if among is None else sens[among]
    positive = ref[ref > 0]
    if positive.size == 0:
        return np.full(len(sens), hi, np.int64)
    median = float(np.median(positive))
    rel = np.log2(np.maximum(sens, median * 2.0**-60) / median)
    e = np.rint(params.bias - rel / 2)
    if params.tail is not None:
        t = params.tail
        e = np.where(e < t, np.ceil(t + (e - t) / 2), e)
    return np.clip(e, lo, hi).astype(np.int64)


def merge_small_classes(exponent: np.ndarray, among: np.ndarray, params: PrecisionParams) -> np.ndarray:
    """``exponent`` with each class of fewer than ``params.min_class`` Gaussians ``among`` those coded moved
    to its neighbour towards exponent 0, from the extremes in (a class that grows past the floor stays)."""
    out = exponent.copy()
    lo, hi = params.exponents
    for outer, step in ((range(lo, 0), 1), (range(hi, 0, -1), -1)):
        for e in outer:
            count = int((out[among] == e).sum())
            if 0 < count < params.min_class:
                out[out == e] = e + step
    return out


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
