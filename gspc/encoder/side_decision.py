"""The encoder's side-information step for one scene (or one tile, spec 10.15): the residuals of its sampled
views and the check that the decoder's refinement against them beats the same bytes spent on attributes
(side.py, policy.py); where none is sent, the attributes of a file the decoder does not refine.

gspc/encoder/decisions.py runs it for a whole scene, gspc/encoder/tiles.py for each tile, with the tile's
cameras and the scene's grid (``CodedAttributes.grid``).
"""

from __future__ import annotations

from dataclasses import dataclass

from gspc.cameras import Camera
from gspc.encoder.coding import EncodedAttributes
from gspc.encoder.policy import (
    CheckInputs,
    Outcome,
    SideInfoDecision,
    Tune,
    check_cameras,
    check_side_info,
)
from gspc.encoder.prepare import CodedAttributes, iteration_counts, sample_side_views, side_candidates
from gspc.encoder.rate import coded_with, search_lambda
from gspc.encoder.side import SideCandidate, view_residuals
from gspc.encoder.tuning import TuningReport
from gspc.options import EncodeOptions
from gspc.presets import quality_preset
from gspc.reconstruct import render_images, work_bound
from gspc.scene import GaussianScene, with_drawn
from gspc.stages import Stages

# A SIDE chunk's table entry and padding, about (spec section 5): what side information adds to a file
# beyond its payload, so that attributes and side information share a --target-size.
CHUNK_ENTRY_BYTES = 48


@dataclass
class SideChoice:
    """The side-information step's outcome: the attributes to send with it (or in its place)."""

    attributes: EncodedAttributes
    side: SideCandidate | None
    refine_iterations: int
    reason: str
    check: SideInfoDecision | None = None
    tuning: TuningReport | None = None  # where the check's tuned rival is the attributes: its tuning


def side_information(
    scene: GaussianScene,
    cams: list[Camera],
    coded: CodedAttributes,
    restorer,
    opts: EncodeOptions,
    device,
    stages: Stages,
    attribute_budget: int | None,
    at_fidelity: bool = False,
    tune: Tune | None = None,
    drawn: GaussianScene | None = None,
) -> SideChoice:
    """Render the sampled views, code their residuals and, where the check runs, keep the side information
    only if it pays for its bytes (gspc/encoder/policy.py). With a byte budget, the attributes are coded
    again in what the side information leaves (its residuals made again for that coding) first. Coded to a
    fidelity (``at_fidelity``), side information that does not pay costs no bytes at all. ``tune``: the
    encoder's tuning of a file without side information, which the check's rival gets too (None: untuned).
    ``drawn``: a tile's neighbours (their original Gaussians), shown with it in every view and score and
    never refined (spec 10.15)."""
    enc = coded.encoded
    runs = iteration_counts(opts, enc.decoded.num_gaussians)
    view_indices, view_cams = sample_side_views(cams, opts)
    if not view_indices:
        if not opts.side_info:
            reason = "none (--no-side-info)"
        elif not quality_preset(opts.quality).side_info:
            reason = f"none (the {opts.quality} preset: a file for viewers, which do not refine)"
        else:
            reason = "none (no view sampled)"
        return SideChoice(unrefined_coding(scene, coded, stages), None, runs.refine, reason)
    original, rendered, candidates = _candidates(
        scene, enc, view_cams, opts, runs.check, stages, device, drawn=drawn
    )
    whole = coded  # in the whole budget: what a file that sends none spends it on
    if attribute_budget is not None and candidates[0].payload is not None:
        room = attribute_budget - len(candidates[0].payload) - CHUNK_ENTRY_BYTES
        with stages.stage("attributes"):
            enc = search_lambda(
                scene,
                room,
                coded.params.with_lambda(enc.lam),
                visible=coded.visible,
                significance=coded.significance,
                first=enc,
                grid=coded.grid,
            )
        if enc.num_bytes > room:  # no room for both: the attributes alone
            return SideChoice(coded.encoded, None, runs.refine, "none (no room for it in the target)")
        coded = CodedAttributes(
            enc, coded.params.with_lambda(enc.lam), coded.visible, coded.significance, grid=coded.grid
        )
        original, rendered, candidates = _candidates(
            scene, enc, view_cams, opts, runs.check, stages, device, original, drawn
        )
    # No residual anywhere: no chunk at all (cameras alone would be dead weight).
    side = candidates[0] if candidates[0].payload is not None else None
    if side is None:
        reason = "none (no view's residual was worth sending)"
        return SideChoice(unrefined_coding(scene, whole, stages), None, runs.refine, reason)
    # No more iterations than a decode of a file of at least these payloads runs (spec 10.8).
    least = enc.num_bytes + min(len(c.payload) for c in candidates if c.payload is not None)
    bound = work_bound(with_drawn(enc.decoded, drawn), view_cams, side.images, least)
    runs = iteration_counts(opts, enc.decoded.num_gaussians, bound)
    if runs.check == 0:
        return SideChoice(enc, side, runs.refine, _sent(side, "unchecked, --check-iterations 0"))
    inputs = CheckInputs(
        scene=scene,
        attributes=enc,
        params=coded.params.unrefined(),
        visible=coded.visible,
        significance=coded.significance,
        view_cameras=view_cams,
        check_cameras=check_cameras(cams, view_indices, opts.check_views),
        original=original,
        coded=rendered,
        candidates=candidates,
        restorer=restorer,
        iterations=runs.refine,
        background=opts.background,
        margin_db=opts.check_margin_db,
        device=device,
        deadline=stages.deadline,
        grid=coded.grid,
        tune=tune,
        drawn=drawn,
    )
    with stages.stage("check"):
        result = check_side_info(inputs, stages.progress)
    d = result.decision
    if result.side is not None:
        # The decoder runs what the check ran (a time budget may cut it).
        return SideChoice(
            result.attributes, result.side, d.iterations, _sent(result.side, "the check found it pays"), d
        )
    attributes, tuning = result.attributes, result.tuning
    if d.outcome is Outcome.DROPPED or (at_fidelity and d.outcome is Outcome.SPENT_ON_ATTRIBUTES):
        # Coded to a fidelity, the attributes already reach it: side information that does not pay
        # leaves its bytes unspent rather than on attributes past the target.
        attributes, tuning = unrefined_coding(scene, coded if at_fidelity else whole, stages), None
    return SideChoice(attributes, None, runs.refine, _not_sent(d, at_fidelity), d, tuning)


