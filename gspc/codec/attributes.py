"""gspc's attribute codec: positions plus quantised, context-coded attributes, bit-exact on any CPU.

Chunks (bytes, stored by the container under these types):
- ``POSN`` Morton-ordered voxels (see :mod:`gspc.codec.positions`); the decoded order is curve order.
- ``OPAC`` activated opacity ``alpha`` quantised to ``L`` levels: ``q = round(alpha * L)``; decoded
  ``logit(clamp(q / L, 1/(4L), 1 - 1/(4L)))`` with a log built from +, -, *, / only.
- ``SCAL`` natural-log scales, ``q = round(log_scale / step)``, decoded ``q * step``.
- ``ROTN`` unit quaternion, smallest three: [index of the largest |component| (made positive),
  the other three in w, x, y, z order quantised over [-1/sqrt2, 1/sqrt2] in ``M`` steps]; the
  largest is ``sqrt(1 - sum of squares)``. Rotation error bound: :func:`rotation_error_bound`.
- ``SHDC`` ``q = round(dc / step)``; ``SHRS`` per-Gaussian flag (any non-zero SH rest symbol), then
  only flagged Gaussians' SH rest, coefficient-major, steps growing with degree. No SHRS at degree 0.
Each chunk is an :func:`gspc.codec.entropy.encode_matrix` payload (SHRS: a msgpack pair).
Dequantisation runs in float64 with correctly rounded ops and casts to float32 at the end.
The byte layouts are specified in spec/gspc-format.md, section 10.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import msgpack
import numpy as np
import torch

from gspc.codec import positions as pos
from gspc.codec.attribute_header import (
    CONTRACTED_VERSION,
    FORMAT_VERSION,
    GAUSSIANS_PER_BYTE,
    check_attribute_header,
)
from gspc.codec.entropy import decode_matrix, encode_matrix
from gspc.codec.params import CodecParams
from gspc.errors import CodecError
from gspc.format.chunks import ATTRIBUTE_TYPES, OPAC, POSN, ROTN, SCAL, SHDC, SHRS
from gspc.scene import GaussianScene, num_sh_rest

SQRT_HALF = 0.7071067811865476  # float64 nearest to 1/sqrt(2)
_LN2 = 0.6931471805599453
OPACITY_FLOOR = 1.0 / 255.0


@dataclass
class EncodedAttributes:
    chunks: dict[str, bytes]
    meta: dict
    decoded: GaussianScene  # G~, from decode_attributes on the chunks
    kept: np.ndarray  # indices into the input scene, in decoded (curve) order

    @property
    def num_bytes(self) -> int:
        """Chunk bytes plus the packed meta: what the container pays for this codec."""
        return sum(len(c) for c in self.chunks.values()) + len(msgpack.packb(self.meta, use_bin_type=True))


# ---------------------------------------------------------------------------------------------
# Deterministic helpers


def det_log(x: np.ndarray) -> np.ndarray:
    """Natural log of positive float64 values using only correctly rounded IEEE operations."""
    m, e = np.frexp(np.asarray(x, np.float64))
    small = m < SQRT_HALF
    m = np.where(small, m * 2.0, m)
    e = np.where(small, e - 1, e).astype(np.float64)
    t = (m - 1.0) / (m + 1.0)  # |t| <= 0.1716
    t2 = t * t
    acc = np.zeros_like(t)
    for k in range(27, 0, -2):  # atanh series, Horner from the highest term
        acc = acc * t2 + 1.0 / k
    return 2.0 * t * acc + e * _LN2


def rotation_error_bound(levels: int) -> float:
    """Largest rotation angle (radians) between a unit quaternion and its decoded version."""
    step = 2.0 * SQRT_HALF / levels
    e = math.sqrt(3.0) * step / 2.0  # norm of the three components' rounding errors
    d = 2.0 * e * (math.sqrt(3.0) + e)  # error of the recomputed largest component (it is >= 1/2)
    chord = math.sqrt(e * e + d * d)
    return 4.0 * math.asin(min(1.0, chord / 2.0))


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().numpy().astype(np.float64)


# ---------------------------------------------------------------------------------------------
# Per-attribute quantisers: encoder side (float -> int) and exact decoder side (int -> float32)


def _opacity_quantise(logits: np.ndarray, levels: int) -> np.ndarray:
    alpha = 1.0 / (1.0 + np.exp(-logits))
    return np.rint(alpha * levels).astype(np.int64)


def _opacity_dequantise(q: np.ndarray, levels: int) -> np.ndarray:
    a = q.astype(np.float64) / float(levels)
    a = np.clip(a, 0.25 / levels, 1.0 - 0.25 / levels)
    return (det_log(a) - det_log(1.0 - a)).astype(np.float32)


_OTHERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


def _rotation_quantise(quats: np.ndarray, levels: int) -> np.ndarray:
    q = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    big = np.argmax(np.abs(q), axis=1)
    q = q * np.where(q[np.arange(len(q)), big] < 0, -1.0, 1.0)[:, None]
    rest = np.take_along_axis(q, _OTHERS[big], axis=1)
    step = 2.0 * SQRT_HALF / levels
    comp = np.clip(np.rint((rest + SQRT_HALF) / step), 0, levels).astype(np.int64)
    return np.concatenate([big[:, None].astype(np.int64), comp], axis=1)


def _rotation_dequantise(sym: np.ndarray, levels: int) -> np.ndarray:
    big = sym[:, 0]
    if ((big < 0) | (big > 3)).any() or ((sym[:, 1:] < 0) | (sym[:, 1:] > levels)).any():
        raise CodecError("rotation symbols outside their range")
    step = 2.0 * SQRT_HALF / levels
    rest = sym[:, 1:].astype(np.float64) * step - SQRT_HALF
    ss = (rest[:, 0] * rest[:, 0] + rest[:, 1] * rest[:, 1]) + rest[:, 2] * rest[:, 2]
    largest = np.sqrt(np.maximum(1.0 - ss, 0.0))
    out = np.zeros((len(sym), 4))
    out[np.arange(len(sym)), big] = largest
    np.put_along_axis(out, _OTHERS[big], rest, axis=1)
    return out.astype(np.float32)


def _sh_steps(params: CodecParams, degree: int) -> list[float]:
    """Step of every SH rest coefficient (index k = 0 .. K-1), growing with its degree."""
    steps = []
    for k in range(num_sh_rest(degree)):
        deg = int(math.isqrt(k + 1))  # k = 0..2 degree 1, 3..7 degree 2, 8..14 degree 3
        growth = params.sh_degree_growth ** (deg - 1)
        steps.append(float(params.sh_step * params.lam**params.sh_lam_exponent * growth))
    return steps


def _deadzone_round(x: np.ndarray, offset: float) -> np.ndarray:
    """Round to nearest, but values within ``0.5 + offset`` steps of zero go to zero."""
    mag = np.maximum(np.floor(np.abs(x) + 0.5 - offset), 0.0)
    return (np.sign(x) * mag).astype(np.int64)


# ---------------------------------------------------------------------------------------------
# Codec


def prune_mask(scene: GaussianScene, params: CodecParams, visible: np.ndarray | None) -> np.ndarray:
    """Gaussians worth coding: visible to some view and at least 1/255 opaque, unless flags keep them."""
    keep = np.ones(scene.num_gaussians, bool)
    if not params.keep_transparent:
        keep &= torch.sigmoid(scene.opacities.detach().double()).cpu().numpy() >= OPACITY_FLOOR
    if visible is not None and not params.keep_invisible:
        visible = np.asarray(visible, bool).reshape(-1)
        if visible.shape[0] != scene.num_gaussians:
            raise CodecError(
                f"visibility mask has {visible.shape[0]} entries for {scene.num_gaussians} Gaussians"
            )
        keep &= visible
    return keep


def encode_attributes(
    scene: GaussianScene, params: CodecParams, visible: np.ndarray | None = None
) -> EncodedAttributes:
    """Encode a scene; ``decoded`` is what :func:`decode_attributes` returns for these chunks."""
    scene.validate()
    keep_idx = np.flatnonzero(prune_mask(scene, params, visible))
    if keep_idx.size == 0:
        raise CodecError("every Gaussian was pruned (transparent or unseen); use the keep flags to code them")
    means = _np(scene.means)[keep_idx]
    voxels, order, grid = pos.curve_order(means, params.effective_position_bits)
    kept = keep_idx[order]

    lam = params.lam
    opacity_levels = max(1, int(round(1.0 / (params.opacity_step * lam))))
    # Even levels make a zero component exact: axis-aligned Gaussians are common and odd levels cost
    # them half a step of rotation error (lego: +1.2 dB at equal bytes).
    rot_levels = 2 * max(1, int(math.ceil(SQRT_HALF / (params.rotation_step * params.geometry_lam))))
    scale_step = float(params.scale_step * params.geometry_lam)
    dc_step = float(params.dc_step * lam)
    sh_steps = _sh_steps(params, scene.sh_degree)
    meta = {
        "version": CONTRACTED_VERSION if pos.is_contracted(grid) else FORMAT_VERSION,
        "n": int(kept.size),
        "sh_degree": int(scene.sh_degree),
        "position": grid,
        "opacity_levels": opacity_levels,
        "scale_step": scale_step,
        "rotation_levels": rot_levels,
        "dc_step": dc_step,
        "sh_steps": sh_steps,
    }

    opac_q = _opacity_quantise(_np(scene.opacities)[kept], opacity_levels)
    chunks = {
        POSN: pos.encode_positions(voxels, grid["bits"]),
        OPAC: encode_matrix(opac_q[:, None]),
        SCAL: encode_matrix(np.rint(_np(scene.log_scales)[kept] / scale_step).astype(np.int64)),
        ROTN: encode_matrix(_rotation_quantise(_np(scene.quats)[kept], rot_levels)),
        SHDC: encode_matrix(np.rint(_np(scene.sh_dc)[kept] / dc_step).astype(np.int64)),
    }
    if scene.sh_degree > 0:
        rest = _np(scene.sh_rest)[kept] / np.asarray(sh_steps)[None, :, None]
        q = _deadzone_round(rest, params.sh_deadzone).reshape(len(kept), -1)
        # Faint Gaussians' view-dependent colour hardly shows: drop it (flag 0), an encoder-only choice.
        faint = opac_q.astype(np.float64) < min(0.5, params.sh_faint_alpha * lam) * opacity_levels
        flags = (q != 0).any(axis=1) & ~faint
        chunks[SHRS] = msgpack.packb(
            [encode_matrix(flags[:, None].astype(np.int64)), encode_matrix(q[flags])], use_bin_type=True
        )
    decoded = decode_attributes(chunks, meta)
    return EncodedAttributes(chunks=chunks, meta=meta, decoded=decoded, kept=kept)


def attribute_chunks(chunks: list) -> dict[str, bytes]:
    """The attribute payloads of a container's chunks by type; each type occurs once, with index 0."""
    out = {}
    for ch in chunks:
        if ch.type in ATTRIBUTE_TYPES:
            if ch.index != 0:
                raise CodecError(f"chunk {ch.type} has index {ch.index}; attribute chunks have index 0")
            out[ch.type] = ch.payload
    return out


