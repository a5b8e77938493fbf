"""How much the encoder removes, and how finely it places positions: the preset's removal and position
grid, or a stronger removal or a coarser or finer grid where views near the encoder's cameras show that the
same bytes code them better with it.

Removal (gspc/encoder/precision_plan.py, ``prune``) drops Gaussians painting under ``prune x lambda`` of the
median Gaussian's blending weight. What that threshold is worth differs by scene: trained captures hold many
Gaussians that barely paint, scenes their authors already pruned (the SOG statues) lose by any more
(bench/precision.md, "Removal chosen per scene"). So the encoder measures, as its check weighs side
information against the same bytes on attributes: for each stronger removal in turn it searches the lambda
that codes the scene in at most the preset's bytes, renders that coding at views halfway between some of its
cameras and their nearest others, and keeps the one closest to the original's renders there, where it beats
the best so far by a margin (every step is tried: a weaker one can lose where a stronger one gains). The
comparison is at equal bytes, so the file keeps the preset's rate and only its quality moves; not along a
slope read off nearby codings (the statues' curves bend either way, and such a slope chose a removal well
under a statue's curve), nor at the cameras themselves (removal takes what they show least, so they flatter
it) (bench/precision.md, "Removal chosen per scene").

Then, with the removal kept, the position grid a bit coarser or finer per axis (``position_offsets``, the
preset's: gspc/presets.py), in the same bytes and scored the same way: at the low preset's rate the trained
captures code the same bytes closer a bit coarser (their Gaussians are large against its voxels), at the high
preset's the statues a bit finer; the others keep the rate's grid (bench/precision.md, "Position precision
chosen per scene"). A preset that removes nothing (the high one) searches only the grid.

Last, where the scene has view-dependent colour, the SH rules (which bands each Gaussian keeps, the dead
zone, the faint Gaussians that carry none: gspc/encoder/params.py SHRules) against ones that drop less
(``sh_options``), in the same bytes, scored the same way: what those rules drop is worth more on some scenes
than on others (bench/precision.md, "SH choices checked per scene").

Only an encoder choice: the file holds what was kept, its classes and its grid, as always.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.encoder.coding import EncodedAttributes, SharedGrid
from gspc.encoder.occlusion import Occlusion
from gspc.encoder.params import CodecParams, SHRules
from gspc.encoder.precision_plan import Significance
from gspc.encoder.rate import search_lambda
from gspc.encoder.significance import evenly_spaced_indices
from gspc.errors import ValueRangeError
from gspc.metrics import mse
from gspc.progress import Progress
from gspc.reconstruct import render_images
from gspc.scene import GaussianScene
from gspc.views import between_views


@dataclass(frozen=True)
class RemovalParams:
    """The search's knobs (bench/precision.md, "Removal chosen per scene")."""

    # Multipliers of the preset's ``prune`` tried in order while each beats the best so far.
    steps: tuple[float, ...] = (2.0, 4.0, 8.0)
    # A stronger removal's floor may pass the median's weight up to this many times (the preset's stops at
    # it, gspc/encoder/precision_plan.py): measured here, not assumed.
    cap: float = 4.0
    # Each stronger removal's lambda search: within this fraction under the preset's bytes, in at most
    # this many codings (a miss over the bytes is not taken).
    rel_tol: float = 0.02
    max_codings: int = 6
    first_lambda_ratio: float = 0.85  # where the first step's search starts, times the preset's lambda
    # How many encoder cameras it scores halfway from, fewer past ``work`` Gaussian-views (never fewer than
    # min_views).
    views: int = 16
    min_views: int = 4
    work: int = 16 * 250_000
    # A stronger removal is taken only this far closer (dB), so that a tie does not move the file.
    min_gain_db: float = 0.1
    # Then these offsets of the position grid's bits per axis (CodecParams.position_offset), in order while
    # each gains as a removal step must; each search starts at first_lambda_ratio of the kept lambda (its
    # inverse for a finer grid). The preset names them (gspc/presets.py, gspc/encoder/prepare.py
    # removal_params); none by default.
    position_offsets: tuple[float, ...] = ()
    # Then, in a scene with view-dependent colour, these SH rules in place of the parameters' own, in order,
    # each kept where it gains as a removal step must: the SH choices drop information whose worth differs by
    # scene as the removal's does (bench/precision.md, "SH choices checked per scene"). None by default.
    sh_options: tuple[SHRules, ...] = ()


