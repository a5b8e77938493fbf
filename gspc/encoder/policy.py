"""The encoder's side-information check: send residuals only when the decoder's refinement, run here, beats
the same bytes spent on attributes at views that carry none.

Inputs and result are typed (:class:`CheckInputs`, :class:`SideInfoDecision`): the decision and every
measured PSNR are fields, which the pipeline reports and tests assert on.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.codec import residuals
from gspc.encoder.coding import EncodedAttributes, SharedGrid, encode_attributes
from gspc.encoder.params import CodecParams
from gspc.encoder.precision_plan import Significance
from gspc.encoder.rate import coded_with, search_lambda
from gspc.encoder.side import SideCandidate
from gspc.encoder.tuning import TuningReport
from gspc.metrics import mean_psnr
from gspc.progress import Progress
from gspc.reconstruct import decoder_refinement, render_images, restored_targets
from gspc.refine import Deadline
from gspc.scene import GaussianScene, with_drawn

# The encoder's tuning of a coding's values within a byte limit (gspc/encoder/tuning.py tune_coding, with the
# run's cameras and settings): what a file without side information gets before it is written.
Tune = Callable[[EncodedAttributes, int], tuple[EncodedAttributes, TuningReport | None]]


@dataclass(frozen=True)
class CheckPolicy:
    """The side-information check's rules, each with the measurement behind it."""

    # Held-out PSNR gain after refinement per dB that the residuals add to their own views' renders (I~ + R~
    # over I~): how the encoder predicts which resolution pays best (bench/pipeline.md).
    refine_transfer: float = 0.85
    # The rival may fall this far under the side information's bytes: a looser search would hand side
    # information a handicap on steep rate curves (bench/pipeline.md).
    rival_tolerance: float = 0.005
    # ... and by at most this share of the side information's own bytes, where those are a sliver of the
    # file (bench/scale_pipeline.md, "Equal bytes, within 0.15%").
    rival_share: float = 0.25
    # The rivals' PSNR is read off two codings, one under and one over every candidate's bytes, in log bytes
    # between them: the coding at the file's lambda and one search above the largest target, aiming this
    # share above it with a window as wide; it takes the same decisions in fewer codings than a search per
    # candidate (bench/speed.md, "The check's rivals read off two codings"). Only a rival the file then holds
    # (SPENT_ON_ATTRIBUTES) is searched to the tolerance.
    rival_bracket: float = 0.02
    chunk_entry_bytes: int = 48  # a chunk-table entry plus alignment padding, about (spec section 5)
    # The trial: a refinement of at least ``trial_from`` iterations is scored after its first
    # ``trial_fraction``; where the trial's gain over the coded scene, times ``gain_ratio``, already clears
    # the bar, the side information is sent without running on (the end of a cosine schedule only
    # polishes, bench/refine.md). A trial that does not clear it decides nothing: the run goes on and its
    # end decides.
    trial_from: int = 100
    trial_fraction: float = 0.25
    gain_ratio: float = 1.0

    def trial_length(self, iterations: int) -> int:
        """Where the check first scores a run of ``iterations``: all of a short one."""
        if iterations < self.trial_from:
            return iterations
        return max(1, math.ceil(iterations * self.trial_fraction))


class Outcome(str, Enum):
    """What the encoder did with the side information."""

    SENT = "sent"
    SPENT_ON_ATTRIBUTES = "spent on attributes"  # the same bytes on attributes measured better
    DROPPED = "dropped"  # refinement did not improve the views that carry none


@dataclass(frozen=True)
class CandidateScore:
    """One candidate resolution as the policy measured it."""

    scale: int  # residuals at 1/scale resolution
    payload_bytes: int
    render_gain_db: float | None  # I~ + R~ over I~ at its own views (measured only when choosing)
    rival_db: float  # PSNR at the check views of the same bytes spent on attributes


