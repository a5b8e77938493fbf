"""Everything the encoder decides about one scene, in one call, as one typed record.

:func:`decide` walks the encoder's steps in order, each in its own module:

1. cameras (given, or synthesised around the scene) and what each Gaussian does to them (prepare.py,
   significance.py);
2. the attributes at the rate or in ``--target-size`` bytes, with the removal and position grid chosen per
   scene (prepare.py, rate.py, removal.py);
3. the side information: residuals of sampled views, and the check that the decoder's refinement against
   them beats the same bytes spent on attributes (side_decision.py, side.py, policy.py);
4. a file without side information, which the decoder takes as it is: its attributes coded for that, then
   its coded values tuned (tuning.py);
5. with ``--target-size``, the whole file within it: side information counts inside the target.

:class:`EncoderDecisions` holds what was chosen and why; its :meth:`~EncoderDecisions.summary` is what a
user reads, and :func:`file_bytes` packs the file it describes.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from gspc import __version__
from gspc.cameras import Camera
from gspc.codec.tiles import decode_tile, file_tile_jobs
from gspc.encoder.coding import EncodedAttributes, prune_mask
from gspc.encoder.fidelity import Fidelity, FidelityParams, code_to_fidelity, tuned_to_fidelity
from gspc.encoder.params import CodecParams
from gspc.encoder.policy import Outcome, SideInfoDecision
from gspc.encoder.prepare import (
    CodedAttributes,
    Measure,
    code_attributes,
    codec_params,
    encoder_cameras,
    fidelity_params,
    measure_scene,
    removal_params,
    tuning_params,
)
from gspc.encoder.rate import coded_with
from gspc.encoder.removal import RemovalChoice, RemovalParams
from gspc.encoder.side import SideCandidate
from gspc.encoder.side_decision import CHUNK_ENTRY_BYTES, SideChoice, side_information
from gspc.encoder.spans import code_spans, spans_line
from gspc.encoder.tiles import SceneRows, TileCoding, TileSettings, code_tiles
from gspc.encoder.tuning import TuningReport, tune_coding
from gspc.errors import CodecError, InputError
from gspc.format.file import pack_file, pack_tiled_file, read_file
from gspc.format.header import FileHeader, SceneSummary, SideInfoHeader
from gspc.format.view_records import check_view_pixels
from gspc.limits import encode_worker_bytes
from gspc.options import EncodeOptions
from gspc.presets import quality_preset
from gspc.reconstruct import check_decode_work, decode_work, refine_iterations
from gspc.restore.restorer import load_restorer
from gspc.scene import GaussianScene
from gspc.stages import Stages
from gspc.tile_reconstruct import tile_views_work
from gspc.workers import Executor, executor_for

# The file's bytes around the attributes' own (preamble, the header beyond the attribute section, the
# chunk table, padding and trailer: spec sections 2 and 5), about: a --target-size's first share for them.
FRAMING_BYTES = 448
# Gaussians a tiled scene's synthesised cameras are placed around (evenly spaced rows of the scene).
CAMERA_SAMPLE = 1 << 20
# A --target-size fit that lands over the target is tried again this many times with the attributes'
# share cut by the excess (the container's framing is only known once the file is packed).
TARGET_RETRIES = 2


@dataclass(frozen=True)
class GaussianCounts:
    """How many Gaussians the encoder was given, and where those it did not code went."""

    given: int
    not_coded: int  # no camera sees them, or they are under 1/255 opaque
    removed: int  # they paint too little of the views for their bytes (the precision plan's removal)
    coded: int

    def summary(self) -> str:
        if self.coded == self.given:
            return f"{self.given:,} given, all coded"
        parts = []
        if self.not_coded:
            parts.append(f"{self.not_coded:,} not coded (no camera sees them, or under 1/255 opaque)")
        if self.removed:
            parts.append(f"{self.removed:,} removed (they paint too little of the views for their bytes)")
        return f"{self.given:,} given, {self.coded:,} coded: " + ", ".join(parts)


@dataclass(frozen=True)
class EncoderDecisions:
    """What the encoder sends and why: the .gspc file's parts and every choice that shaped them."""

    attributes: EncodedAttributes | None  # None where the scene is coded as tiles
    side: SideCandidate | None  # the side information sent (None: none)
    refine_iterations: int  # the decoder's default refinement, written to the header
    counts: GaussianCounts
    lam_asked: float  # the rate knob of the preset or --lambda: it sets the bytes
    # Why the attributes are coded at another lambda in those bytes (empty: at the one asked).
    lambda_reasons: tuple[str, ...]
    side_info: str  # one line: what happened to the side information, and why
    removal: RemovalChoice | None = None  # the removal and grid search, where it ran
    check: SideInfoDecision | None = None  # the side-information check, where it ran
    tuning: TuningReport | None = None  # the tuning of the coded values, where it ran
    target_size: int | None = None
    fidelity: Fidelity | None = None  # the fidelity search, where --target-psnr or the preset asked for one
    target_psnr: float | None = None  # a tiled scene's: each tile's target
    tiles: tuple[TileCoding, ...] = ()  # a scene coded as spatial tiles (gspc/encoder/tiles.py), in order
    ran_on: str = "1 worker"  # where the tiles were coded (gspc/workers.py Executor.describe)
    coordinates: str | None = None  # the axes the input stated (spec 10.8)

    def summary(self) -> dict[str, str]:
        """One line per decision, in the order they were taken, for the command line's summary."""
        if self.tiles:
            return self._tiled_summary()
        out = {"Gaussians": self.counts.summary(), "lambda": self._lambda_line()}
        if self.fidelity is not None:
            out["fidelity"] = self.fidelity.summary()
        if self.removal is not None:
            out["removal"] = self.removal.summary()
        out["side info"] = self.side_info
        if self.check is not None:
            out.update(self.check.summary())
            out["side info"] = self.side_info  # the decisions' line: what happened to its bytes too
        if self.tuning is not None:
            out["tuning"] = self.tuning.summary()
        out["decoder refines"] = (
            f"{self.refine_iterations} iterations by default"
            if self.side is not None
            else "nothing (no side information)"
        )
        return out

    @property
    def tile_sides(self) -> list[bytes | None]:
        """Each tile's own side information as it goes into the file (spec 10.15; None: none)."""
        return [t.side.payload if _sends(t) else None for t in self.tiles]

    def _tiled_summary(self) -> dict[str, str]:
        """A tiled scene's decisions: each tile took its own, as a scene of its own would."""
        tiles = self.tiles
        lams = [t.lam for t in tiles]
        sizes = [t.tile.n for t in tiles]
        if self.target_psnr is not None:
            lam_line = f"each tile's searched for its fidelity: {min(lams):.3g}-{max(lams):.3g}"
        else:
            lam_line = (
                f"{self.lam_asked:.4g} asked (it sets the bytes); tiles coded at {min(lams):.3g}-"
                f"{max(lams):.3g} with their own removal and grid, in those bytes"
            )
            if self.target_size:
                lam_line += f", then each in its share of the {self.target_size:,} B target"
        out = {
            "Gaussians": self.counts.summary(),
            "tiles": f"{len(tiles)} of {min(sizes):,}-{max(sizes):,} Gaussians, coded on {self.ran_on} "
            f"({sum(t.seconds for t in tiles):.1f} s of tile work)",
            "lambda": lam_line,
        }
        known = [t.occlusion for t in tiles if t.occlusion is not None]
        if known:  # gspc/encoder/occlusion.py
            seen = [k.seen for k in known]
            out["occlusion"] = (
                f"each tile measured with what the other tiles hide: their opaque depths in view at "
                f"{min(seen)}-{max(seen)} of {known[0].views} views (the cameras and halfway between them), "
                f"maps at 1/{known[0].cell} of their pixels"
            )
        chosen: dict[str, int] = {}
        for t in tiles:
            key = t.removal.chosen() if t.removal is not None else "the preset's removal and grid (no search)"
            chosen[key] = chosen.get(key, 0) + 1
        out["removal"] = "; ".join(f"{k}: {v} tile{'s' if v > 1 else ''}" for k, v in chosen.items())
        if self.target_psnr is not None:
            scores = [t.fidelity_db for t in tiles if t.fidelity_db is not None]
            short = sum(not t.fidelity_reached for t in tiles)
            shares = [t.share_db for t in tiles]
            out["fidelity"] = (
                f"each tile coded to its share of {self.target_psnr:g} dB at views between the cameras that "
                f"see it (the target +{min(shares):.1f} to +{max(shares):.1f} dB, for the tiles those "
                f"cameras see): {min(scores):.2f}-{max(scores):.2f} dB less its share"
            )
            if short:
                out["fidelity"] += f"; {short} of {len(tiles)} tiles short of it within the preset's size"
        tuned = [t.tuning for t in tiles if t.tuning is not None and t.tuning.kept]
        if any(t.tuning is not None for t in tiles):
            gain = sum(t.after_db - t.before_db for t in tuned) / max(1, len(tuned))
            out["tuning"] = (
                f"{len(tuned)} of {len(tiles)} tiles kept their tuned values ({gain:+.2f} dB mean)"
            )
        out["side info"] = self.side_info
        checks = [t.side.check for t in tiles if t.side is not None and t.side.check is not None]
        if checks:  # what each tile's check measured at its views carrying none (policy.py)
            gains = [c.refined_db - c.coded_db for c in checks]
            rivals = [c.best_rival_db - c.coded_db for c in checks]
            out["tile checks"] = (
                f"{len(checks)} tiles: refined with their side information {min(gains):+.2f} to "
                f"{max(gains):+.2f} dB over their coding, the same bytes on attributes {min(rivals):+.2f} to "
                f"{max(rivals):+.2f} dB"
            )
        sent = sum(_sends(t) for t in tiles)
        spans = [t.tile.span for t in tiles if _sends(t) and t.tile.span > 1]
        shared = f" ({len(spans)} of them with their spans' {sum(spans)} tiles, as one)" if spans else ""
        out["decoder refines"] = (
            f"each of {sent} tiles against its own views{shared}, up to {self.refine_iterations} iterations "
            "by default"
            if sent
            else "nothing (no side information)"
        )
        return out

    def _lambda_line(self) -> str:
        lam = self.attributes.lam
        if self.fidelity is not None:
            return f"{lam:.4g} (searched for the {self.fidelity.target_db:g} dB target)"
        if self.target_size is not None:
            return f"{lam:.4g} (searched for the {self.target_size:,} B target)"
        if not self.lambda_reasons:
            return f"{lam:.4g}"
        why = " and ".join(self.lambda_reasons)
        return f"{self.lam_asked:.4g} asked (it sets the bytes), coded at {lam:.4g}: {why}, in those bytes"


