"""Side information: signed render residuals R = I - I~ coded as small lossy images.

A residual (H, W, 3) float32 is mapped to unsigned integers ``q = round(R * gain + offset)``
(offset at mid-range, gain from a robust percentile of |R| so clipping is rare), then coded by a
still-image codec. ``meta`` (msgpack-able) holds everything :func:`decode_residual` needs.

Image codecs sit behind one interface, :class:`ImageCodec` (``IMAGE_CODECS``: the ones this imagecodecs
build has), whose rate parameter is a *distance* for every codec: larger is coarser and smaller. It is JPEG
XL's butteraugli distance; WebP and AVIF take a quality 0-100 (larger is finer), and a distance ``d`` maps
to quality ``100 - 10 d`` (:func:`quality_for_distance`). The mapping makes the knob run the same way for
every codec; it does not make equal distances cost equal bytes (bench/residual_codecs.md compares the codecs
at equal bytes). Decoding is deterministic: the codecs return integers and the float mapping is plain numpy
arithmetic.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import asdict, dataclass

import imagecodecs
import numpy as np

from gspc.errors import CodecError, InputError

# Effort 3 codes residuals as small as effort 7 at about 15x the speed.
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


# --- image sizes from codestream headers, read before decoding (issue 15: a residual whose codestream
# declared a huge size was decoded before its size was checked) ---------------------------------------------

_JXL_RATIOS = {1: (1, 1), 2: (12, 10), 3: (4, 3), 4: (3, 2), 5: (16, 9), 6: (5, 4), 7: (2, 1)}
_JXL_CONTAINER = b"\x00\x00\x00\x0cJXL \r\n\x87\n"


class _Bits:
    """JPEG XL's bit reader: least significant bit of each byte first."""

    def __init__(self, data: bytes):
        self.data, self.pos = data, 0

    def read(self, n: int) -> int:
        v = 0
        for i in range(n):
            byte = self.pos >> 3
            if byte >= len(self.data):
                raise CodecError("residual jxl codestream ends inside its size header")
            v |= ((self.data[byte] >> (self.pos & 7)) & 1) << i
            self.pos += 1
        return v

    def u32_size(self) -> int:
        """U32(Bits(9) + 1, Bits(13) + 1, Bits(18) + 1, Bits(30) + 1), the SizeHeader's distribution."""
        return self.read((9, 13, 18, 30)[self.read(2)]) + 1


def _jxl_codestream(data: bytes) -> bytes:
    """The codestream of a bare JPEG XL stream or of the ISOBMFF container's first jxlc/jxlp box."""
    if not data.startswith(_JXL_CONTAINER):
        return data
    pos = 0
    while pos + 8 <= len(data):
        size, kind = struct.unpack_from(">I4s", data, pos)
        head = 8
        if size == 1 and pos + 16 <= len(data):
            (size,) = struct.unpack_from(">Q", data, pos + 8)
            head = 16
        end = len(data) if size == 0 else pos + size
        if kind == b"jxlc":
            return data[pos + head : end]
        if kind == b"jxlp":
            return data[pos + head + 4 : end]  # after the part index
        if size < head:
            break
        pos = end
    raise CodecError("residual jxl container holds no codestream box")


def _jxl_size(data: bytes) -> tuple[int, int]:
    """(width, height) from the SizeHeader that follows the codestream signature FF 0A."""
    code = _jxl_codestream(data)
    if code[:2] != b"\xff\x0a":
        raise CodecError("residual jxl payload does not start with a JPEG XL signature")
    b = _Bits(code[2:34])
    small = b.read(1)
    height = (b.read(5) + 1) * 8 if small else b.u32_size()
    ratio = b.read(3)
    if ratio:
        num, den = _JXL_RATIOS[ratio]
        width = height * num // den
    else:
        width = (b.read(5) + 1) * 8 if small else b.u32_size()
    return width, height


def _webp_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a WebP's first chunk: VP8 (lossy), VP8L (lossless) or VP8X (extended)."""
    if len(data) < 30 or data[:4] != b"RIFF" or data[8:12] != b"WEBP":
        raise CodecError("residual webp payload is not a RIFF WEBP file")
    kind, body = data[12:16], data[20:30]
    if kind == b"VP8 " and body[3:6] == b"\x9d\x01\x2a":
        w, h = struct.unpack_from("<HH", body, 6)
        return w & 0x3FFF, h & 0x3FFF
    if kind == b"VP8L" and body[0] == 0x2F:
        (bits,) = struct.unpack_from("<I", body, 1)
        return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
    if kind == b"VP8X":
        w = int.from_bytes(body[4:7], "little") + 1
        h = int.from_bytes(body[7:10], "little") + 1
        return w, h
    raise CodecError(f"residual webp payload has no size header (first chunk {kind!r})")