@dataclass(frozen=True)
class SideInfoDecision:
    """The check's outcome and what it measured (PSNR in dB at ``check_views`` views carrying none)."""

    outcome: Outcome
    scale: int  # the candidate refined (and sent, when outcome is SENT)
    check_views: int
    coded_db: float  # G~ as coded
    refined_db: float  # G~ after the decoder's refinement (after the trial, when the trial decided)
    rival_db: float  # the chosen candidate's rival: the same bytes on attributes
    trial_iterations: int  # where the run was first scored
    predicted: bool  # sent on the trial's score (refined_db is then the trial's), the run not continued
    iterations: int  # the refinement's length: the decoder's default (a time budget may cut it)
    candidates: tuple[CandidateScore, ...]
    # The rival as the encoder would write it, its values tuned, where the untuned rival lost (None: not
    # needed, or no tuning asked).
    tuned_rival_db: float | None = None

    @property
    def best_rival_db(self) -> float:
        """The rival side information had to beat: the tuned one where it was coded."""
        return self.rival_db if self.tuned_rival_db is None else max(self.rival_db, self.tuned_rival_db)

    def summary(self) -> dict[str, str]:
        """One line per fact, for the command line's summary."""
        out = {}
        if len(self.candidates) > 1:
            out["side info resolution"] = (
                "; ".join(
                    f"1/{c.scale}: {c.payload_bytes:,} B, renders +{c.render_gain_db:.2f} dB, same bytes on "
                    f"attributes {c.rival_db - self.coded_db:+.2f} dB"
                    for c in self.candidates
                )
                + f"; chose 1/{self.scale}"
            )
        refined = f"{self.refined_db:.2f} dB"
        if self.predicted:
            refined += f" after {self.trial_iterations} of {self.iterations} iterations (decided there)"
        rival = f"{self.rival_db:.2f} dB"
        if self.tuned_rival_db is not None:
            rival += f" ({self.tuned_rival_db:.2f} dB tuned)"
        out["check"] = (
            f"at {self.check_views} unsent views: coded {self.coded_db:.2f} dB, refined {refined}, "
            f"same bytes on attributes {rival}"
        )
        if self.outcome is Outcome.SPENT_ON_ATTRIBUTES:
            out["side info"] = "spent on attributes instead (measured better at equal bytes)"
        elif self.outcome is Outcome.DROPPED:
            out["side info"] = "dropped (refinement did not improve unsent views)"
        return out


@dataclass
class CheckInputs:
    """What the check needs: the scene and its coding, the side-information views and their renders, the
    candidates, and the decoder's configuration it predicts (restorer, iterations, background).

    Scenes are on the CPU, where the attribute codec runs; the check renders and refines them on ``device``,
    where the renders and the restorer already are."""

    scene: GaussianScene
    attributes: EncodedAttributes
    params: CodecParams  # the rival's: a file without side information (CodecParams.unrefined)
    visible: np.ndarray | None
    significance: Significance | None  # the rival codes per-Gaussian precision from it, as the file does
    view_cameras: list[Camera]  # the side-information views, in their stored form
    check_cameras: list[Camera]  # views carrying none, where the check scores
    original: list[torch.Tensor]  # renders of G at view_cameras
    coded: list[torch.Tensor]  # renders of G~ at view_cameras
    candidates: list[SideCandidate]  # the first is the preset's resolution
    restorer: object | None  # gspc.restore.restorer.Restorer, or None for I~ + R~
    iterations: int
    background: tuple[float, float, float]
    margin_db: float  # side information must win by this much
    policy: CheckPolicy = CheckPolicy()
    device: torch.device = torch.device("cpu")  # renders and refinement run here
    # time.perf_counter() by which the encode should end: refinement is shortened so that it and the final
    # scoring fit (None: the full ``iterations``).
    deadline: float | None = None
    grid: SharedGrid | None = None  # a tile's: the scene's grid, which the rivals keep (spec 10.14)
    # The encoder's tuning (None: the file is not tuned): a refinement that beats the untuned rival must
    # also beat the rival tuned, the file the encoder would write in its place.
    tune: Tune | None = None
    # A tile's neighbours, drawn with it at every view and never refined (spec 10.15; None: alone): the
    # original's, which the decoder's coded ones differ from only where they are coded.
    drawn: GaussianScene | None = None