@dataclass(frozen=True)
class Trial:
    prune: float
    lam: float
    bytes: int
    psnr: float  # mean over the scoring views, dB against the original's renders
    position_offset: float = 0.0
    sh: SHRules | None = None  # the SH rules tried; None: the parameters' own

    def label(self, base: Trial) -> str:
        if self.sh is not None:
            return self.sh.words()
        if self.position_offset:
            return f"positions {self.position_offset:+g} bit"
        return f"x{self.prune / base.prune:g}"


@dataclass(frozen=True)
class RemovalChoice:
    """The coding kept, its parameters, and what was measured (``base`` None: no search ran)."""

    encoded: EncodedAttributes
    params: CodecParams
    base: Trial | None = None
    trials: tuple[Trial, ...] = ()
    views: int = 0
    seconds: float = 0.0
    min_gain_db: float = 0.0  # a trial had to gain this much to be kept

    @property
    def kept(self) -> Trial:
        """The trial whose coding was kept (``base``: the preset's)."""
        lam, offset = self.encoded.lam, self.params.position_offset
        prune = self.params.precision.prune if self.params.precision is not None else 0.0

        def made(t: Trial) -> bool:
            sh_ok = t.sh is None or t.sh == self.params.sh_rules
            return (t.lam, t.prune, t.position_offset) == (lam, prune, offset) and sh_ok

        match = [t for t in self.trials if made(t)]
        return match[-1] if match else self.base

    def chosen(self) -> str:
        """The removal and grid kept, in words."""
        t, b = self.kept, self.base
        if b is None or t is b:
            return "the preset's removal and grid"
        parts = [f"x{t.prune / b.prune:g} the preset's removal"] if t.prune != b.prune else []
        if t.position_offset:
            parts.append(f"positions {t.position_offset:+g} bit")
        if t.sh is not None:
            parts.append(t.sh.words())
        return ", ".join(parts)

    def summary(self) -> str:
        """What was kept and why, in one line."""
        b = self.base
        if b is None:
            return "the preset's (no search)"

        def trial(t: Trial) -> str:
            return f"{t.label(b)} at lambda {t.lam:.3g} {t.psnr - b.psnr:+.2f} dB"

        t = self.kept
        verdict = (
            f"no trial gained {self.min_gain_db:g} dB over it"
            if t is b
            else f"{t.psnr - b.psnr:+.2f} dB over the preset's"
        )
        tried = ", ".join(trial(t) for t in self.trials) or "none tried"
        return (
            f"{self.chosen()}: {verdict} at {self.views} views between the encoder's cameras, each trial in "
            f"the preset's bytes ({tried}; {self.seconds:.1f} s)"
        )


def better(best: Trial, t: Trial, limit: int, min_gain_db: float) -> bool:
    """Whether ``t`` codes in at most ``limit`` bytes at least ``min_gain_db`` closer than ``best``."""
    return t.bytes <= limit and t.psnr >= best.psnr + min_gain_db