def _avif_size(data: bytes) -> tuple[int, int]:
    """The largest (width, height) of the image spatial extents (ispe) in meta/iprp/ipco."""

    def boxes(buf: bytes, start: int, end: int):
        pos = start
        while pos + 8 <= end:
            size, kind = struct.unpack_from(">I4s", buf, pos)
            head = 8
            if size == 1 and pos + 16 <= end:
                (size,) = struct.unpack_from(">Q", buf, pos + 8)
                head = 16
            size = end - pos if size == 0 else size
            if size < head or pos + size > end:
                return
            yield kind, pos + head, pos + size
            pos += size

    sizes = []
    for kind, a, b in boxes(data, 0, len(data)):
        if kind != b"meta":
            continue
        for kind2, a2, b2 in boxes(data, a + 4, b):  # meta is a full box: 4 bytes version and flags
            if kind2 != b"iprp":
                continue
            for kind3, a3, b3 in boxes(data, a2, b2):
                if kind3 != b"ipco":
                    continue
                for kind4, a4, b4 in boxes(data, a3, b3):
                    if kind4 == b"ispe" and b4 - a4 >= 12:
                        sizes.append(struct.unpack_from(">II", data, a4 + 4))
    if not sizes:
        raise CodecError("residual avif payload has no image size (ispe) box")
    return max(w for w, _ in sizes), max(h for _, h in sizes)


def _webp_encode(img: np.ndarray, distance: float) -> bytes:
    # imagecodecs codes WebP losslessly unless told otherwise.
    return imagecodecs.webp_encode(img, level=quality_for_distance(distance), lossless=False, method=4)


def _avif_encode(img: np.ndarray, distance: float) -> bytes:
    # 4:4:4 keeps chroma resolution: residual colour errors are not smooth like photos.
    level = int(round(quality_for_distance(distance)))
    return imagecodecs.avif_encode(img, level=level, speed=8, pixelformat="444")


@dataclass(frozen=True)
class ImageCodec:
    """A still-image codec for residuals: encode at a distance, decode, read the declared size."""

    name: str
    encode: Callable[[np.ndarray, float], bytes]  # (uint8 or uint16 H x W x 3, distance) -> bytes
    decode: Callable[[bytes], np.ndarray]
    size: Callable[[bytes], tuple[int, int]]  # (width, height) from the header, without decoding
    bits: tuple[int, ...]  # sample depths imagecodecs accepts (WebP is 8-bit only)
    available: Callable[[], bool]


_JXL = ImageCodec("jxl", _jxl_encode, _jxl_decode, _jxl_size, (8, 16), lambda: imagecodecs.JPEGXL.available)
_WEBP = ImageCodec(
    "webp", _webp_encode, imagecodecs.webp_decode, _webp_size, (8,), lambda: imagecodecs.WEBP.available
)
_AVIF = ImageCodec(
    "avif", _avif_encode, imagecodecs.avif_decode, _avif_size, (8, 16), lambda: imagecodecs.AVIF.available
)
# Every codec a file may name (the SIDE chunk's codec ids: gspc/codec/sideinfo.py), and those this
# imagecodecs build can run.
_ALL_CODECS: dict[str, ImageCodec] = {c.name: c for c in (_JXL, _WEBP, _AVIF)}
IMAGE_CODECS: dict[str, ImageCodec] = {k: c for k, c in _ALL_CODECS.items() if c.available()}


def coded_size(codec: str, payload: bytes) -> tuple[int, int]:
    """(width, height) that a residual image's header declares, without decoding it; CodecError if none."""
    if codec not in _ALL_CODECS:
        raise CodecError(f"residual image codec {codec!r} is not one gspc reads")
    try:
        return _ALL_CODECS[codec].size(bytes(payload))
    except (struct.error, IndexError, KeyError):
        raise CodecError(f"residual {codec} payload ends inside its size header") from None


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


def encode_residual(residual: np.ndarray, params: ResidualParams | None = None) -> tuple[bytes, dict]:
    """Code a signed residual (H, W, 3) float. Returns (payload, meta)."""
    p = asdict(params or ResidualParams())
    r = np.asarray(residual, dtype=np.float32)
    if r.ndim != 3 or r.shape[2] != 3:
        raise InputError(f"residual must be HxWx3, got shape {r.shape}")
    if not np.isfinite(r).all():
        raise InputError("residual has NaN or Inf values")
    bits = int(p["bits"])
    codec = _image_codec(p["codec"])
    if bits not in codec.bits:
        raise InputError(f"residual codec {p['codec']!r} does not take {bits}-bit samples")
    full_h, full_w = r.shape[:2]
    factor = int(p["scale"])
    if not 1 <= factor <= 16:
        raise InputError(f"residual scale must be 1..16, got {factor}")
    r, zeroed = _zero_quiet_tiles(r, int(p["tile"]), float(p["zero_rms"]))
    r = downsample(r, factor).astype(np.float32)
    gain = choose_gain(r, bits, float(p["percentile"]), float(p["max_gain"]))
    offset = 1 << (bits - 1)
    top = (1 << bits) - 1
    dtype = np.uint8 if bits == 8 else np.uint16
    q = np.clip(np.rint(r * np.float32(gain) + offset), 0, top).astype(dtype)
    payload = codec.encode(np.ascontiguousarray(q), float(p["distance"]))
    meta = {
        "codec": p["codec"],
        "shape": [int(r.shape[0]), int(r.shape[1])],
        "bits": bits,
        "gain": gain,
        "offset": offset,
    }
    if zeroed:
        meta["zeroed_tiles"] = zeroed  # informative
    if factor != 1:
        meta.update(scale=factor, full_shape=[full_h, full_w])
    return payload, meta