def _candidates(
    scene: GaussianScene,
    enc: EncodedAttributes,
    view_cams: list[Camera],
    opts: EncodeOptions,
    check_iterations: int,
    stages: Stages,
    device,
    original: list | None = None,
    drawn: GaussianScene | None = None,
) -> tuple[list, list, list[SideCandidate]]:
    """Renders of G (``original``, where already made) and G~ at the side-information views, each with
    ``drawn`` beside it, and the residuals' candidate codings (gspc/encoder/prepare.py side_candidates)."""
    with stages.stage("render", announce=False):
        bg = opts.background
        # The residuals go into the file: rendered by the file's renderer rules (spec 10.12), which the
        # torch renderer follows on every device and gsplat 1.5 does not (gspc/render/gsplat_backend.py).
        if original is None:
            shown = with_drawn(scene, drawn).to(device)
            original = render_images(shown, view_cams, bg, stages.progress, "render original", "torch")
        coded = render_images(
            with_drawn(enc.decoded, drawn).to(device), view_cams, bg, stages.progress, "render coded", "torch"
        )
    with stages.stage("side info"):
        candidates = side_candidates(opts, view_cams, view_residuals(original, coded), check_iterations)
    return original, coded, candidates


def side_cameras(cams: list[Camera], opts: EncodeOptions) -> list[Camera]:
    """Every camera :func:`side_information` renders a scene at: its views and its check's (a tile's
    neighbours need be read only where these see them)."""
    view_indices, view_cams = sample_side_views(cams, opts)
    if not view_indices:
        return []
    return view_cams + check_cameras(cams, view_indices, opts.check_views)


def _sent(side: SideCandidate, why: str) -> str:
    return (
        f"sent ({why}): {side.views_with_residual} of {len(side.records)} views carry a residual, "
        f"{len(side.payload):,} B at 1/{side.scale} resolution"
    )


def _not_sent(d: SideInfoDecision, at_fidelity: bool = False) -> str:
    if d.outcome is Outcome.SPENT_ON_ATTRIBUTES:
        where = (
            "left unspent (the attributes reach the fidelity)"
            if at_fidelity
            else "spent on attributes instead"
        )
        rival = f"{d.rival_db:.2f}" if d.tuned_rival_db is None else f"{d.tuned_rival_db:.2f} (tuned)"
        return (
            f"none: it did not beat the same bytes on attributes by the check's margin, {rival} dB "
            f"at {d.check_views} views carrying none against {d.refined_db:.2f} dB refined with it; its "
            f"bytes {where}"
        )
    return (
        f"none: refinement did not improve the {d.check_views} views carrying none ({d.coded_db:.2f} dB "
        f"coded, {d.refined_db:.2f} dB refined)"
    )


def unrefined_coding(scene: GaussianScene, coded: CodedAttributes, stages: Stages) -> EncodedAttributes:
    """The attributes of a file without side information, which the decoder does not refine: coded with
    the parameters for that (CodecParams.unrefined) in the bytes the refined coding takes. Past the
    deadline no search starts, and one it cuts short keeps the refined coding unless it found better."""
    enc = coded.encoded
    params = coded.params.unrefined().with_lambda(enc.lam)
    if coded_with(enc, params) or stages.past_deadline():
        return enc  # the same steps (a fine rate, or the uniform codec), or no time left
    with stages.stage("attributes for no side information"):
        found = search_lambda(
            scene,
            enc.num_bytes,
            params,
            visible=coded.visible,
            significance=coded.significance,
            rel_tol=0.005,
            deadline=stages.deadline,
            grid=coded.grid,
        )
    return found if found.num_bytes <= enc.num_bytes else enc
