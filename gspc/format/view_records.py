"""The side information's records (spec 10.7-10.9) as typed, frozen values: a :class:`ViewRecord` per view,
its :class:`CameraRecord` and, where the view carries one, its :class:`ResidualRecord`.

Both layouts of a file (1.0's msgpack maps, 1.1's SIDE chunk: gspc/format/side_chunk.py) and the encoder
build these records, and each field is checked once, in the record's ``__post_init__`` (``from_dict``
checks only the msgpack types of the 1.0 maps). The pixel limits that depend on the file's size are
:func:`check_view_pixels`. CodecError names the view and the field.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from gspc.errors import CodecError
from gspc.limits import (
    MAX_CAMERA_SIDE,
    MAX_TOTAL_PIXELS,
    MAX_VIEW_PIXELS,
    PIXEL_FLOOR,
    PIXELS_PER_FILE_BYTE,
    RenderAllowance,
    allowance,
)

# The residual image codecs a file may name; a SIDE chunk stores the position in this tuple (spec 10.9).
RESIDUAL_CODECS: tuple[str, ...] = ("jxl", "webp", "avif")
RESIDUAL_BITS = (8, 16)
# Residuals may be coded at 1/s resolution for s in 1..16: the SIDE chunk's scale field (spec 10.7, 10.9);
# beyond 16 a residual of a 4096-pixel view has under 256 pixels a side, too few to carry anything.
MAX_RESIDUAL_SCALE = 16
if TYPE_CHECKING:
    from gspc.cameras import Camera

_INTRINSICS_BYTES, _POSE_BYTES = 16, 48  # 4 and 12 binary32 (spec 10.8)


def _show(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_int(v: object) -> bool:
    return type(v) is int  # bool is an int subclass but not a msgpack integer


def coded_shape(height: int, width: int, scale: int) -> tuple[int, int]:
    """(rows, columns) of a residual image coded at 1/``scale`` of a ``height`` x ``width`` view."""
    return math.ceil(height / scale), math.ceil(width / scale)


@dataclass(frozen=True)
class CameraRecord:
    """A stored camera (spec 10.8): size, binary32 intrinsics (fx, fy, cx, cy) and pose (the top three rows
    of world-to-camera) as the file holds them; ``gspc.cameras.Camera.from_dict(record.to_dict())`` renders
    with them."""

    width: int
    height: int
    intrinsics: bytes
    pose: bytes
    name: str = ""

    def __post_init__(self) -> None:
        for side, v in (("width", self.width), ("height", self.height)):
            if not (_is_int(v) and 1 <= v <= MAX_CAMERA_SIDE):
                raise CodecError(f"camera {side} {_show(v)} is not an integer in 1..{MAX_CAMERA_SIDE}")
        if not (isinstance(self.intrinsics, bytes) and len(self.intrinsics) == _INTRINSICS_BYTES):
            raise CodecError(f"camera intrinsics {_show(self.intrinsics)} are not {_INTRINSICS_BYTES} bytes")
        if not (isinstance(self.pose, bytes) and len(self.pose) == _POSE_BYTES):
            raise CodecError(f"camera pose {_show(self.pose)} is not {_POSE_BYTES} bytes")
        if not all(math.isfinite(x) for x in struct.unpack("<16f", self.intrinsics + self.pose)):
            raise CodecError("camera has NaN or Inf values")
        fx, fy = struct.unpack("<2f", self.intrinsics[:8])
        if not (fx > 0 and fy > 0):  # a pinhole camera divides by them (spec 10.8), read or not
            raise CodecError(f"camera focal lengths fx={fx:g}, fy={fy:g}; both must be > 0")

    @property
    def pixels(self) -> int:
        return self.width * self.height

    def to_dict(self) -> dict:
        """The form gspc.cameras.Camera.from_dict reads (and the 1.0 layout stored)."""
        return {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "intrinsics": self.intrinsics,
            "pose": self.pose,
        }

    @classmethod
    def from_camera(cls, camera: Camera) -> CameraRecord:
        """A camera as the file stores it (binary32): what the encoder renders with and the decoder reads."""
        d = camera.to_dict()
        return cls(d["width"], d["height"], d["intrinsics"], d["pose"], d["name"])

    def to_camera(self) -> Camera:
        from gspc.cameras import Camera  # numpy: not needed to read a header

        return Camera.from_dict(self.to_dict())

    @classmethod
    def from_dict(cls, cam: object) -> CameraRecord:
        if not isinstance(cam, dict):
            raise CodecError(f"camera {_show(cam)} is not a map")
        try:
            name, width, height = cam.get("name", ""), cam["width"], cam["height"]
            intrinsics, pose = cam["intrinsics"], cam["pose"]
        except KeyError as err:
            raise CodecError(f"camera lacks {err}") from None
        return cls(width, height, intrinsics, pose, str(name))


@dataclass(frozen=True)
class ResidualRecord:
    """How one view's residual image is coded (spec 10.7): image ``codec``, sample ``bits``, the binary32
    ``gain`` (samples ``u`` decode to ``(u - offset) / gain``), the ``full_shape`` (rows, columns) of its
    view and the ``scale`` it was coded at (the image is ``shape`` = full_shape / scale, rounded up)."""

    codec: str
    bits: int
    gain: float
    full_shape: tuple[int, int]
    scale: int = 1
    zeroed_tiles: int = field(default=0, compare=False)  # informative: tiles the encoder zeroed

    def __post_init__(self) -> None:
        if self.codec not in RESIDUAL_CODECS:
            raise CodecError(f"residual codec {_show(self.codec)} is not one of {', '.join(RESIDUAL_CODECS)}")
        if not (_is_int(self.bits) and self.bits in RESIDUAL_BITS):
            raise CodecError(f"residual bits {_show(self.bits)} are not 8 or 16")
        if not (_is_int(self.scale) and 1 <= self.scale <= MAX_RESIDUAL_SCALE):
            raise CodecError(
                f"residual scale {_show(self.scale)} is not an integer in 1..{MAX_RESIDUAL_SCALE}"
            )
        # Checked as the binary32 value R is divided by (spec 10.7): 1e-50 would round to 0, 1e39 to infinity.
        if not (type(self.gain) is float and 2.0**-150 < self.gain < 2.0**128 - 2.0**103):
            raise CodecError(f"residual gain {_show(self.gain)} is not a positive finite float")

    @property
    def offset(self) -> int:
        return 1 << (self.bits - 1)

    @property
    def shape(self) -> tuple[int, int]:
        return coded_shape(*self.full_shape, self.scale)

    def to_dict(self) -> dict:
        """The 1.0 layout's map (spec 10.7)."""
        out: dict = {
            "codec": self.codec,
            "shape": list(self.shape),
            "bits": self.bits,
            "gain": self.gain,
            "offset": self.offset,
        }
        if self.zeroed_tiles:
            out["zeroed_tiles"] = self.zeroed_tiles
        if self.scale != 1:
            out.update(scale=self.scale, full_shape=list(self.full_shape))
        return out

    @classmethod
    def from_dict(cls, m: object, camera: CameraRecord) -> ResidualRecord:
        """A 1.0 layout's residual map for a view of ``camera``: it must cover the camera's whole image."""
        if not isinstance(m, dict):
            raise CodecError(f"residual record {_show(m)} is not a map")
        try:
            codec, bits, gain, shape, offset = m["codec"], m["bits"], m["gain"], m["shape"], m["offset"]
        except KeyError as err:
            raise CodecError(f"residual record lacks {err}") from None
        full = [camera.height, camera.width]
        record = cls(codec, bits, gain, (camera.height, camera.width), m.get("scale", 1))
        if not (_is_int(offset) and offset == record.offset):
            raise CodecError(f"residual offset {_show(offset)} is not 2^(bits - 1) = {record.offset}")
        if m.get("full_shape", full) != full or shape != list(record.shape):
            raise CodecError(
                f"residual shape {_show(shape)} (full shape {_show(m.get('full_shape', full))}) does not "
                f"cover its {camera.width}x{camera.height} camera at 1/{record.scale}"
            )
        return record