def check_residual(payload: bytes, meta: object, view_hw: tuple[int, int] | None = None) -> None:
    """CodecError unless ``meta`` names a codec, a positive finite gain, bits and offset, a scale in 1..16
    whose full shape is the view's (``view_hw``, when given), and the image's header declares the size
    ``meta`` names (meta["shape"] = [h, w]): all before any pixel is decoded."""
    try:
        codec, (h, w), gain = meta["codec"], meta["shape"], meta["gain"]  # type: ignore[index]
    except (KeyError, TypeError, ValueError) as e:
        raise CodecError(f"residual metadata is incomplete: {e}") from None
    if not isinstance(codec, str):
        raise CodecError(f"residual codec {codec!r} is not a name")
    if not (type(gain) in (int, float) and math.isfinite(gain) and gain > 0):
        raise CodecError(f"residual gain {gain!r} is not a positive finite number")
    bits, offset = meta.get("bits"), meta.get("offset")  # type: ignore[union-attr]
    if bits not in (8, 16) or type(bits) is not int or offset != 1 << (bits - 1) or type(offset) is not int:
        raise CodecError(f"residual bits {bits!r} and offset {offset!r} are not 8 or 16 and 2^(bits - 1)")
    scale = meta.get("scale", 1)  # type: ignore[union-attr]
    if type(scale) is not int or not 1 <= scale <= 16:
        raise CodecError(f"residual scale {scale!r} is not an integer in 1..16")
    full = meta.get("full_shape", [h, w]) if scale != 1 else [h, w]  # type: ignore[union-attr]
    want = list(view_hw) if view_hw is not None else full
    if not (isinstance(full, list) and full == want and full == [x for x in full if type(x) is int]):
        raise CodecError(f"residual full shape {full!r} is not its view's {want!r}")
    if [h, w] != [math.ceil(full[0] / scale), math.ceil(full[1] / scale)]:
        raise CodecError(f"residual shape {[h, w]!r} is not its full shape {full!r} at 1/{scale}")
    declared = coded_size(codec, payload)
    if declared != (w, h):
        raise CodecError(
            f"residual {codec} image declares {declared[0]}x{declared[1]} pixels, its view expects {w}x{h}"
        )


def decode_residual(payload: bytes, meta: dict) -> np.ndarray:
    """Inverse of :func:`encode_residual`: (H, W, 3) float32. Raises CodecError on bad data."""
    try:
        codec, (h, w) = meta["codec"], meta["shape"]
        gain, offset = np.float32(meta["gain"]), np.float32(meta["offset"])
    except (KeyError, TypeError, ValueError) as e:
        raise CodecError(f"residual metadata is incomplete: {e}") from None
    check_residual(payload, meta)
    try:
        q = _image_codec(codec).decode(payload)
    except Exception as e:  # imagecodecs raises its own per-codec error classes
        raise CodecError(f"residual {codec} payload does not decode: {e}") from None
    if q.ndim == 2:
        q = np.repeat(q[:, :, None], 3, axis=2)
    if q.shape[:2] != (h, w) or q.shape[2] < 3:
        raise CodecError(f"residual decodes to shape {q.shape}, expected {h}x{w}x3")
    if not gain > 0:
        raise CodecError(f"residual gain {float(gain)} is not positive")
    r = ((q[:, :, :3].astype(np.float32) - offset) / gain).astype(np.float32)
    factor = meta.get("scale", 1)
    if factor != 1:
        try:
            fh, fw = (int(v) for v in meta["full_shape"])
            factor = int(factor)
        except (KeyError, TypeError, ValueError) as e:
            raise CodecError(f"residual metadata has a bad scale or full_shape: {e}") from None
        if not (1 <= factor <= 16 and 0 < fh <= h * factor and 0 < fw <= w * factor):
            raise CodecError(f"residual scale {factor} does not fit shape {h}x{w} -> {fh}x{fw}")
        r = upsample(r, factor, fh, fw)
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