def _matrix(chunks: dict[str, bytes], name: str, n: int, c: int) -> np.ndarray:
    if name not in chunks:
        raise CodecError(f"chunk {name} is missing")
    return decode_matrix(chunks[name], (n, c))


def decode_attributes(chunks: dict[str, bytes], meta: dict) -> GaussianScene:
    """Decode chunks to a float32 scene in curve order; identical on every machine."""
    check_attribute_header(meta)
    n, degree, grid = meta["n"], meta["sh_degree"], meta["position"]
    bits = grid["bits"]
    opacity_levels, rot_levels = meta["opacity_levels"], meta["rotation_levels"]
    scale_step, dc_step = meta["scale_step"], meta["dc_step"]
    sh_steps = list(meta["sh_steps"])
    if degree == 0 and SHRS in chunks:
        raise CodecError("chunk SHRS in a file of SH degree 0")
    payload_bytes = sum(len(chunks.get(t, b"")) for t in ATTRIBUTE_TYPES)
    if n > GAUSSIANS_PER_BYTE * payload_bytes:
        raise CodecError(
            f"{n} Gaussians from {payload_bytes} payload bytes (at most {GAUSSIANS_PER_BYTE} per byte)"
        )
    if POSN not in chunks:
        raise CodecError("chunk POSN is missing")
    voxels = pos.decode_positions(chunks[POSN], bits, n)
    means = pos.positions(voxels, grid)
    opac = _opacity_dequantise(_matrix(chunks, OPAC, n, 1)[:, 0], opacity_levels)
    scales = (_matrix(chunks, SCAL, n, 3).astype(np.float64) * scale_step).astype(np.float32)
    quats = _rotation_dequantise(_matrix(chunks, ROTN, n, 4), rot_levels)
    dc = (_matrix(chunks, SHDC, n, 3).astype(np.float64) * dc_step).astype(np.float32)
    k = num_sh_rest(degree)
    rest = np.zeros((n, k, 3), np.float32)
    if degree > 0:
        if SHRS not in chunks:
            raise CodecError("chunk SHRS is missing")
        try:
            flag_payload, rest_payload = msgpack.unpackb(chunks[SHRS], raw=False)
        except Exception:
            raise CodecError("chunk SHRS is malformed") from None
        if not (isinstance(flag_payload, bytes) and isinstance(rest_payload, bytes)):
            raise CodecError("chunk SHRS is not a pair of msgpack bins")
        flags = decode_matrix(flag_payload, (n, 1))
        if ((flags != 0) & (flags != 1)).any():
            raise CodecError("chunk SHRS has a malformed flag matrix")
        flags = flags[:, 0].astype(bool)
        q = decode_matrix(rest_payload, (int(flags.sum()), 3 * k))
        vals = q.reshape(-1, k, 3).astype(np.float64) * np.asarray(sh_steps)[None, :, None]
        rest[flags] = vals.astype(np.float32)
    t = torch.from_numpy
    return GaussianScene(t(means), t(quats), t(scales), t(opac), t(dc), t(rest), degree)


def search_lambda(
    scene: GaussianScene,
    target_bytes: int,
    params: CodecParams,
    visible: np.ndarray | None = None,
    rel_tol: float = 0.03,
    max_iter: int = 12,
) -> EncodedAttributes:
    """The encoding with the smallest lambda whose size is at most ``target_bytes`` (bisection in log lambda).

    Stops when a fit lands within ``rel_tol`` under the target; if even the coarsest lambda tried is
    too big, returns that one (the caller reports the miss).
    """
    lo, hi = math.log(1e-3), math.log(1e3)
    best: EncodedAttributes | None = None
    fallback: EncodedAttributes | None = None
    x = math.log(params.lam)
    for _ in range(max_iter):
        enc = encode_attributes(scene, params.with_lambda(math.exp(x)), visible)
        size = enc.num_bytes
        if size <= target_bytes:
            if best is None or size > best.num_bytes:
                best = enc
            if size >= (1.0 - rel_tol) * target_bytes:
                break
            hi = x
        else:
            if fallback is None or size < fallback.num_bytes:
                fallback = enc
            lo = x
        x = 0.5 * (lo + hi)
    return best if best is not None else fallback