@dataclass
class CheckResult:
    side: SideCandidate | None  # the side information to send, or None
    attributes: EncodedAttributes  # the attributes to send (a finer coding when the bytes went there)
    decision: SideInfoDecision
    tuning: TuningReport | None = None  # where ``attributes`` are the tuned rival: its tuning


def check_cameras(cameras: Sequence[Camera], views: Sequence[int], count: int) -> list[Camera]:
    """``count`` cameras spread over those that carry no side information (all of ``views`` if none do not),
    in their stored form."""
    sent = set(views)
    others = [c for i, c in enumerate(cameras) if i not in sent] or [cameras[i] for i in views]
    pick = np.linspace(0, len(others) - 1, min(count, len(others))).round().astype(int)
    return [Camera.from_dict(others[i].to_dict()) for i in pick]


def check_side_info(inp: CheckInputs, progress: Progress | None = None) -> CheckResult:
    """Keep the side information only if the decoder's refinement, run here, beats at the check views the
    coded scene and the same bytes spent on attributes by ``margin_db``."""
    enc = inp.attributes
    drawn = None if inp.drawn is None else inp.drawn.to(inp.device)
    scene = with_drawn(inp.scene.to(inp.device), drawn)
    reference = render_images(scene, inp.check_cameras, inp.background, progress, "check render original")
    del scene

    # Capped per view: a tile's check views may show none of its error (identical to 8 bits), and an
    # infinite score would make every refinement, gain or loss, look alike (spec 10.15's tiles).
    def score(s: GaussianScene) -> float:
        images = render_images(with_drawn(s.to(inp.device), drawn), inp.check_cameras, inp.background)
        return mean_psnr(images, reference, capped=True)

    t0 = time.perf_counter()
    before = score(enc.decoded)
    # A refinement must leave time for the scoring after it (one more like this one) and the writing.
    deadline = None if inp.deadline is None else Deadline(inp.deadline - 1.5 * (time.perf_counter() - t0))
    rivals = _rivals(inp, score, progress, before)
    best, gains = _choose_candidate(inp, rivals, before)
    side, alt_psnr = inp.candidates[best], rivals[best]
    bar = max(before, alt_psnr) + inp.margin_db
    targets = restored_targets(inp.coded, side.records, side.images, inp.restorer)
    run = decoder_refinement(
        enc.decoded.to(inp.device),
        enc.section,
        inp.view_cameras,
        targets,
        inp.iterations,
        inp.background,
        precision=enc.precision,
        drawn=drawn,
    )
    trial = inp.policy.trial_length(inp.iterations)
    run.run(trial, deadline, _stage_report(progress, "check refine (trial)", 0, trial))
    after = score(run.scene())
    predicted = run.done < run.total and trial_settles(after - before, bar - before, inp.policy.gain_ratio)
    if run.done < run.total and not predicted:
        run.run(None, deadline, _stage_report(progress, "check refine", run.done, run.total))
        after = score(run.scene())
    tuned, tuned_db = None, None
    if (predicted or after >= bar) and inp.tune is not None:
        # Beating the untuned rival is not enough: the file the encoder writes without side information
        # has its values tuned (bench/pipeline.md, "The check's rival tuned").
        tuned = _tuned_rival(inp, side, progress)
        tuned_db = score(tuned[0].decoded)
        bar = max(bar, tuned_db + inp.margin_db)
        if predicted and not trial_settles(after - before, bar - before, inp.policy.gain_ratio):
            predicted = False
            run.run(None, deadline, _stage_report(progress, "check refine", run.done, run.total))
            after = score(run.scene())
    if predicted or after >= bar:
        outcome = Outcome.SENT
    elif tuned is not None or alt_psnr > before:
        # Side information does not pay for its bytes: send none (the decoder will not refine), and spend
        # the bytes on attributes when that measured better.
        outcome = Outcome.SPENT_ON_ATTRIBUTES
    else:
        outcome = Outcome.DROPPED
    decision = SideInfoDecision(
        outcome=outcome,
        scale=side.scale,
        check_views=len(inp.check_cameras),
        coded_db=before,
        refined_db=after,
        rival_db=alt_psnr,
        trial_iterations=trial,
        predicted=predicted,
        iterations=run.total,
        candidates=tuple(
            CandidateScore(c.scale, len(c.payload), g, r) for c, g, r in zip(inp.candidates, gains, rivals)
        ),
        tuned_rival_db=tuned_db,
    )
    if outcome is Outcome.SENT:
        return CheckResult(side, enc, decision)
    if tuned is not None:  # the tuned rival won: it is the file
        return CheckResult(None, tuned[0], decision, tuned[1])
    if outcome is Outcome.SPENT_ON_ATTRIBUTES:  # searched after the refinement: within the time budget
        rival = _rival_coding(inp, _rival_target(inp, side), deadline=inp.deadline)
        return CheckResult(None, rival, decision)
    return CheckResult(None, enc, decision)