@dataclass(frozen=True)
class ViewRecord:
    """One side-information view: a camera, and the residual record where the view carries an image."""

    camera: CameraRecord
    residual: ResidualRecord | None = None

    def __post_init__(self) -> None:
        if self.residual is not None and self.residual.full_shape != (self.camera.height, self.camera.width):
            raise CodecError(
                f"residual of full shape {list(self.residual.full_shape)} does not cover its "
                f"{self.camera.width}x{self.camera.height} camera"
            )

    def to_dict(self) -> dict:
        out: dict = {"camera": self.camera.to_dict()}
        if self.residual is not None:
            out["residual"] = self.residual.to_dict()
        return out

    @classmethod
    def from_dict(cls, v: object) -> ViewRecord:
        """A 1.0 layout's ``side_info.views`` entry (spec 10.8)."""
        if not isinstance(v, dict):
            raise CodecError(f"view {_show(v)} is not a map")
        camera = CameraRecord.from_dict(v.get("camera"))
        residual = ResidualRecord.from_dict(v["residual"], camera) if "residual" in v else None
        return cls(camera, residual)


def check_view_pixels(
    views: tuple[ViewRecord, ...] | list[ViewRecord], file_size: int | RenderAllowance
) -> None:
    """Each view's pixels, and all views' together, against gspc/limits.py (a file's budget for its size, or
    a tile's share: RenderAllowance): the decoder renders and keeps every view, so a small file must not ask
    for gigapixels. Run before any camera is built or rendered."""
    total = 0
    for k, v in enumerate(views):
        if v.camera.pixels > MAX_VIEW_PIXELS:
            raise CodecError(
                f"side-information view {k} is {v.camera.width}x{v.camera.height} = {v.camera.pixels:,} "
                f"pixels; the limit is {MAX_VIEW_PIXELS:,}"
            )
        total += v.camera.pixels
    budget = allowance(file_size)
    if total > budget.pixels:
        raise CodecError(
            f"side-information views ask for {total:,} pixels in {budget.of}; the limit is {budget.pixels:,} "
            f"(max({PIXEL_FLOOR:,}, {PIXELS_PER_FILE_BYTE} per file byte), at most {MAX_TOTAL_PIXELS:,}; "
            f"{budget.rule})"
        )