def decide(
    scene: GaussianScene,
    cameras: list[Camera] | None,
    opts: EncodeOptions,
    stages: Stages,
    device,
    executor: Executor | None = None,
) -> EncoderDecisions:
    """The encoder's decisions for ``scene`` (``cameras`` None: synthesised) under ``opts``; renders,
    the check and the restorer run on ``device``, the attribute codec on the CPU. A scene of more than
    ``opts.tile_size`` Gaussians is coded as spatial tiles (:func:`decide_tiled`, on ``executor``)."""
    if is_tiled(scene.num_gaussians, opts):
        return decide_tiled(SceneRows(scene), cameras, opts, stages, executor)
    cams = encoder_cameras(scene, cameras, opts)
    restorer = load_restorer(opts.restorer, device=device)  # fails early on a name the package lacks
    params = codec_params(opts)
    with stages.stage("attributes"):
        measure = measure_scene(scene, cams, params, opts.background, stages.progress)
    budget = None if opts.target_size is None else opts.target_size - FRAMING_BYTES
    for _ in range(TARGET_RETRIES + 1):
        decisions = _decide_at(scene, cams, opts, stages, device, restorer, measure, budget)
        if opts.target_size is None:
            return decisions
        size = len(file_bytes(decisions, scene, opts))
        if size <= opts.target_size:
            return decisions
        budget = decisions.attributes.num_bytes - (size - opts.target_size) - 8
    raise InputError(
        f"--target-size {opts.target_size:,} B cannot be reached: the file stays at {size:,} B (its framing "
        "and side information leave too few bytes for the attributes); a larger target"
    )


