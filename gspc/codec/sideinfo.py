"""The SIDE chunk: every side-information view's camera and residual image in one compact payload.

Format 1.0 stored each view as a msgpack map in the header (key strings, a name, a full camera and the
residual's parameters) and each residual as its own RESI chunk with a chunk-table entry: about 240 bytes
per view before any image data, 8.5 KB of a 206 KB lego file. What varies between views is the pose, the
image length and the gain; the rest is stated once here. Spec section 10.9 is the byte layout.

``pack_side`` and ``unpack_side`` convert between this payload and the pipeline's in-memory form: a list of
view records ``{"camera": Camera.to_dict(), "residual": meta}`` (``residual`` absent for views without an
image) and a dict {view number: image bytes}, the same form the 1.0 layout decodes to.
"""

from __future__ import annotations

import math
import struct

import numpy as np

from gspc.errors import CodecError
from gspc.format.chunks import RESI, SIDE
from gspc.limits import MAX_CAMERA_SIDE, MAX_TOTAL_PIXELS, MAX_VIEW_PIXELS

CODEC_IDS = {"jxl": 0, "webp": 1, "avif": 2}
CODEC_NAMES = {v: k for k, v in CODEC_IDS.items()}
FLAG_PER_VIEW_CAMERA = 1  # each view stores its own size and intrinsics

_HEAD = struct.Struct("<IBBBB")  # view count, flags, codec id, bits, scale
_CAMERA = struct.Struct("<II16s")  # width, height, intrinsics (4 x binary32: fx, fy, cx, cy)
_VIEW = struct.Struct("<48sI")  # pose (12 x binary32), image length
_GAIN = struct.Struct("<f")
MAX_VIEWS = 1 << 20
# Width, height and pixels of the views (spec 10.8): each limit's reason is in gspc/limits.py.
MAX_SIDE = MAX_CAMERA_SIDE


def _camera_key(camera: dict) -> tuple[int, int, bytes]:
    return int(camera["width"]), int(camera["height"]), bytes(camera["intrinsics"])


def pack_side(views: list[dict], images: dict[int, bytes]) -> bytes:
    """Payload of a SIDE chunk for ``views`` (records as above) and their residual ``images``.

    Every residual must share one codec, bit depth and scale and cover its camera's full image; the
    encoder makes them so (ValueError otherwise: a bug, not bad input).
    """
    if not views or len(views) > MAX_VIEWS:
        raise ValueError(f"a SIDE chunk holds 1..{MAX_VIEWS} views, got {len(views)}")
    if set(images) != {k for k, v in enumerate(views) if "residual" in v}:
        raise ValueError("every view with a residual record needs an image, and only those")
    if not all(images.values()):
        raise ValueError("a residual image is empty (length 0 means 'no residual')")
    metas = [v["residual"] for v in views if "residual" in v]
    first = metas[0] if metas else {"codec": "jxl", "bits": 8}
    codec, bits, scale = first["codec"], int(first["bits"]), int(first.get("scale", 1))
    for v in views:
        m = v.get("residual")
        if m is None:
            continue
        h, w = int(v["camera"]["height"]), int(v["camera"]["width"])
        if (m["codec"], m["bits"], int(m.get("scale", 1))) != (codec, bits, scale):
            raise ValueError("residuals of one file must share codec, bits and scale")
        if list(m.get("full_shape", m["shape"])) != [h, w] or list(m["shape"]) != _coded_shape(h, w, scale):
            raise ValueError("a residual must cover its camera's whole image")
        if m["offset"] != 1 << (bits - 1):
            raise ValueError("residual offset must be 2^(bits-1)")
    keys = {_camera_key(v["camera"]) for v in views}
    flags = FLAG_PER_VIEW_CAMERA if len(keys) > 1 else 0
    out = [_HEAD.pack(len(views), flags, CODEC_IDS[codec], bits, scale)]
    if not flags:
        out.append(_CAMERA.pack(*keys.pop()))
    for k, v in enumerate(views):
        cam = v["camera"]
        if flags:
            out.append(_CAMERA.pack(*_camera_key(cam)))
        out.append(_VIEW.pack(bytes(cam["pose"]), len(images.get(k, b""))))
        if k in images:
            out.append(_GAIN.pack(v["residual"]["gain"]))
    out += [images[k] for k in sorted(images)]
    return b"".join(out)


def _coded_shape(h: int, w: int, scale: int) -> list[int]:
    return [math.ceil(h / scale), math.ceil(w / scale)]


