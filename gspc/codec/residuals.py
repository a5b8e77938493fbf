"""Side information: signed render residuals R = I - I~ coded as small lossy images.

A residual (H, W, 3) float32 is mapped to unsigned integers ``q = round(R * gain + offset)``
(offset at mid-range, gain from a robust percentile of |R| so clipping is rare), then coded by a
still-image codec. Its :class:`gspc.format.view_records.ResidualRecord` holds everything
:func:`decode_residual` needs; the images' declared sizes are read in gspc/format/image_headers.py.

Image codecs sit behind one interface, :class:`ImageCodec` (``IMAGE_CODECS``: the ones this imagecodecs
build has), whose rate parameter is a *distance* for every codec: larger is coarser and smaller. It is JPEG
XL's butteraugli distance; WebP and AVIF take a quality 0-100 (larger is finer), and a distance ``d`` maps
to quality ``100 - 10 d`` (:func:`quality_for_distance`). The mapping makes the knob run the same way for
every codec; it does not make equal distances cost equal bytes (bench/residual_codecs.md compares the codecs
at equal bytes). Decoding is deterministic: the codecs return integers and the float mapping is plain numpy
arithmetic.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import imagecodecs
import numpy as np

from gspc.errors import CodecError, InputError
from gspc.format.view_records import MAX_RESIDUAL_SCALE, RESIDUAL_CODECS, ResidualRecord

# Effort 3 codes residuals about as small as effort 7, far faster (bench/residual_codecs.md, "Moved from code
# comments").
JXL_EFFORT = 3


@dataclass(frozen=True)
class ResidualParams:
    """How one residual is coded (keyword-built: a misspelt knob is a TypeError, not ignored)."""

    codec: str = "jxl"
    distance: float = 2.0  # the rate knob, larger is coarser (see the module's doc)
    bits: int = 8
    percentile: float = 99.9  # |R| at this percentile maps to the edge of the integer range
    max_gain: float = 2048.0  # caps amplification of near-zero residuals (in units of 1/range)
    tile: int = 32  # tiles whose RMS is below zero_rms are zeroed before coding; 0 disables
    zero_rms: float = 0.0
    scale: int = 1  # code the residual at 1/scale resolution (box filter); the decoder upsamples bilinearly


def downsample(r: np.ndarray, factor: int) -> np.ndarray:
    """Box-filter an (H, W, C) image by an integer factor, edge-padding to a multiple of it."""
    if factor == 1:
        return r
    h, w = r.shape[:2]
    ph, pw = -h % factor, -w % factor
    r = np.pad(r, ((0, ph), (0, pw), (0, 0)), mode="edge")
    return r.reshape(r.shape[0] // factor, factor, r.shape[1] // factor, factor, -1).mean(axis=(1, 3))


def upsample(r: np.ndarray, factor: int, h: int, w: int) -> np.ndarray:
    """Bilinear upsampling (pixel-centre aligned) back to (h, w); inverse of :func:`downsample`'s grid."""
    if factor == 1:
        return r[:h, :w]

    def axis(n_out: int, n_in: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = (np.arange(n_out) + 0.5) / factor - 0.5
        x = np.clip(x, 0, n_in - 1)
        i0 = np.floor(x).astype(np.int64)
        i1 = np.minimum(i0 + 1, n_in - 1)
        return i0, i1, (x - i0).astype(np.float32)

    y0, y1, fy = axis(h, r.shape[0])
    x0, x1, fx = axis(w, r.shape[1])
    top = r[y0][:, x0] * (1 - fx)[None, :, None] + r[y0][:, x1] * fx[None, :, None]
    bot = r[y1][:, x0] * (1 - fx)[None, :, None] + r[y1][:, x1] * fx[None, :, None]
    return (top * (1 - fy)[:, None, None] + bot * fy[:, None, None]).astype(np.float32)


def quality_for_distance(distance: float) -> float:
    """The WebP / AVIF quality (0-100, larger is finer) that stands for a distance (larger is coarser)."""
    return min(100.0, max(0.0, 100.0 - 10.0 * float(distance)))


def _jxl_encode(img: np.ndarray, distance: float) -> bytes:
    return imagecodecs.jpegxl_encode(img, distance=float(distance), effort=JXL_EFFORT)


def _jxl_decode(data: bytes) -> np.ndarray:
    # The first frame only: a residual is one frame, and an animation's further frames would cost memory
    # that its size header does not announce.
    return imagecodecs.jpegxl_decode(data, index=0)


def _webp_encode(img: np.ndarray, distance: float) -> bytes:
    # imagecodecs codes WebP losslessly unless told otherwise.
    return imagecodecs.webp_encode(img, level=quality_for_distance(distance), lossless=False, method=4)


def _avif_encode(img: np.ndarray, distance: float) -> bytes:
    # 4:4:4 keeps chroma resolution: residual colour errors are not smooth like photos.
    level = int(round(quality_for_distance(distance)))
    return imagecodecs.avif_encode(img, level=level, speed=8, pixelformat="444")


@dataclass(frozen=True)
class ImageCodec:
    """A still-image codec for residuals: encode at a distance, decode."""

    name: str
    encode: Callable[[np.ndarray, float], bytes]  # (uint8 or uint16 H x W x 3, distance) -> bytes
    decode: Callable[[bytes], np.ndarray]
    bits: tuple[int, ...]  # sample depths imagecodecs accepts (WebP is 8-bit only)
    available: Callable[[], bool]


_JXL = ImageCodec("jxl", _jxl_encode, _jxl_decode, (8, 16), lambda: imagecodecs.JPEGXL.available)
_WEBP = ImageCodec("webp", _webp_encode, imagecodecs.webp_decode, (8,), lambda: imagecodecs.WEBP.available)
_AVIF = ImageCodec("avif", _avif_encode, imagecodecs.avif_decode, (8, 16), lambda: imagecodecs.AVIF.available)
# Every codec a file may name (gspc/format/view_records.py), and those this imagecodecs build can run.
_ALL_CODECS: dict[str, ImageCodec] = {c.name: c for c in (_JXL, _WEBP, _AVIF)}
assert tuple(_ALL_CODECS) == RESIDUAL_CODECS
IMAGE_CODECS: dict[str, ImageCodec] = {k: c for k, c in _ALL_CODECS.items() if c.available()}


def _image_codec(name: str) -> ImageCodec:
    if name not in IMAGE_CODECS:
        raise CodecError(f"residual image codec {name!r} is not available (have: {', '.join(IMAGE_CODECS)})")
    return IMAGE_CODECS[name]


def choose_gain(
    residual: np.ndarray, bits: int = 8, percentile: float = 99.9, max_gain: float = 2048.0
) -> float:
    """Gain mapping |R| at ``percentile`` to the edge of the ``bits`` integer range.

    ``max_gain`` is per 8-bit level and scaled for 16 bits. The result is rounded to a float32 so
    encoder and decoder use the identical value after msgpack.
    """
    half = (1 << (bits - 1)) - 1
    p = float(np.percentile(np.abs(residual), percentile)) if residual.size else 0.0
    cap = max_gain * (1 << (bits - 8))
    gain = cap if p <= half / cap else half / p
    return float(np.float32(gain))


def _zero_quiet_tiles(residual: np.ndarray, tile: int, zero_rms: float) -> tuple[np.ndarray, int]:
    """Residual with every tile whose RMS is below ``zero_rms`` set to 0; returns (array, tiles zeroed)."""
    if tile <= 0 or zero_rms <= 0:
        return residual, 0
    h, w, _ = residual.shape
    out = residual.copy()
    zeroed = 0
    for y in range(0, h, tile):
        for x in range(0, w, tile):
            block = out[y : y + tile, x : x + tile]
            if float(np.sqrt(np.mean(block.astype(np.float64) ** 2))) < zero_rms:
                block[...] = 0
                zeroed += 1
    return out, zeroed


def encode_residual(
    residual: np.ndarray, params: ResidualParams | None = None
) -> tuple[bytes, ResidualRecord]:
    """Code a signed residual (H, W, 3) float. Returns (image bytes, its record)."""
    p = params or ResidualParams()
    r = np.asarray(residual, dtype=np.float32)
    if r.ndim != 3 or r.shape[2] != 3:
        raise InputError(f"residual must be HxWx3, got shape {r.shape}")
    if not np.isfinite(r).all():
        raise InputError("residual has NaN or Inf values")
    codec = _image_codec(p.codec)
    if p.bits not in codec.bits:
        raise InputError(f"residual codec {p.codec!r} does not take {p.bits}-bit samples")
    full_h, full_w = r.shape[:2]
    if not 1 <= p.scale <= MAX_RESIDUAL_SCALE:
        raise InputError(f"residual scale must be 1..{MAX_RESIDUAL_SCALE}, got {p.scale}")
    r, zeroed = _zero_quiet_tiles(r, int(p.tile), float(p.zero_rms))
    r = downsample(r, p.scale).astype(np.float32)
    gain = choose_gain(r, p.bits, float(p.percentile), float(p.max_gain))
    record = ResidualRecord(p.codec, p.bits, gain, (full_h, full_w), p.scale, zeroed)
    top = (1 << p.bits) - 1
    dtype = np.uint8 if p.bits == 8 else np.uint16
    q = np.clip(np.rint(r * np.float32(gain) + record.offset), 0, top).astype(dtype)
    return codec.encode(np.ascontiguousarray(q), float(p.distance)), record


def decode_residual(payload: bytes, record: ResidualRecord) -> np.ndarray:
    """Inverse of :func:`encode_residual`: (H, W, 3) float32 at the view's full size. The record was
    checked where it was built and the image's declared size where the file was read
    (gspc/format/side_chunk.py); CodecError where the image does not decode to that size."""
    codec = record.codec
    try:
        q = _image_codec(codec).decode(payload)
    except Exception as e:  # imagecodecs raises its own per-codec error classes
        raise CodecError(f"residual {codec} payload does not decode: {e}") from None
    if q.ndim == 2:
        q = np.repeat(q[:, :, None], 3, axis=2)
    h, w = record.shape
    if q.shape[:2] != (h, w) or q.shape[2] < 3:
        raise CodecError(f"residual decodes to shape {q.shape}, expected {h}x{w}x3")
    gain, offset = np.float32(record.gain), np.float32(record.offset)
    r = ((q[:, :, :3].astype(np.float32) - offset) / gain).astype(np.float32)
    if record.scale != 1:
        r = upsample(r, record.scale, *record.full_shape)
    return r


def plan_residual_rates(
    residuals: list[np.ndarray],
    distance: float,
    skip_rms: float = 1.0 / 255,
    strength: float = 0.5,
    clamp: tuple[float, float] = (0.5, 2.0),
) -> list[float | None]:
    """Distance per view (see the module's doc), or None for views not worth a chunk.

    Views whose residual RMS is below ``skip_rms`` (default: one level of an 8-bit image, too little for a
    viewer to see) are skipped. The others get
    ``distance * clip((median_rms / rms) ** strength, *clamp)``: finer coding where the
    compressed scene went most wrong. Because the gain normalises each residual to the integer
    range, a fixed distance gives an error roughly proportional to the view's RMS; the exponent
    moves part of the budget from quiet views to loud ones (measured in bench/residual_codecs.md).
    """
    rms = [
        float(np.sqrt(np.mean(np.asarray(r, dtype=np.float64) ** 2))) if r.size else 0.0 for r in residuals
    ]
    kept = [v for v in rms if v >= skip_rms]
    if not kept:
        return [None] * len(residuals)
    median = float(np.median(kept))
    lo, hi = clamp
    out: list[float | None] = []
    for v in rms:
        if v < skip_rms:
            out.append(None)
        else:
            out.append(float(distance * np.clip((median / v) ** strength, lo, hi)))
    return out