def is_tiled(num_gaussians: int, opts: EncodeOptions) -> bool:
    """Whether a scene of ``num_gaussians`` is coded as spatial tiles (``--tile-size``; 0: never)."""
    return opts.tile_size > 0 and num_gaussians > opts.tile_size


def decide_tiled(
    source,
    cameras: list[Camera] | None,
    opts: EncodeOptions,
    stages: Stages,
    executor: Executor | None = None,
) -> EncoderDecisions:
    """A scene larger than a tile, as spatial tiles each coded alone, on ``executor`` (None: the options'
    workers or Ray; gspc/encoder/tiles.py); ``source`` reads its Gaussians by rows (gspc/io/ply.py PlyRows,
    SceneRows). Each tile weighs side information of its own (spec 10.15), or each span of tiles
    (``--span-size``, 10.17: gspc/encoder/spans.py)."""
    with executor_for(executor, opts.workers, opts.ray, encode_worker_bytes(opts.span_size)) as ex:
        return _decide_tiled_on(source, cameras, opts, stages, ex)


def _decide_tiled_on(
    source, cameras: list[Camera] | None, opts: EncodeOptions, stages: Stages, ex: Executor
) -> EncoderDecisions:
    cams = encoder_cameras(_camera_sample(source), cameras, opts)
    params = codec_params(opts)
    fp = fidelity_params(opts)
    # Each tile weighs side information of its own (spec 10.15) where the options and preset ask for any.
    side = opts if opts.side_info and quality_preset(opts.quality).side_info else None
    settings = TileSettings(
        tuple(cams),
        params,
        opts.background,
        removal_params(opts),
        tuning_params(opts),
        fp,
        side,
        opts.tile_neighbours,
    )
    target = None if opts.target_size is None else opts.target_size
    at_rate = None  # a retry codes only the tiles in their new shares
    for _ in range(TARGET_RETRIES + 1):
        budget = None if target is None else target - _tiled_framing(source.num_gaussians, opts.tile_size)
        with stages.stage("tiles", announce=False):
            if opts.span_size and side is not None:  # side information shared by spans (spec 10.17)
                plan, codings, at_rate, _ = code_spans(
                    source, settings, opts.tile_size, opts.span_size, ex, stages.progress, budget, at_rate
                )
            else:
                plan, codings, at_rate = code_tiles(
                    source, settings, opts.tile_size, ex, budget, stages.progress, at_rate
                )
        given = sum(c.given for c in codings)
        candidates = sum(c.candidates for c in codings)
        coded = sum(c.tile.n for c in codings)
        decisions = EncoderDecisions(
            attributes=None,
            side=None,
            refine_iterations=max((c.side.refine_iterations for c in codings if _sends(c)), default=0),
            counts=GaussianCounts(given, given - candidates, candidates - coded, coded),
            lam_asked=params.lam,
            lambda_reasons=(),
            side_info=spans_line(codings) if opts.span_size and side else _tiles_side_line(codings, opts),
            target_size=opts.target_size,
            tiles=tuple(codings),
            ran_on=ex.describe(),
            target_psnr=None if fp is None else fp.target_db,
            coordinates=source.coordinates,
        )
        if target is None:
            return decisions
        size = len(file_bytes(decisions, None, opts))
        if size <= opts.target_size:
            return decisions
        target -= size - opts.target_size + 8
    raise InputError(
        f"--target-size {opts.target_size:,} B cannot be reached: the tiled file stays at {size:,} B"
    )