def trial_settles(trial_gain: float, needed: float, ratio: float) -> bool:
    """Whether a trial's gain over the coded scene settles the check for sending: the full run's gain,
    predicted at ``ratio`` times the trial's, reaches ``needed`` (and the trial gained at all)."""
    return trial_gain > 0 and ratio * trial_gain >= needed


def _stage_report(
    progress: Progress | None, stage: str, first: int, last: int
) -> Callable[[int, int, float], None] | None:
    """A refinement callback reporting iterations ``first``..``last`` of a run as ``stage`` (opened here;
    a deadline that shortens the run shortens the stage)."""
    if progress is None:
        return None
    progress(stage, 0, last - first)
    return lambda done, total, loss: progress(stage, done - first, min(last, total) - first)


def _tuned_rival(
    inp: CheckInputs, side: SideCandidate, progress: Progress | None
) -> tuple[EncodedAttributes, TuningReport | None]:
    """The same bytes as ``side`` and the file's attributes spent on attributes alone, searched to the
    policy's tolerance and tuned within them: what the encoder writes if the side information is not sent."""
    target = _rival_target(inp, side)
    if progress:
        progress("check tuned rival", 0, 1)
    out = inp.tune(_rival_coding(inp, target, deadline=inp.deadline), target)
    if progress:
        progress("check tuned rival", 1, 1)
    return out


def _rival_target(inp: CheckInputs, side: SideCandidate) -> int:
    """The bytes a rival spends on attributes: the file's attributes and the side information's chunk."""
    return inp.attributes.num_bytes + len(side.payload) + inp.policy.chunk_entry_bytes


def _rival_coding(
    inp: CheckInputs,
    target: int,
    rel_tol: float | None = None,
    first: EncodedAttributes | None = None,
    deadline: float | None = None,
) -> EncodedAttributes:
    """The attributes alone at ``target`` bytes (at most), to ``rel_tol`` under it (default: the policy's
    tolerance, and its share of the side information's bytes); the search starts from ``first`` (a coding
    with the rival's parameters), else from the file's coding where it has them, and starts no coding after
    ``deadline`` (search_lambda's)."""
    enc = inp.attributes
    params = inp.params.with_lambda(enc.lam)
    if rel_tol is None:
        extra = target - enc.num_bytes
        rel_tol = min(inp.policy.rival_tolerance, inp.policy.rival_share * extra / target)
    if first is None and coded_with(enc, params):
        first = enc
    return search_lambda(
        inp.scene,
        target,
        params,
        visible=inp.visible,
        significance=inp.significance,
        rel_tol=rel_tol,
        first=first,
        deadline=deadline,
        grid=inp.grid,
    )


