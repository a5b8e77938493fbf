"""The side information of a file: the SIDE chunk's byte layout (spec 10.9) and the one reader of both
layouts, :func:`read_side_views`.

Format 1.0 stores each view as a msgpack map in the header (key strings, a name, a full camera and the
residual's parameters) and each residual as its own RESI chunk with a chunk-table entry: hundreds of bytes
per view before any image data (bench/pipeline.md, "Moved from code comments"). What varies between views
is the pose, the image length and the gain; the SIDE chunk states the rest once. Both layouts read to the same
:class:`SideViews`: typed view records (gspc/format/view_records.py) and the residual images by view number.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from gspc.errors import CodecError
from gspc.format.chunks import RESI, SIDE
from gspc.format.image_headers import coded_size
from gspc.format.view_records import (
    MAX_RESIDUAL_SCALE,
    RESIDUAL_BITS,
    RESIDUAL_CODECS,
    CameraRecord,
    ResidualRecord,
    ViewRecord,
    check_view_pixels,
)
from gspc.limits import RenderAllowance

FLAG_PER_VIEW_CAMERA = 1  # each view stores its own size and intrinsics

_HEAD = struct.Struct("<IBBBB")  # view count, flags, codec id, bits, scale
_CAMERA = struct.Struct("<II16s")  # width, height, intrinsics (4 x binary32: fx, fy, cx, cy)
_VIEW = struct.Struct("<48sI")  # pose (12 x binary32), image length
_GAIN = struct.Struct("<f")
MAX_VIEWS = 1 << 20


@dataclass(frozen=True)
class SideViews:
    """A file's side-information views and their residual images (view number -> image bytes)."""

    views: tuple[ViewRecord, ...] = ()
    images: dict[int, bytes] = field(default_factory=dict)


def _camera_key(camera: CameraRecord) -> tuple[int, int, bytes]:
    return camera.width, camera.height, camera.intrinsics


def pack_side(views: Sequence[ViewRecord], images: dict[int, bytes]) -> bytes:
    """Payload of a SIDE chunk for ``views`` and the residual ``images`` of those that carry one.

    Every residual must share one codec, bit depth and scale; the encoder makes them so (ValueError
    otherwise: a bug, not bad input).
    """
    if not views or len(views) > MAX_VIEWS:
        raise ValueError(f"a SIDE chunk holds 1..{MAX_VIEWS} views, got {len(views)}")
    if set(images) != {k for k, v in enumerate(views) if v.residual is not None}:
        raise ValueError("every view with a residual record needs an image, and only those")
    if not all(images.values()):
        raise ValueError("a residual image is empty (length 0 means 'no residual')")
    records = [v.residual for v in views if v.residual is not None]
    shared = {(r.codec, r.bits, r.scale) for r in records} or {("jxl", 8, 1)}
    if len(shared) != 1:
        raise ValueError("residuals of one file must share codec, bits and scale")
    codec, bits, scale = shared.pop()
    keys = {_camera_key(v.camera) for v in views}
    flags = FLAG_PER_VIEW_CAMERA if len(keys) > 1 else 0
    out = [_HEAD.pack(len(views), flags, RESIDUAL_CODECS.index(codec), bits, scale)]
    if not flags:
        out.append(_CAMERA.pack(*keys.pop()))
    for k, v in enumerate(views):
        if flags:
            out.append(_CAMERA.pack(*_camera_key(v.camera)))
        out.append(_VIEW.pack(v.camera.pose, len(images.get(k, b""))))
        if v.residual is not None:
            out.append(_GAIN.pack(v.residual.gain))
    out += [images[k] for k in sorted(images)]
    return b"".join(out)