def _sends(coding: TileCoding) -> bool:
    return coding.side is not None and coding.side.payload is not None


def _tiles_side_line(codings: list[TileCoding], opts: EncodeOptions) -> str:
    """The summary's side-information line of a tiled file: how many tiles carry their own (spec 10.15)."""
    if not opts.side_info:
        return "none (--no-side-info)"
    if all(c.side is None for c in codings):
        return f"none (the {opts.quality} preset: a file for viewers, which do not refine)"
    sent = [c for c in codings if _sends(c)]
    weighed = [c for c in codings if c.side is not None]
    if not sent:
        return f"none sent: {_reasons(weighed)}"
    size = sum(len(c.side.payload) for c in sent)
    views = sum(c.side.views_with_residual for c in sent)
    drawn = sum(len(c.tile.drawn) for c in sent)
    beside = f", each drawn with its neighbouring tiles ({drawn / len(sent):.1f} on average)" if drawn else ""
    line = (
        f"each tile's own: sent for {len(sent)} of {len(codings)} tiles ({_reasons(sent)}), {views} views "
        f"with a residual, {size:,} B{beside}"
    )
    unsent = [c for c in weighed if not _sends(c)]
    return f"{line}; not sent: {_reasons(unsent)}" if unsent else line


def _reasons(codings) -> str:
    """How many tiles gave each reason (the side-information step's line, its head: gspc/encoder/
    side_decision.py), most common first."""
    heads: dict[str, int] = {}
    for c in codings:
        head = c.side.reason.split(":")[0]
        head = head.removeprefix("none (").removeprefix("sent (").removeprefix("none").rstrip(")").strip()
        head = head or "its check found it does not pay"
        heads[head] = heads.get(head, 0) + 1
    ranked = sorted(heads.items(), key=lambda x: -x[1])
    return "; ".join(f"{k}: {v} tile{'s' if v > 1 else ''}" for k, v in ranked)


