"""The encoder's stages before its policy: cameras, attribute coding, the side-information views and their
candidates. gspc/pipeline.py runs them in order; tools/make_restorer_data.py runs the same ones, so the
restorer trains on what the encoder sends.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from gspc.cameras import Camera
from gspc.codec import residuals
from gspc.encoder.coding import EncodedAttributes, SharedGrid, encode_attributes
from gspc.encoder.fidelity import FidelityParams
from gspc.encoder.occlusion import Occlusion
from gspc.encoder.params import CodecParams
from gspc.encoder.precision_plan import Significance
from gspc.encoder.rate import search_lambda
from gspc.encoder.removal import RemovalChoice, RemovalParams, choose_removal
from gspc.encoder.side import SideCandidate, side_candidate
from gspc.encoder.significance import encoder_significance
from gspc.encoder.tuning import TuningParams
from gspc.limits import default_refine_iterations
from gspc.options import EncodeOptions
from gspc.presets import PRESET_TOLERANCE_DB, quality_preset, refine_iterations_for
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


def fidelity_params(opts: EncodeOptions) -> FidelityParams | None:
    """The fidelity the attributes are coded to: ``--target-psnr``'s, or the preset's within its size where
    neither ``--lambda`` nor ``--target-size`` names the rate (None: coded at the rate)."""
    if opts.target_psnr is not None:
        return FidelityParams(opts.target_psnr)
    preset = quality_preset(opts.quality)
    if preset.target_db is None or opts.lam is not None or opts.target_size is not None:
        return None
    return FidelityParams(
        preset.target_db, PRESET_TOLERANCE_DB, max_bytes_per_gaussian=preset.max_bytes_per_gaussian
    )


def removal_params(opts: EncodeOptions) -> RemovalParams | None:
    """The preset's search of removal and position grid (gspc/encoder/removal.py), or None where the options
    turn it off."""
    if not opts.removal_search:
        return None
    preset = quality_preset(opts.quality)
    return RemovalParams(position_offsets=preset.position_offsets, sh_options=preset.sh_options)


def tuning_params(opts: EncodeOptions) -> TuningParams | None:
    """The tuning of the coded values the options ask for (gspc/encoder/tuning.py; None: none)."""
    iterations = quality_preset(opts.quality).tune_iterations
    if opts.tune_iterations is not None:
        iterations = opts.tune_iterations
    return TuningParams(iterations=iterations) if iterations > 0 else None


@dataclass(frozen=True)
class Measure:
    """What the encoder measured of each input Gaussian at its cameras: the coding's choices follow it."""

    visible: np.ndarray  # seen by some camera
    significance: Significance | None  # what it does to the views, where the parameters spend precision
    occlusion: Occlusion | None = None  # a tile's: what the other tiles hide (measured and scored without)


@dataclass
class CodedAttributes:
    encoded: EncodedAttributes  # chunks, meta and G~ as the decoder decodes it
    params: CodecParams
    visible: np.ndarray  # per input Gaussian: seen by some camera
    significance: Significance | None = None  # what each Gaussian does to the views, where measured
    removal: RemovalChoice | None = None  # how the removal was chosen (None: the parameters' own)
    grid: SharedGrid | None = None  # a tile's: the scene's grid, which every coding of it keeps


def measure_scene(
    scene: GaussianScene,
    cameras: list[Camera],
    params: CodecParams,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    progress: Progress | None = None,
    occlusion: Occlusion | None = None,
) -> Measure:
    """Which Gaussians some camera sees and, where the parameters spend precision per Gaussian, what each
    does to the views (gspc/encoder/significance.py; a tile's of what the other tiles leave in view,
    ``occlusion``); on the CPU, where the codec runs."""
    visible = visible_mask(
        scene.means.detach().cpu().numpy(), scene.log_scales.detach().cpu().numpy(), cameras
    )
    sig = None
    if params.precision is not None:
        sig = encoder_significance(scene.to("cpu"), cameras, background, progress, occlusion)
    return Measure(visible, sig, occlusion)


def code_attributes(
    scene: GaussianScene,
    cameras: list[Camera],
    params: CodecParams,
    target_size: int | None = None,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    progress: Progress | None = None,
    removal: RemovalParams | None = None,
    deadline: float | None = None,
    measure: Measure | None = None,
    grid: SharedGrid | None = None,
) -> CodedAttributes:
    """Prune what no camera sees and code the rest (at most ``target_size`` bytes when given), on the CPU:
    the visibility mask decides what is coded, so it is numpy like the codec. ``measure``: the scene's, where
    already taken (:func:`measure_scene` otherwise). With ``removal``, views between the encoder's cameras
    choose how much to remove in the bytes that coding takes (gspc/encoder/removal.py). ``grid``: the
    scene's whose tile this is (gspc/encoder/tiles.py)."""
    m = measure if measure is not None else measure_scene(scene, cameras, params, background, progress)
    visible, sig = m.visible, m.significance
    if target_size is not None:
        enc = search_lambda(scene, target_size, params, visible=visible, significance=sig, grid=grid)
    else:
        enc = encode_attributes(scene, params, visible=visible, significance=sig, grid=grid)
    choice = None
    if removal is not None and sig is not None:
        choice = choose_removal(
            scene.to("cpu"),
            enc,
            params,
            visible,
            sig,
            cameras,
            background,
            removal,
            deadline,
            progress,
            grid,
            m.occlusion,
        )
        enc, params = choice.encoded, choice.params
    return CodedAttributes(enc, params, visible, sig, choice, grid)


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
    wanted = opts.side_info and quality_preset(opts.quality).side_info
    views = sample_views(cameras, opts.views_fraction) if wanted else []
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