def unpack_side(payload: bytes) -> tuple[list[dict], dict[int, bytes]]:
    """Inverse of :func:`pack_side`: (view records, {view number: image bytes}). CodecError on bad data."""
    buf = memoryview(payload)
    pos = 0

    def take(s: struct.Struct) -> tuple:
        nonlocal pos
        if pos + s.size > len(buf):
            raise CodecError("SIDE chunk is truncated")
        vals = s.unpack_from(buf, pos)
        pos += s.size
        return vals

    n, flags, codec_id, bits, scale = take(_HEAD)
    if not 1 <= n <= MAX_VIEWS:
        raise CodecError(f"SIDE chunk has {n} views (allowed 1..{MAX_VIEWS})")
    if flags & ~FLAG_PER_VIEW_CAMERA:
        raise CodecError(f"SIDE chunk has unknown flags {flags:#x}")
    if codec_id not in CODEC_NAMES or bits not in (8, 16) or not 1 <= scale <= 16:
        raise CodecError(f"SIDE chunk names codec {codec_id}, {bits} bits, scale {scale}: not allowed")
    shared = None if flags else take(_CAMERA)
    views: list[dict] = []
    lengths: list[int] = []
    for _ in range(n):
        w, h, intr = take(_CAMERA) if flags else shared
        if not (1 <= w <= 1 << 16 and 1 <= h <= 1 << 16):
            raise CodecError(f"SIDE chunk has a {w}x{h} camera (allowed 1..65536 per side)")
        pose, length = take(_VIEW)
        cam = {"name": "", "width": w, "height": h, "intrinsics": intr, "pose": pose}
        if not np.isfinite(np.frombuffer(intr + pose, dtype="<f4")).all():
            raise CodecError("SIDE chunk has a camera with NaN or Inf values")
        record: dict = {"camera": cam}
        if length:
            (gain,) = take(_GAIN)
            # Refused here, not only when the image is decoded: decoding with --no-restore must not
            # accept a file that a restoring decoder refuses (spec 10.9).
            if not (math.isfinite(gain) and gain > 0):
                raise CodecError(f"SIDE chunk view {len(views)} has gain {gain}, not positive and finite")
            meta = {
                "codec": CODEC_NAMES[codec_id],
                "shape": _coded_shape(h, w, scale),
                "bits": bits,
                "gain": gain,
                "offset": 1 << (bits - 1),
            }
            if scale != 1:
                meta.update(scale=scale, full_shape=[h, w])
            record["residual"] = meta
        views.append(record)
        lengths.append(length)
    _check_views(views)
    if pos + sum(lengths) != len(buf):
        raise CodecError(
            f"SIDE chunk images need {sum(lengths)} bytes after the view table, found {len(buf) - pos}"
        )
    images = {}
    for k, length in enumerate(lengths):
        if length:
            images[k] = bytes(buf[pos : pos + length])
            pos += length
    return views, images


def _check_residual_record(k: int, m: object, h: int, w: int) -> None:
    """A residual record (spec 10.7) that covers its camera's image, with a positive finite gain."""
    try:
        scale = m.get("scale", 1)
        ok = (
            m["codec"] in CODEC_IDS
            and m["bits"] in (8, 16)
            and m["offset"] == 1 << (m["bits"] - 1)
            and isinstance(scale, int)
            and 1 <= scale <= 16
            and list(m.get("full_shape", m["shape"])) == [h, w]
            and list(m["shape"]) == _coded_shape(h, w, scale)
        )
        gain = m["gain"]
    except (AttributeError, KeyError, TypeError):
        ok, gain = False, None
    if not ok:
        raise CodecError(f"side-information view {k} has a residual record that does not fit its camera")
    # Checked as the binary32 value R is divided by (spec 10.7): 1e-50 would round to 0 and 1e39 to infinity.
    if not (isinstance(gain, float) and 2.0**-150 < gain < 2.0**128 - 2.0**103):
        raise CodecError(f"side-information view {k} has gain {gain!r}, not a positive finite float")


def _check_views(views: list[dict]) -> None:
    """Camera sizes, pixel totals and gains of either layout (spec 10.7-10.9), before anything is rendered."""
    total = 0
    for k, v in enumerate(views):
        cam = v.get("camera") if isinstance(v, dict) else None
        w, h = (cam.get("width"), cam.get("height")) if isinstance(cam, dict) else (None, None)
        ok = all(isinstance(x, int) and not isinstance(x, bool) and 1 <= x <= MAX_SIDE for x in (w, h))
        if not ok:
            raise CodecError(f"side-information view {k} has a camera size {w}x{h} outside 1..{MAX_SIDE}")
        if w * h > MAX_VIEW_PIXELS:
            raise CodecError(f"side-information view {k} has {w * h} pixels (limit {MAX_VIEW_PIXELS})")
        total += w * h
        if "residual" in v:
            _check_residual_record(k, v["residual"], h, w)
    if total > MAX_TOTAL_PIXELS:
        raise CodecError(f"side-information views have {total} pixels together (limit {MAX_TOTAL_PIXELS})")


def side_views(side: dict, chunks: list) -> tuple[list[dict], dict[int, bytes]]:
    """The side-information views of a file, from either layout: a 1.1 ``SIDE`` chunk, or 1.0's
    ``side_info.views`` records with one ``RESI`` chunk per view. ``side`` is ``meta["side_info"]``,
    ``chunks`` the container's chunks. CodecError when the two forms are mixed or do not match.
    """
    if not isinstance(side, dict):
        raise CodecError("side_info is not a map")
    views = side.get("views", [])
    if not isinstance(views, list):
        raise CodecError("side_info.views is not an array")
    res = {ch.index: ch.payload for ch in chunks if ch.type == RESI}
    packed = [ch for ch in chunks if ch.type == SIDE]
    if packed:
        if views or res:
            raise CodecError("the file holds side information both in a SIDE chunk and in the 1.0 form")
        if packed[0].index != 0:
            raise CodecError(f"chunk SIDE has index {packed[0].index}, not 0")
        return unpack_side(packed[0].payload)
    with_res = {k for k, v in enumerate(views) if isinstance(v, dict) and "residual" in v}
    if set(res) != with_res:
        bad = sorted(set(res) ^ with_res)[0]
        raise CodecError(f"side-information view {bad} has a RESI chunk or a residual record, not both")
    _check_views(views)
    return views, res
