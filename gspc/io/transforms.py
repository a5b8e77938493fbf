"""NeRF / instant-ngp ``transforms.json`` cameras, and image sizes read from image headers."""

from __future__ import annotations

import math
import os
import struct
import warnings
from pathlib import Path

import numpy as np

from gspc.cameras import Camera
from gspc.errors import InputError
from gspc.io.camera_common import check_rotation, frame_name, intrinsics_matrix, rigid_inverse

_GL_TO_CV = np.diag([1.0, -1.0, -1.0])


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) of a PNG or JPEG from its header, without decoding pixels."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(32)
            if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
                w, h = struct.unpack(">II", head[16:24])
                return int(w), int(h)
            if head[:2] == b"\xff\xd8":
                f.seek(2)
                return _jpeg_size(f, path)
    except OSError as e:
        raise InputError(f"image {path} cannot be read: {e}") from None
    except struct.error:  # a length field or the frame header runs past the end of the file
        raise InputError(f"image {path} is truncated before its size") from None
    raise InputError(f"image {path} is neither PNG nor JPEG; give width and height instead")


def _jpeg_size(f, path: Path) -> tuple[int, int]:
    while True:
        b = f.read(1)
        while b and b != b"\xff":
            b = f.read(1)
        while b == b"\xff":
            b = f.read(1)
        if not b:
            raise InputError(f"JPEG {path} has no frame header")
        marker = b[0]
        if marker in (0x01, 0xD8) or 0xD0 <= marker <= 0xD7:
            continue  # markers without a length field
        (length,) = struct.unpack(">H", f.read(2))
        if length < 2:  # the length counts its own two bytes; less would seek backwards forever
            raise InputError(f"JPEG {path} has a segment of length {length}")
        # SOF0-SOF15 carry the size; C4 (DHT), C8 (JPG) and CC (DAC) share the range but do not.
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            seg = f.read(5)
            h, w = struct.unpack(">HH", seg[1:5])
            return int(w), int(h)
        f.seek(length - 2, os.SEEK_CUR)


def _frame_image(root: Path, file_path: str) -> Path | None:
    p = root / file_path
    if p.suffix.lower() in (".png", ".jpg", ".jpeg") and p.is_file():
        return p
    for ext in (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG"):
        q = p.with_name(p.name + ext)
        if q.is_file():
            return q
    return p if p.is_file() else None


def _first_image_size(path: Path, file_path: str, width: int | None, height: int | None) -> tuple[int, int]:
    """Image size for a transforms.json that states none: the first frame's image, else the arguments."""
    img = _frame_image(path.parent, file_path)
    if img is None:
        if width is None:
            raise InputError(
                f"{path} states no image size and image {file_path!r} is missing; give width and height"
            )
        return width, height
    wh = image_size(img)
    if width is not None and wh != (width, height):
        raise InputError(f"image {img} is {wh[0]}x{wh[1]} but {width}x{height} was given")
    return wh


def _focal_from_angle(size: int, angle: object, path: Path, name: str, key: str) -> float:
    """Focal length in pixels from a field of view in radians, which must lie in (0, pi)."""
    a = float(angle)  # TypeError / ValueError: reported by the caller with the frame
    if not 0.0 < a < math.pi:
        raise InputError(
            f"{path}: frame {name!r} has {key} {a!r}; a field of view in radians lies in (0, pi)"
        )
    return 0.5 * size / math.tan(0.5 * a)


def parse_transforms(data: dict, path: Path, width: int | None, height: int | None) -> list[Camera]:
    frames = data["frames"]
    if not isinstance(frames, list) or not frames:
        raise InputError(f"{path}: 'frames' is empty or not a list")
    cams = []
    image_wh: tuple[int, int] | None = None  # size of the first image, read once if needed
    distortion = False
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict):
            raise InputError(f"{path}: frame {i} is not an object")
        if "transform_matrix" not in fr:
            raise InputError(f"{path}: frame {i} lacks key 'transform_matrix'")
        file_path = str(fr.get("file_path", ""))
        name = frame_name(file_path, i)

        def get(key, fr=fr):
            return fr[key] if key in fr else data.get(key)

        w, h = get("w"), get("h")
        if w is None or h is None:
            if image_wh is None:
                image_wh = _first_image_size(path, file_path, width, height)
            w, h = image_wh
        elif width is not None and (int(w), int(h)) != (width, height):
            raise InputError(f"{path}: frame {name!r} is {int(w)}x{int(h)} but {width}x{height} was given")
        try:
            w, h = int(w), int(h)
            if get("fl_x") is not None:
                fx = float(get("fl_x"))
                fy = float(get("fl_y")) if get("fl_y") is not None else fx
            elif get("camera_angle_x") is not None:
                fx = _focal_from_angle(w, get("camera_angle_x"), path, name, "camera_angle_x")
                cay = get("camera_angle_y")
                fy = _focal_from_angle(h, cay, path, name, "camera_angle_y") if cay is not None else fx
            else:
                raise InputError(f"{path}: frame {name!r} has no focal length (fl_x or camera_angle_x)")
            cx = float(get("cx")) if get("cx") is not None else w / 2
            cy = float(get("cy")) if get("cy") is not None else h / 2
            c2w = np.asarray(fr["transform_matrix"], dtype=np.float64)
            if c2w.shape == (3, 4):
                c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
            c2w = c2w.reshape(4, 4)
        except (TypeError, ValueError, OverflowError) as err:
            raise InputError(f"{path}: frame {i} ({name!r}) does not parse: {err}") from None
        try:
            distortion |= any(float(get(k) or 0.0) != 0.0 for k in ("k1", "k2", "k3", "k4", "p1", "p2"))
        except (TypeError, ValueError) as err:
            raise InputError(
                f"{path}: frame {i} ({name!r}) has a distortion term that is no number: {err}"
            ) from None
        R_gl = c2w[:3, :3]
        check_rotation(R_gl, f"{path}: frame {name!r}")
        cams.append(
            Camera(rigid_inverse(R_gl @ _GL_TO_CV, c2w[:3, 3]), intrinsics_matrix(fx, fy, cx, cy), w, h, name)
        )
    if distortion:
        warnings.warn(f"{path}: lens distortion is ignored; gspc uses the pinhole part only", stacklevel=3)
    return cams


# --- COLMAP sparse models ----------------------------------------------------------------------

# model id -> (name, number of parameters); the ids and counts are COLMAP's.
