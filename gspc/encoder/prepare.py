"""The encoder's stages before its policy: cameras, attribute coding, the side-information views and their
candidates. gspc/pipeline.py runs them in order; tools/make_restorer_data.py runs the same ones, so the
restorer trains on what the encoder sends.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from gspc.cameras import Camera
from gspc.codec import residuals
from gspc.codec.attributes import EncodedAttributes, encode_attributes, search_lambda
from gspc.codec.params import CodecParams
from gspc.codec.precision import Significance
from gspc.encoder.removal import RemovalChoice, RemovalParams, choose_removal
from gspc.encoder.side import SideCandidate, side_candidate
from gspc.encoder.significance import encoder_significance
from gspc.encoder.tuning import TuningParams
from gspc.limits import default_refine_iterations
from gspc.options import EncodeOptions
from gspc.presets import quality_preset, refine_iterations_for
from gspc.progress import Progress
from gspc.scene import GaussianScene
from gspc.views import limit_size, sample_views, synthesize_views
from gspc.visibility import visible_mask


def encoder_cameras(scene: GaussianScene, cameras: list[Camera] | None, opts: EncodeOptions) -> list[Camera]:
    """The cameras given (or ``opts.synth_views`` synthesised around the scene), at most ``opts.max_side``."""
    cams = cameras if cameras is not None else synthesize_views(scene, opts.synth_views)
    return limit_size(cams, opts.max_side)


def codec_params(opts: EncodeOptions) -> CodecParams:
    """The preset's attribute parameters with the options' overrides."""
    params = quality_preset(opts.quality).attributes
    if opts.lam is not None:
        params = replace(params, lam=opts.lam)
    if opts.keep_invisible:
        params = replace(params, keep_invisible=True)
    if not opts.precision:
        params = replace(params, precision=None)
    return params


def removal_params(opts: EncodeOptions) -> RemovalParams | None:
    """The preset's search of removal and position grid (gspc/encoder/removal.py), or None where the options
    turn it off."""
    if not opts.removal_search:
        return None
    return RemovalParams(position_offsets=quality_preset(opts.quality).position_offsets)


def tuning_params(opts: EncodeOptions) -> TuningParams | None:
    """The tuning of the coded values the options ask for (gspc/encoder/tuning.py; None: none)."""
    iterations = quality_preset(opts.quality).tune_iterations
    if opts.tune_iterations is not None:
        iterations = opts.tune_iterations
    return TuningParams(iterations=iterations) if iterations > 0 else None


@dataclass
class CodedAttributes:
    encoded: EncodedAttributes  # chunks, meta and G~ as the decoder decodes it
    params: CodecParams
    visible: np.ndarray  # per input Gaussian: seen by some camera
    significance: Significance | None = None  # what each Gaussian does to the views, where measured
    removal: RemovalChoice | None = None  # how the removal was chosen (None: the parameters' own)


def code_attributes(
    scene: GaussianScene,
    cameras: list[Camera],
    params: CodecParams,
    target_size: int | None = None,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    progress: Progress | None = None,
    removal: RemovalParams | None = None,
    deadline: float | None = None,
) -> CodedAttributes:
    """Prune what no camera sees and code the rest (at ``target_size`` bytes when given), on the CPU: the
    visibility mask decides what is coded, so it is numpy like the codec. Where the parameters spend
    precision per Gaussian, its significance is measured first (gspc/encoder/significance.py), and with
    ``removal`` views between the encoder's cameras choose how much to remove in the bytes that coding takes
    (gspc/encoder/removal.py)."""
    visible = visible_mask(
        scene.means.detach().cpu().numpy(), scene.log_scales.detach().cpu().numpy(), cameras
    )
    sig = None
    on_cpu = scene.to("cpu")
    if params.precision is not None:
        sig = encoder_significance(on_cpu, cameras, background, progress)
    if target_size is not None:
        enc = search_lambda(scene, target_size, params, visible=visible, significance=sig)
    else:
        enc = encode_attributes(scene, params, visible=visible, significance=sig)
    choice = None
    if removal is not None and sig is not None:
        choice = choose_removal(
            on_cpu, enc, params, visible, sig, cameras, background, removal, deadline, progress
        )
        enc, params = choice.encoded, choice.params
    return CodedAttributes(enc, params, visible, sig, choice)


@dataclass(frozen=True)
class Iterations:
    check: int  # the encoder's check runs this many (0: no check)
    refine: int  # the decoder's default, written to the header


def iteration_counts(opts: EncodeOptions, num_gaussians: int, work_bound: int | None = None) -> Iterations:
    """The check's and the decoder's refinement lengths: an explicit ``--check-iterations``, else the preset's
    scaled down for large scenes (gspc/presets.py, REFINE_WORK); both within the default a file of
    ``num_gaussians`` coded Gaussians may name and within ``work_bound``, the iterations its bytes pay for
    (gspc/limits.py, gspc/reconstruct.py work_bound), so the check runs what a decode will run."""
    preset = refine_iterations_for(quality_preset(opts.quality).refine_iterations, num_gaussians)
    check = preset if opts.check_iterations is None else opts.check_iterations
    check = default_refine_iterations(check, num_gaussians)
    if work_bound is not None:
        preset, check = min(preset, work_bound), min(check, work_bound)
    return Iterations(check, check or preset)  # unchecked files name the preset's


def sample_side_views(cameras: list[Camera], opts: EncodeOptions) -> tuple[list[int], list[Camera]]:
    """(indices, cameras) of the views that carry side information. The cameras are round-tripped through
    their stored form, so the encoder renders exactly the cameras the decoder reads."""
    views = sample_views(cameras, opts.views_fraction) if opts.side_info else []
    return views, [Camera.from_dict(cameras[i].to_dict()) for i in views]


def side_candidates(
    opts: EncodeOptions, view_cams: list[Camera], res: list[np.ndarray], check_iterations: int
) -> list[SideCandidate]:
    """The preset's resolution, and half of it as a cheaper candidate for the check to weigh."""
    q = quality_preset(opts.quality)
    distance = opts.residual_distance if opts.residual_distance is not None else q.residual_distance
    codec = opts.residual_codec or q.residual_codec
    plan = residuals.plan_residual_rates(res, distance)
    scales = [opts.residual_scale or q.residual_scale]
    if not opts.residual_scale and check_iterations > 0:
        scales.append(2 * q.residual_scale)
    return [side_candidate(view_cams, res, plan, codec, sc) for sc in scales]