def _tiled_framing(num_gaussians: int, tile_size: int) -> int:
    """About what a tiled file spends around its tiles' attribute bytes: the header, and per tile its index
    entry and its chunks' table entries and padding (spec 10.14)."""
    tiles = -(-num_gaussians // tile_size)
    return FRAMING_BYTES + tiles * (7 * CHUNK_ENTRY_BYTES + 512)


def _camera_sample(source) -> GaussianScene:
    """Evenly spaced Gaussians of ``source``, enough to place synthesised cameras around the scene."""
    n = source.num_gaussians
    rows = np.unique(np.linspace(0, n - 1, min(n, CAMERA_SAMPLE)).astype(np.int64))
    return source.rows(rows)


def _decide_at(
    scene: GaussianScene,
    cams: list[Camera],
    opts: EncodeOptions,
    stages: Stages,
    device,
    restorer,
    measure: Measure,
    attribute_budget: int | None,
) -> EncoderDecisions:
    """:func:`decide` with the attributes (and, with a target, the side information they make room for)
    in at most ``attribute_budget`` bytes (None: at the rate)."""
    with stages.stage("attributes"):
        coded = code_attributes(
            scene,
            cams,
            codec_params(opts),
            attribute_budget,
            opts.background,
            stages.progress,
            removal_params(opts),
            stages.deadline,
            measure,
        )
    fidelity = None
    fp = fidelity_params(opts)
    if fp is not None:  # the fewest bytes that reach the fidelity, with the choices kept
        # A file that cannot carry side information is coded with the parameters for no refinement: the
        # search reaches the target with those, not with others re-searched in the same bytes after.
        no_side = not (opts.side_info and quality_preset(opts.quality).side_info)
        params = coded.params.unrefined() if no_side else coded.params
        fidelity = _fidelity_search(scene, coded, params, cams, opts, fp, stages, stages.progress)
        reached = fidelity.encoded
        coded = replace(coded, encoded=reached, params=coded.params.with_lambda(reached.lam))
        if attribute_budget is not None and reached.num_bytes > attribute_budget:
            raise InputError(
                f"--target-psnr {opts.target_psnr:g} dB needs {reached.num_bytes:,} B of attributes, more "
                f"than --target-size {opts.target_size:,} B allows"
            )
    if attribute_budget is not None and fidelity is None:
        _refuse_missed_target(coded.encoded, attribute_budget, opts.target_size)

    def tune(
        enc: EncodedAttributes, limit: int | None = attribute_budget
    ) -> tuple[EncodedAttributes, TuningReport | None]:
        return _tuned(scene, enc, coded, cams, opts, stages, limit)

    side = side_information(
        scene, cams, coded, restorer, opts, device, stages, attribute_budget, fidelity is not None, tune
    )
    attributes, tuning = side.attributes, side.tuning

    def search(target_db: float, lam: float) -> EncodedAttributes:
        params = coded.params.unrefined().with_lambda(lam)
        lower = replace(fp, target_db=target_db)
        return _fidelity_search(scene, coded, params, cams, opts, lower, stages).encoded

    if side.side is None and fidelity is not None:  # tuned, and brought back near the target
        tolerance = fp.tolerance_db
        attributes, tuning, reached_db = tuned_to_fidelity(attributes, fidelity, tolerance, tune, search)
        fidelity = replace(fidelity, encoded=attributes, psnr_db=reached_db)
    elif side.side is None and tuning is None:  # a file the decoder does not refine: its values tuned
        attributes, tuning = tune(attributes)
    elif fidelity is not None:  # what the file itself renders at the fidelity's views
        fidelity = replace(fidelity, encoded=attributes, psnr_db=fidelity.score(attributes))
    return EncoderDecisions(
        attributes=attributes,
        side=side.side,
        refine_iterations=side.refine_iterations,
        counts=_counts(scene, coded, attributes),
        lam_asked=codec_params(opts).lam,
        lambda_reasons=_lambda_reasons(coded, side, attributes),
        side_info=side.reason,
        removal=coded.removal if coded.removal is not None and coded.removal.base is not None else None,
        check=side.check,
        tuning=tuning,
        target_size=opts.target_size,
        fidelity=fidelity,
    )


def _fidelity_search(
    scene: GaussianScene,
    coded: CodedAttributes,
    params: CodecParams,
    cams: list[Camera],
    opts: EncodeOptions,
    fp: FidelityParams,
    stages: Stages,
    progress=None,
) -> Fidelity:
    """The fidelity search (gspc/encoder/fidelity.py) over ``coded``'s visibility and measure, from
    ``params``, with the options' removal kept."""
    with stages.stage("fidelity", announce=False):
        return code_to_fidelity(
            scene.to("cpu"),
            params,
            coded.visible,
            coded.significance,
            cams,
            opts.background,
            fp,
            removal_params(opts) or RemovalParams(),
            progress=progress,
        )


def _lambda_reasons(coded: CodedAttributes, side: SideChoice, enc: EncodedAttributes) -> tuple[str, ...]:
    """What moved the coding's lambda away from the one asked, in the bytes that lambda codes."""
    reasons = []
    if coded.removal is not None and coded.removal.kept is not coded.removal.base:
        reasons.append(coded.removal.chosen())
    if side.check is not None and side.check.outcome is Outcome.SPENT_ON_ATTRIBUTES:
        reasons.append("the side information's bytes spent on attributes")
    elif side.side is None and not coded_with(enc, coded.params):
        reasons.append("the finer scales and rotations of a file decoded without refinement")
    return tuple(reasons)


def _refuse_missed_target(enc: EncodedAttributes, budget: int, target: int | None) -> None:
    """InputError where even the coarsest coding the search tried is over the attributes' budget."""
    if enc.num_bytes > budget:
        raise InputError(
            f"--target-size {target:,} B cannot be reached: the coarsest coding tried (lambda {enc.lam:.3g}) "
            f"takes {enc.num_bytes:,} B for its {enc.decoded.num_gaussians:,} Gaussians' attributes alone; "
            "a larger target"
        )


def _counts(scene: GaussianScene, coded: CodedAttributes, enc: EncodedAttributes) -> GaussianCounts:
    candidates = int(prune_mask(scene, coded.params, coded.visible).sum())
    n = enc.decoded.num_gaussians
    return GaussianCounts(scene.num_gaussians, scene.num_gaussians - candidates, candidates - n, n)


def _tuned(
    scene: GaussianScene,
    enc: EncodedAttributes,
    coded: CodedAttributes,
    cameras: list[Camera],
    opts: EncodeOptions,
    stages: Stages,
    byte_limit: int | None,
) -> tuple[EncodedAttributes, TuningReport | None]:
    """``enc`` (the preset's coding, the one for no side information, or the check's rival: all with
    ``coded``'s visibility and measure) with its values tuned as the options ask (gspc/encoder/tuning.py),
    within ``byte_limit`` where given.

    Only files without side information are tuned: where the decoder refines against side information it
    moves the same values inside the same cells, for less than the tuning costs (bench/tuning.md)."""
    tuning = tuning_params(opts)
    if tuning is None:
        return enc, None
    unrefined = coded.params.unrefined()
    params = unrefined if coded_with(enc, unrefined) else coded.params
    with stages.stage("tune", announce=False):
        tuned = tune_coding(
            scene,
            enc,
            params,
            cameras,
            opts.background,
            coded.visible,
            coded.significance,
            tuning,
            byte_limit=byte_limit,
            deadline=stages.deadline,
            progress=stages.progress,
        )
    return tuned.encoded, tuned.report


def file_bytes(decisions: EncoderDecisions, scene: GaussianScene | None, opts: EncodeOptions) -> bytes:
    """The .gspc file the decisions describe. The decoder refuses views beyond its pixel and work budgets for
    the file's size (spec 10.8): the encoder refuses to write a file it would refuse."""
    if decisions.tiles:
        return _tiled_file_bytes(decisions, opts)
    enc, side = decisions.attributes, decisions.side
    iterations, work = decisions.refine_iterations, None
    if side is not None:
        # Name no more iterations than a decode of this file runs (its payloads' bytes: a lower bound).
        work = decode_work(enc.decoded, [v.camera.to_camera() for v in side.records], side.images, None)
        payloads = enc.num_bytes + len(side.payload)
        iterations = refine_iterations(iterations, work, payloads)
    header = FileHeader(
        encoder=f"gspc {__version__}",
        scene=SceneSummary(
            enc.decoded.num_gaussians,
            enc.decoded.sh_degree,
            scene.num_gaussians,
            scene.coordinates,
            decisions.fidelity.psnr_db if decisions.fidelity is not None else None,
        ),
        attributes=enc.section,
        side_info=SideInfoHeader(opts.background, opts.restorer, iterations),
    )
    data = pack_file(header, enc.chunks, side.payload if side is not None else None)
    try:
        check_view_pixels(side.records if side is not None else [], len(data))
        if work is not None:
            check_decode_work(work, len(data))
    except CodecError as e:
        raise InputError(f"{e}; lower --max-side or --views-fraction") from None
    return data


def _lowest_fidelity(tiles: tuple[TileCoding, ...]) -> float | None:
    """A tiled file's fidelity: its lowest tile's, where every tile was coded to one (None: not)."""
    scores = [t.fidelity_db for t in tiles]
    return None if any(x is None for x in scores) else min(scores)


def _tiled_file_bytes(decisions: EncoderDecisions, opts: EncodeOptions) -> bytes:
    """A tiled file (spec 10.14): its header names no attribute section, its tile index holds the tiles'."""
    tiles = decisions.tiles
    header = FileHeader(
        encoder=f"gspc {__version__}",
        scene=SceneSummary(
            decisions.counts.coded,
            tiles[0].tile.section.sh_degree,
            decisions.counts.given,
            decisions.coordinates,
            _lowest_fidelity(tiles),
        ),
        attributes=None,
        side_info=SideInfoHeader(opts.background, opts.restorer, decisions.refine_iterations),
    )
    sides = decisions.tile_sides
    data = pack_tiled_file(header, [(t.tile, t.chunks) for t in tiles], None, sides)
    written = read_file(data) if any(sides) else None
    jobs = None if written is None else file_tile_jobs(written.tiles.tiles, written.tile_chunks)
    for k, t in enumerate(tiles):  # each tile's views within its (span's) share of the budget (10.15, 10.17)
        if _sends(t):
            share = written.tile_allowances[k]
            try:
                if sum(t.side.work.pixels) > share.pixels:
                    raise CodecError(f"its views ask for more than its {share.pixels:,} pixels")
                check_decode_work(t.side.work, share)
                if t.tile.drawn:  # as a decoder counts it: the neighbours decoded
                    drawn = tuple(jobs[j] for j in t.tile.drawn)
                    span = [decode_tile(jobs[j]) for j in range(k, k + t.tile.span)]
                    scene = GaussianScene.concat(span)
                    tile_views_work(scene, written.tile_sides[k], drawn, share)
            except CodecError as e:
                raise InputError(f"tile {k}: {e}; lower --max-side or --views-fraction") from None
    return data
