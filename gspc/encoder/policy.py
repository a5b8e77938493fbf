"""The encoder's side-information check: send residuals only when the decoder's refinement, run here, beats
the same bytes spent on attributes at views that carry none.

Inputs and result are typed (:class:`CheckInputs`, :class:`SideInfoDecision`): the decision and every
measured PSNR are fields, which the pipeline reports and tests assert on.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.codec import residuals
from gspc.codec.attributes import EncodedAttributes, search_lambda
from gspc.codec.params import CodecParams
from gspc.encoder.side import SideCandidate
from gspc.metrics import mean_psnr
from gspc.progress import Progress
from gspc.refine import Refined
from gspc.scene import GaussianScene
from gspc.stages import refine_in_cells, render_images, restored_targets

# Held-out PSNR gain after refinement per dB that the residuals add to their own views' renders (I~ + R~ over
# I~), measured with 1000 iterations inside the cells: lego fit lambda 8, 0.86 (residuals at 1/2 resolution)
# and 0.82 (1/4); donut lambda 64, 0.89 (1/4). The encoder predicts with it which resolution pays best.
REFINE_TRANSFER = 0.85
# The rival may fall this far under the side information's bytes: search_lambda's default 3% is worth 1.5 dB
# on a curve as steep as the donut's (5 dB per 10% of bytes), a handicap that would favour side information.
RIVAL_TOLERANCE = 0.005
CHUNK_ENTRY_BYTES = 48  # a chunk-table entry plus alignment padding, about (spec section 5)
# A refinement this long or longer is first tried for a tenth of its iterations (see _short_length).
SHORT_RUN_FROM = 500


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
    refined_db: float  # G~ after the decoder's refinement (the short run's, when that failed)
    rival_db: float  # the chosen candidate's rival: the same bytes on attributes
    short_iterations: int  # the trial run's length
    short_check_failed: bool  # the trial run made the coded scene worse: the long run was skipped
    iterations: int  # the refinement run that decided: the decoder's default (a time budget may cut it)
    candidates: tuple[CandidateScore, ...]

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
        if self.short_check_failed:
            out["short check"] = f"{self.short_iterations} iterations: {refined}, worse than coded"
        out["check"] = (
            f"at {self.check_views} unsent views: coded {self.coded_db:.2f} dB, refined {refined}, "
            f"same bytes on attributes {self.rival_db:.2f} dB"
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
    params: CodecParams
    visible: np.ndarray | None
    view_cameras: list[Camera]  # the side-information views, in their stored form
    check_cameras: list[Camera]  # views carrying none, where the check scores
    original: list[torch.Tensor]  # renders of G at view_cameras
    coded: list[torch.Tensor]  # renders of G~ at view_cameras
    candidates: list[SideCandidate]  # the first is the preset's resolution
    restorer: object | None  # gspc.restore.restorer.Restorer, or None for I~ + R~
    iterations: int
    background: tuple[float, float, float]
    margin_db: float  # side information must win by this much
    device: torch.device = torch.device("cpu")  # renders and refinement run here
    # time.perf_counter() by which the encode should end: refinement is shortened so that it and the final
    # scoring fit (None: the full ``iterations``).
    deadline: float | None = None


@dataclass
class CheckResult:
    side: SideCandidate | None  # the side information to send, or None
    attributes: EncodedAttributes  # the attributes to send (a finer coding when the bytes went there)
    decision: SideInfoDecision


def check_cameras(cameras: Sequence[Camera], views: Sequence[int], count: int) -> list[Camera]:
    """``count`` cameras spread over those that carry no side information (all of ``views`` if none do not),
    in their stored form."""
    sent = set(views)
    others = [c for i, c in enumerate(cameras) if i not in sent] or [cameras[i] for i in views]
    pick = np.linspace(0, len(others) - 1, min(count, len(others))).round().astype(int)
    return [Camera.from_dict(others[i].to_dict()) for i in pick]


def check_side_info(inp: CheckInputs, progress: Progress | None = None) -> CheckResult:
    """Run the decoder's refinement and keep the side information only if it beats, at the check views, the
    coded scene and the same bytes spent on attributes, by ``margin_db``."""
    enc = inp.attributes
    scene = inp.scene.to(inp.device)
    reference = render_images(scene, inp.check_cameras, inp.background, progress, "check render original")

    def score(s: GaussianScene) -> float:
        return mean_psnr(render_images(s.to(inp.device), inp.check_cameras, inp.background), reference)

    t0 = time.perf_counter()
    before = score(enc.decoded)
    # A refinement must leave time for the scoring after it (one more like this one) and the writing.
    deadline = None if inp.deadline is None else inp.deadline - 1.5 * (time.perf_counter() - t0)

    def rival(candidate: SideCandidate) -> tuple[EncodedAttributes, float]:
        """The fair rival: the same total bytes spent on attributes alone, and its PSNR."""
        extra = len(candidate.payload) + CHUNK_ENTRY_BYTES
        alt = search_lambda(
            inp.scene,
            enc.num_bytes + extra,
            inp.params,
            visible=inp.visible,
            rel_tol=RIVAL_TOLERANCE,
            first=enc,
        )
        return alt, score(alt.decoded)

    rivals = []
    for k, c in enumerate(inp.candidates):
        if progress:
            progress("check rivals", k, len(inp.candidates))
        rivals.append(rival(c))
    if progress:
        progress("check rivals", len(inp.candidates), len(inp.candidates))
    best = 0
    gains: list[float | None] = [None] * len(inp.candidates)
    if len(inp.candidates) > 1:
        # Predict each candidate's refined PSNR from how much its residuals improve the renders they were
        # sent for, and refine only the most promising one.
        gains = [_target_gain(inp.original, inp.coded, c) for c in inp.candidates]
        margins = [REFINE_TRANSFER * g - max(0.0, r[1] - before) for g, r in zip(gains, rivals)]
        best = int(np.argmax(margins))
    side, (alt, alt_psnr) = inp.candidates[best], rivals[best]
    targets = restored_targets(inp.coded, side.records, side.images, inp.restorer)
    # A run a tenth as long first: where refinement makes the coded scene worse, the long run is not worth
    # its minutes.
    short = _short_length(inp.iterations)
    run = _refined(inp, targets, short, progress, "check refine (short)", deadline)
    after, ran = score(run.scene), run.iterations
    failed = after < before
    if not failed and short < inp.iterations and (deadline is None or time.perf_counter() < deadline):
        run = _refined(inp, targets, inp.iterations, progress, "check refine", deadline)
        after, ran = score(run.scene), run.iterations
    if after >= max(before, alt_psnr) + inp.margin_db:
        outcome = Outcome.SENT
    elif alt_psnr > before:
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
        short_iterations=short,
        short_check_failed=failed,
        iterations=ran,
        candidates=tuple(
            CandidateScore(c.scale, len(c.payload), g, r[1]) for c, g, r in zip(inp.candidates, gains, rivals)
        ),
    )
    if outcome is Outcome.SENT:
        return CheckResult(side, enc, decision)
    return CheckResult(None, alt if outcome is Outcome.SPENT_ON_ATTRIBUTES else enc, decision)


def _target_gain(original: list[torch.Tensor], coded: list[torch.Tensor], side: SideCandidate) -> float:
    """Mean PSNR gain of I~ + R~ over I~ against I at the side-information views (0 where none is sent)."""
    gains = []
    for k, (ref, img, v) in enumerate(zip(original, coded, side.records)):
        if k not in side.images:
            gains.append(0.0)
            continue
        r = torch.from_numpy(residuals.decode_residual(side.images[k], v.residual)).to(img)
        gains.append(mean_psnr([(img + r).clamp(0, 1)], [ref]) - mean_psnr([img], [ref]))
    return float(np.mean(gains))


def _refined(
    inp: CheckInputs,
    targets: list[torch.Tensor],
    iterations: int,
    progress: Progress | None,
    stage: str,
    deadline: float | None,
) -> Refined:
    """The decoder's refinement as the encoder predicts it (same targets, iterations and cells)."""
    enc = inp.attributes
    return refine_in_cells(
        enc.decoded.to(inp.device),
        enc.section,
        inp.view_cameras,
        targets,
        iterations,
        inp.background,
        progress,
        stage,
        deadline=deadline,
    )


def _short_length(iterations: int) -> int:
    """The check's trial runs: a tenth of a long refinement, the whole of a short one."""
    return iterations // 10 if iterations >= SHORT_RUN_FROM else iterations