def _rivals(
    inp: CheckInputs, score: Callable[[GaussianScene], float], progress: Progress | None, before: float
) -> list[float]:
    """Per candidate, the PSNR of its fair rival: the same total bytes spent on attributes alone, read off
    codings under and over its bytes (log-linear between them, CheckPolicy.rival_bracket). ``before``: the
    file's coding's PSNR (``score`` of it)."""
    enc, bracket = inp.attributes, inp.policy.rival_bracket
    targets = [_rival_target(inp, c) for c in inp.candidates]
    params = inp.params.with_lambda(enc.lam)
    steps = 2
    if progress:
        progress("check rivals", 0, steps)
    # The rival's parameters at the file's lambda: the file's own coding where they agree.
    if coded_with(enc, params):
        first = enc
    else:
        first = encode_attributes(inp.scene, params, inp.visible, inp.significance, grid=inp.grid)
    low = first if first.num_bytes <= min(targets) else _rival_coding(inp, min(targets), bracket, first)
    if progress:
        progress("check rivals", 1, steps)
    # Over every target: the search's window [1 - bracket, 1] x (1 + 2 bracket) x the largest lies above it.
    high = first
    if first.num_bytes < max(targets):
        high = _rival_coding(inp, math.ceil(max(targets) * (1 + 2 * bracket)), bracket, low)
    codings = [low] if high is low else [low, high]
    points = [(e.num_bytes, before if e is enc else score(e.decoded)) for e in codings]
    out = []
    for t in targets:
        under = [p for p in points if p[0] <= t]
        over = [p for p in points if p[0] >= t]
        if under and over:
            out.append(_log_linear(max(under), min(over), t))
        else:  # the searches missed it (sizes jump there): this target's own search, as close as the policy
            own = _rival_coding(inp, t, first=high)
            out.append(score(own.decoded))
            points.append((own.num_bytes, out[-1]))
    if progress:
        progress("check rivals", steps, steps)
    return out


def _log_linear(a: tuple[int, float], b: tuple[int, float], x: int) -> float:
    """The value at ``x`` on the line through the (log bytes, value) points ``a`` and ``b`` (a's value where
    they share their bytes)."""
    if a[0] == b[0]:
        return a[1]
    f = (math.log(x) - math.log(a[0])) / (math.log(b[0]) - math.log(a[0]))
    return a[1] + f * (b[1] - a[1])


def _choose_candidate(inp: CheckInputs, rivals: list[float], before: float) -> tuple[int, list[float | None]]:
    """The candidate to refine, and each one's render gain (None where there is one candidate): the one
    whose residuals, by how much they improve the renders they were sent for, promise the widest margin."""
    if len(inp.candidates) == 1:
        return 0, [None]
    gains = [_target_gain(inp.original, inp.coded, c) for c in inp.candidates]
    margins = [inp.policy.refine_transfer * g - max(0.0, r - before) for g, r in zip(gains, rivals)]
    return int(np.argmax(margins)), list(gains)


def _target_gain(original: list[torch.Tensor], coded: list[torch.Tensor], side: SideCandidate) -> float:
    """Mean PSNR gain of I~ + R~ over I~ against I at the side-information views (0 where none is sent)."""
    gains = []
    for k, (ref, img, v) in enumerate(zip(original, coded, side.records)):
        if k not in side.images:
            gains.append(0.0)
            continue
        r = torch.from_numpy(residuals.decode_residual(side.images[k], v.residual)).to(img)
        gains.append(mean_psnr([(img + r).clamp(0, 1)], [ref], True) - mean_psnr([img], [ref], True))
    return float(np.mean(gains))