def scoring_views(
    cameras: Sequence[Camera], num_gaussians: int, rp: RemovalParams, occlusion: Occlusion | None = None
) -> list[Camera]:
    """Where the search renders: halfway from ``rp.views`` evenly spaced encoder cameras (fewer past
    ``rp.work``) to their nearest others (a tile's: of the scene's cameras, where ``occlusion`` knows what
    the other tiles hide). Not the cameras themselves: removal takes what they show least, so they flatter
    it (bench/precision.md, "Removal chosen per scene")."""
    count = max(rp.min_views, min(rp.views, rp.work // max(1, num_gaussians)))
    picked = evenly_spaced_indices(len(cameras), count)
    if occlusion is not None:
        return occlusion.scoring_views(cameras, picked)
    return between_views(cameras, picked)


def choose_removal(
    scene: GaussianScene,
    first: EncodedAttributes,
    params: CodecParams,
    visible: np.ndarray | None,
    significance: Significance,
    cameras: Sequence[Camera],
    background: Sequence[float],
    rp: RemovalParams = RemovalParams(),
    deadline: float | None = None,
    progress: Progress | None = None,
    grid: SharedGrid | None = None,
    occlusion: Occlusion | None = None,
) -> RemovalChoice:
    """The removal for ``scene`` (``first``: its coding with ``params``): the preset's, or the best of
    ``rp.steps``, each tried in ``first``'s bytes and kept where it beats the best so far (none where the
    parameters remove nothing); then the position grid, the rate's or moved by ``rp.position_offsets``
    while each gains (module docstring). No search without classes or with nothing to try, and none starts
    past ``deadline``."""
    precision = params.precision
    steps = rp.steps if precision is not None and precision.prune > 0 else ()
    sh_options = rp.sh_options if scene.sh_degree > 0 else ()
    if (
        precision is None
        or not (steps or rp.position_offsets or sh_options)
        or (deadline is not None and time.perf_counter() >= deadline)
    ):
        return RemovalChoice(first, params)
    t0 = time.perf_counter()
    views = scoring_views(cameras, scene.num_gaussians, rp, occlusion)
    score = scorer(scene, views, background, occlusion)
    stages = len(steps) + len(rp.position_offsets) + len(sh_options)
    _tick(progress, 0, stages)
    base = Trial(precision.prune, first.lam, first.num_bytes, score(first))
    best, kept = base, (first, params)
    trials: list[Trial] = []

    def attempt(p: CodecParams, offset: float = 0.0, sh: SHRules | None = None) -> bool:
        """Code ``p`` in ``first``'s bytes and keep it where it beats the best; whether it did."""
        nonlocal best, kept
        try:
            enc = search_lambda(
                scene,
                first.num_bytes,
                p,
                visible=visible,
                rel_tol=rp.rel_tol,
                max_iter=rp.max_codings,
                significance=significance,
                deadline=deadline,
                grid=grid,
            )
        except ValueRangeError:  # nothing codes these rules in the bytes: a rate too fine for the scene
            _tick(progress, len(trials) + 1, stages)
            return False
        trials.append(Trial(p.precision.prune, enc.lam, enc.num_bytes, score(enc), offset, sh))
        _tick(progress, len(trials), stages)
        if not better(best, trials[-1], first.num_bytes, rp.min_gain_db):
            return False
        best, kept = trials[-1], (enc, p.with_lambda(enc.lam))
        return True

    guess = first.lam * rp.first_lambda_ratio
    for step in steps:
        if deadline is not None and time.perf_counter() >= deadline:
            break
        stronger = replace(precision, prune=precision.prune * step, prune_cap=rp.cap)
        # A step that does not gain goes on to the next all the same: on the district's tiles x8 gained dB
        # where x2 lost (bench/tiles.md, "What other tiles hide"). One whose search missed the bytes ends it.
        if not attempt(replace(params, lam=guess, precision=stronger)) and trials[-1].bytes > first.num_bytes:
            break
        # Each step's lambda falls by about the same ratio (bench/precision.md, "Removal chosen per scene").
        guess = trials[-1].lam * trials[-1].lam / (trials[-2].lam if len(trials) > 1 else first.lam)
    for offset in rp.position_offsets:
        if deadline is not None and time.perf_counter() >= deadline:
            break
        p = kept[1]
        # Coarser positions free bytes for the rest (a lower lambda), finer ones take them (a higher one).
        ratio = rp.first_lambda_ratio if offset < 0 else 1.0 / rp.first_lambda_ratio
        if not attempt(replace(p, lam=p.lam * ratio, position_offset=offset), offset):
            break
    for rules in sh_options:
        if deadline is not None and time.perf_counter() >= deadline:
            break
        p = kept[1]
        # Keeping more of the view-dependent colour takes bytes from the rest: a higher lambda.
        attempt(replace(p, lam=p.lam / rp.first_lambda_ratio).with_sh_rules(rules), p.position_offset, rules)
    if len(trials) < stages:  # ended early: the stage is done all the same
        _tick(progress, stages, stages)
    seconds = time.perf_counter() - t0
    return RemovalChoice(kept[0], kept[1], base, tuple(trials), len(views), seconds, rp.min_gain_db)


def scorer(
    scene: GaussianScene,
    views: list[Camera],
    background: Sequence[float],
    occlusion: Occlusion | None = None,
) -> Callable[[EncodedAttributes], float]:
    """Mean PSNR over ``views`` of a coding's renders against the original's, unquantised: at the statues'
    quality the error is under one 8-bit level, which 8-bit renders would round away. A tile's
    ``occlusion``: only the pixels where some of it is in front of the other tiles count (over the whole
    image still, so the scale is a scene's)."""
    refs = render_images(scene, views, background)
    masks = occlusion.masks(scene, views) if occlusion is not None else [None] * len(views)

    def score(enc: EncodedAttributes) -> float:
        coded = render_images(enc.decoded, views, background)
        errors = torch.stack(
            [mse(a, b) if m is None else mse(a * m, b * m) for a, b, m in zip(coded, refs, masks)]
        ).clamp_min(1e-12)
        return float((-10.0 * torch.log10(errors)).mean())

    return score


def _tick(progress: Progress | None, done: int, total: int) -> None:
    if progress:
        progress("removal", done, total)