def unpack_side(payload: bytes) -> SideViews:
    """Inverse of :func:`pack_side`. CodecError on bad data."""
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
    if codec_id >= len(RESIDUAL_CODECS) or bits not in RESIDUAL_BITS or not 1 <= scale <= MAX_RESIDUAL_SCALE:
        raise CodecError(f"SIDE chunk names codec {codec_id}, {bits} bits, scale {scale}: not allowed")
    shared = None if flags else take(_CAMERA)
    views: list[ViewRecord] = []
    lengths: list[int] = []
    for k in range(n):
        w, h, intrinsics = take(_CAMERA) if flags else shared
        pose, length = take(_VIEW)
        # Gains are refused here, not only when the image is decoded: decoding with --no-restore must not
        # accept a file that a restoring decoder refuses (spec 10.9).
        gain = take(_GAIN)[0] if length else None
        codec = RESIDUAL_CODECS[codec_id]
        views.append(_view(k, _side_view, w, h, intrinsics, pose, gain, codec, bits, scale))
        lengths.append(length)
    if pos + sum(lengths) != len(buf):
        raise CodecError(
            f"SIDE chunk images need {sum(lengths)} bytes after the view table, found {len(buf) - pos}"
        )
    images = {}
    for k, length in enumerate(lengths):
        if length:
            images[k] = bytes(buf[pos : pos + length])
            pos += length
    return SideViews(tuple(views), images)


def _side_view(
    w: int, h: int, intrinsics: bytes, pose: bytes, gain: float | None, codec: str, bits: int, scale: int
) -> ViewRecord:
    camera = CameraRecord(w, h, intrinsics, pose)
    residual = None if gain is None else ResidualRecord(codec, bits, gain, (h, w), scale)
    return ViewRecord(camera, residual)


def _view(k: int, build: Callable[..., ViewRecord], *args: object) -> ViewRecord:
    """``build(*args)``, with a CodecError naming side-information view ``k``."""
    try:
        return build(*args)
    except CodecError as err:
        raise CodecError(f"side-information view {k}: {err}") from None


def legacy_views(views: object) -> tuple[ViewRecord, ...]:
    """The 1.0 layout's ``side_info.views`` records (spec 10.8), typed and checked."""
    if not isinstance(views, list):
        raise CodecError(f"the .gspc header's side_info.views is {type(views).__name__}, not an array")
    return tuple(_view(k, ViewRecord.from_dict, v) for k, v in enumerate(views))


def read_side_views(legacy: tuple[ViewRecord, ...], chunks: list, file_size: int) -> SideViews:
    """The side-information views of a file of ``file_size`` bytes, from either layout: a 1.1 ``SIDE``
    chunk, or 1.0's ``legacy`` header records (the typed header's side_info.legacy_views) with one
    ``RESI`` chunk per view carrying a residual. Checks the views' pixels against the file's budget and
    each image's declared size against its record, before any camera is built or image decoded;
    CodecError when the two layouts are mixed or anything does not match."""
    res = {ch.index: ch.payload for ch in chunks if ch.type == RESI}
    packed = [ch for ch in chunks if ch.type == SIDE]
    if packed:
        if legacy or res:
            raise CodecError("the file holds side information both in a SIDE chunk and in the 1.0 form")
        if packed[0].index != 0:
            raise CodecError(f"chunk SIDE has index {packed[0].index}, not 0")
        side = unpack_side(packed[0].payload)
    else:
        with_res = {k for k, v in enumerate(legacy) if v.residual is not None}
        if set(res) != with_res:
            bad = sorted(set(res) ^ with_res)[0]
            raise CodecError(f"side-information view {bad} has a RESI chunk or a residual record, not both")
        side = SideViews(legacy, res)
    check_view_pixels(side.views, file_size)
    _check_images(side)
    return side


def read_tile_side(payload: bytes, budget: RenderAllowance) -> SideViews:
    """One tile's side information (a TSID payload, spec 10.15: the SIDE layout), its views' pixels checked
    against the tile's share of the file's budget and each image's declared size against its record."""
    side = unpack_side(payload)
    check_view_pixels(side.views, budget)
    _check_images(side)
    return side


def _check_images(side: SideViews) -> None:
    """Each residual image's declared size against its record, before any image is decoded."""
    for k, image in side.images.items():
        record = side.views[k].residual
        declared = coded_size(record.codec, image)
        rows, columns = record.shape
        if declared != (columns, rows):
            raise CodecError(
                f"side-information view {k}: residual {record.codec} image declares {declared[0]}x"
                f"{declared[1]} pixels, its record expects {columns}x{rows}"
            )
