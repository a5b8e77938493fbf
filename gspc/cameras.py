"""Camera: a pinhole camera in OpenCV convention (x right, y down, z forward).

Kept as float64 numpy so cameras serialise exactly (container header, cameras.json); the
renderer converts to the scene's dtype and device.
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import numpy as np

from gspc.atomic import atomic_write_bytes
from gspc.errors import InputError
from gspc.limits import MAX_CAMERA_SIDE


@dataclass
class Camera:
    world_to_cam: np.ndarray  # (4, 4) float64
    K: np.ndarray  # (3, 3) float64 intrinsics: fx, fy, cx, cy
    width: int
    height: int
    name: str = ""

    def __post_init__(self) -> None:
        self.world_to_cam = np.asarray(self.world_to_cam, dtype=np.float64).reshape(4, 4)
        self.K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        try:
            self.width, self.height = int(self.width), int(self.height)
        except (TypeError, ValueError, OverflowError):  # NaN, Inf, strings
            raise InputError(f"camera {self.name!r} has size {self.width!r}x{self.height!r}") from None
        if not (0 < self.width <= MAX_CAMERA_SIDE and 0 < self.height <= MAX_CAMERA_SIDE):
            raise InputError(
                f"camera {self.name!r} has size {self.width}x{self.height}; each side must be in "
                f"1..{MAX_CAMERA_SIDE}"
            )
        if not (np.isfinite(self.world_to_cam).all() and np.isfinite(self.K).all()):
            raise InputError(f"camera {self.name!r} has NaN or Inf in its matrices")
        # Projection divides by the focal lengths (gspc/render/project.py); zero or negative ones are no
        # pinhole camera.
        if not (self.K[0, 0] > 0 and self.K[1, 1] > 0):
            raise InputError(
                f"camera {self.name!r} has focal lengths fx={self.fx:g}, fy={self.fy:g}; both must be > 0"
            )

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates."""
        R, t = self.world_to_cam[:3, :3], self.world_to_cam[:3, 3]
        return -R.T @ t

    def scaled(self, factor: float) -> Camera:
        """The same view at ``factor`` times the resolution (intrinsics scaled to match)."""
        w, h = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        K = self.K.copy()
        K[0] *= w / self.width
        K[1] *= h / self.height
        return Camera(self.world_to_cam.copy(), K, w, h, self.name)

    def to_dict(self) -> dict:
        """Compact msgpack form for the container header (spec 10.8): binary32, little-endian.

        ``intrinsics`` = fx, fy, cx, cy (zero skew); ``pose`` = the top 3 rows of world_to_cam, row-major.
        The encoder renders with ``Camera.from_dict(cam.to_dict())`` so both sides see the same camera.
        """
        K = self.K
        intr = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dtype="<f4")
        return {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "intrinsics": intr.tobytes(),
            "pose": self.world_to_cam[:3].astype("<f4").tobytes(),
        }

    @staticmethod
    def from_dict(d: dict) -> Camera:
        try:
            fx, fy, cx, cy = np.frombuffer(d["intrinsics"], dtype="<f4", count=4).astype(np.float64)
            pose = np.frombuffer(d["pose"], dtype="<f4", count=12).astype(np.float64).reshape(3, 4)
            K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
            w2c = np.vstack([pose, [0.0, 0.0, 0.0, 1.0]])
            return Camera(w2c, K, d["width"], d["height"], str(d.get("name", "")))
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as e:
            raise InputError(f"camera record does not parse: {type(e).__name__}: {e}") from None


# ---------------------------------------------------------------------------
# Loading and saving camera sets
# ---------------------------------------------------------------------------

_NAME_PARTS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple:
    """Sort key that orders embedded numbers by value, so ``r_2`` comes before ``r_10``."""
    parts = _NAME_PARTS.split(name)
    # re.split with a capture group alternates text, number, text, ...: types line up between keys.
    return tuple(int(p) if i % 2 else p.lower() for i, p in enumerate(parts)) + (name,)


def sort_cameras(cameras: Sequence[Camera]) -> list[Camera]:
    """Cameras in natural order of their names (the order every gspc tool works in)."""
    return sorted(cameras, key=lambda c: natural_key(c.name))


def _read_json(path: Path):
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"camera file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"camera file {path} cannot be read: {e}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"camera file {path} is not valid JSON: {e}") from None


def load_cameras(path: str | Path, width: int | None = None, height: int | None = None) -> list[Camera]:
    """Cameras from an INRIA ``cameras.json``, a NeRF/instant-ngp ``transforms.json`` or a COLMAP
    sparse model (a folder with cameras/images as .txt or .bin), sorted by name (natural order).

    ``width``/``height`` give the image size for a transforms.json that states none and has no
    readable first image; where the file or image states a size, they must agree with it.
    """
    path = Path(path)
    if (width is None) != (height is None):
        raise InputError("give both width and height, or neither")
    if path.is_dir():
        for sub in (path, path / "sparse" / "0", path / "sparse"):
            if _colmap_files(sub) is not None:
                return sort_cameras(_load_colmap(sub))
        for name in ("cameras.json", "transforms.json"):
            if (path / name).is_file():
                return load_cameras(path / name, width, height)
        raise InputError(f"{path} holds no cameras.json, transforms.json or COLMAP cameras/images files")
    if path.name in ("cameras.bin", "images.bin", "cameras.txt", "images.txt"):
        return sort_cameras(_load_colmap(path.parent))
    if not path.exists():
        raise InputError(f"camera file {path} does not exist")
    data = _read_json(path)
    if isinstance(data, list):
        cams = _parse_inria(data, path)
    elif isinstance(data, dict) and "frames" in data:
        cams = _parse_transforms(data, path, width, height)
    else:
        raise InputError(
            f"{path} is neither an INRIA cameras.json (a list) nor a transforms.json (with 'frames')"
        )
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise InputError(f"{path} names image {dup!r} more than once")
    return sort_cameras(cams)


def _intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def _rigid_inverse(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 inverse of x -> R x + t for a rotation R."""
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def _check_rotation(R: np.ndarray, what: str) -> None:
    if not np.isfinite(R).all():
        raise InputError(f"{what} has NaN or Inf in its rotation")
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        raise InputError(f"{what} has a rotation that is not orthonormal and right-handed")


def _parse_inria(entries: list, path: Path) -> list[Camera]:
    cams = []
    for i, e in enumerate(entries):
        if not isinstance(e, dict):
            raise InputError(f"{path}: entry {i} is not an object")
        for key in ("width", "height", "position", "rotation", "fx", "fy"):
            if key not in e:
                raise InputError(f"{path}: entry {i} lacks key {key!r}")
        name = str(e.get("img_name", e.get("id", i)))
        try:
            R_c2w = np.asarray(e["rotation"], dtype=np.float64).reshape(3, 3)
            pos = np.asarray(e["position"], dtype=np.float64).reshape(3)
            w, h = int(e["width"]), int(e["height"])
            # INRIA's file has no principal point (its renderer assumes the centre); ours may add one.
            K = _intrinsics(
                float(e["fx"]), float(e["fy"]), float(e.get("cx", w / 2)), float(e.get("cy", h / 2))
            )
        except (TypeError, ValueError, OverflowError) as err:
            raise InputError(f"{path}: entry {i} ({name!r}) does not parse: {err}") from None
        _check_rotation(R_c2w, f"{path}: camera {name!r}")
        cams.append(Camera(_rigid_inverse(R_c2w, pos), K, w, h, name))
    if not cams:
        raise InputError(f"{path} lists no cameras")
    return cams


def save_cameras_json(cameras: Sequence[Camera], path: str | Path) -> None:
    """Write cameras in INRIA's cameras.json layout (plus ``cx``/``cy``, which INRIA's tools ignore)."""
    records = []
    for i, cam in enumerate(cameras):
        R = cam.world_to_cam[:3, :3]
        records.append(
            {
                "id": i,
                "img_name": cam.name,
                "width": cam.width,
                "height": cam.height,
                "position": [float(v) for v in cam.center],
                "rotation": [[float(v) for v in row] for row in R.T],
                "fy": cam.fy,
                "fx": cam.fx,
                "cx": cam.cx,
                "cy": cam.cy,
            }
        )
    atomic_write_bytes(path, json.dumps(records, indent=1).encode("utf-8"))


# --- NeRF / instant-ngp / nerfstudio transforms.json -------------------------------------------

# OpenGL/Blender camera axes (x right, y up, z backward) to OpenCV (x right, y down, z forward).
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


def _frame_name(file_path: str, index: int) -> str:
    if not file_path:
        return f"frame_{index:05d}"
    name = PurePosixPath(file_path.replace("\\", "/")).name
    for ext in (".png", ".jpg", ".jpeg", ".exr", ".webp"):
        if name.lower().endswith(ext):
            return name[: -len(ext)]
    return name


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


def _parse_transforms(data: dict, path: Path, width: int | None, height: int | None) -> list[Camera]:
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
        name = _frame_name(file_path, i)

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
        _check_rotation(R_gl, f"{path}: frame {name!r}")
        cams.append(
            Camera(_rigid_inverse(R_gl @ _GL_TO_CV, c2w[:3, 3]), _intrinsics(fx, fy, cx, cy), w, h, name)
        )
    if distortion:
        warnings.warn(f"{path}: lens distortion is ignored; gspc uses the pinhole part only", stacklevel=3)
    return cams


# --- COLMAP sparse models ----------------------------------------------------------------------

# model id -> (name, number of parameters); the ids and counts are COLMAP's.
_COLMAP_MODELS = {
    0: ("SIMPLE_PINHOLE", 3),
    1: ("PINHOLE", 4),
    2: ("SIMPLE_RADIAL", 4),
    3: ("RADIAL", 5),
    4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8),
    6: ("FULL_OPENCV", 12),
    7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5),
    10: ("THIN_PRISM_FISHEYE", 12),
}
_COLMAP_BY_NAME = {name: (mid, n) for mid, (name, n) in _COLMAP_MODELS.items()}
# Models whose first parameters are a pinhole (f or fx, fy, then cx, cy) plus radial/tangential terms.
_SINGLE_F = ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL")
_DOUBLE_F = ("PINHOLE", "OPENCV", "FULL_OPENCV")


def _colmap_files(d: Path) -> tuple[Path, Path] | None:
    for ext in (".bin", ".txt"):
        c, i = d / f"cameras{ext}", d / f"images{ext}"
        if c.is_file() and i.is_file():
            return c, i
    return None


def _load_colmap(d: Path) -> list[Camera]:
    files = _colmap_files(d)
    if files is None:
        raise InputError(f"{d} lacks a pair of COLMAP cameras/images files (.bin or .txt)")
    cam_file, img_file = files
    try:
        if cam_file.suffix == ".bin":
            intr = _colmap_cameras_bin(cam_file.read_bytes())
            images = _colmap_images_bin(img_file.read_bytes())
        else:
            intr = _colmap_cameras_txt(cam_file.read_text(encoding="utf-8"))
            images = _colmap_images_txt(img_file.read_text(encoding="utf-8"))
    except (struct.error, ValueError, IndexError, UnicodeDecodeError) as e:
        raise InputError(f"COLMAP model in {d} does not parse: {e}") from None
    cams, distorted = [], set()
    for cam_id, q, t, name in images:
        if cam_id not in intr:
            raise InputError(f"COLMAP image {name!r} refers to camera {cam_id}, which {cam_file} lacks")
        model, w, h, params = intr[cam_id]
        if model in _SINGLE_F:
            fx = fy = params[0]
            cx, cy, rest = params[1], params[2], params[3:]
        elif model in _DOUBLE_F:
            fx, fy, cx, cy, rest = params[0], params[1], params[2], params[3], params[4:]
        else:
            raise InputError(f"COLMAP camera model {model} is not supported (pinhole-like models only)")
        if any(v != 0.0 for v in rest):
            distorted.add(model)
        q = np.asarray(q, dtype=np.float64)
        if not np.linalg.norm(q) > 0:
            raise InputError(f"COLMAP image {name!r} has a zero quaternion")
        w2c = np.eye(4)
        w2c[:3, :3] = _quat_to_rot(q / np.linalg.norm(q))
        w2c[:3, 3] = t
        cams.append((name, Camera(w2c, _intrinsics(fx, fy, cx, cy), w, h, name)))
    if not cams:
        raise InputError(f"COLMAP model in {d} lists no images")
    if distorted:
        warnings.warn(
            f"COLMAP cameras of model {', '.join(sorted(distorted))} have lens distortion; gspc uses their "
            "pinhole part only (undistort the images for exact results)",
            stacklevel=3,
        )
    return _names_from_paths(cams)


def _names_from_paths(named: list[tuple[str, Camera]]) -> list[Camera]:
    """Name cameras by image file stem (as 3DGS does); keep folders if stems collide."""
    stems = [_frame_name(n, i) for i, (n, _) in enumerate(named)]
    if len(set(stems)) != len(stems):
        stems = [str(PurePosixPath(n).with_suffix("")) for n, _ in named]
        if len(set(stems)) != len(stems):
            raise InputError("COLMAP model names the same image more than once")
    for s, (_, cam) in zip(stems, named, strict=True):
        cam.name = s
    return [cam for _, cam in named]


def _quat_to_rot(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _data_lines(text: str) -> list[str]:
    return [ln.strip() for ln in text.splitlines() if not ln.lstrip().startswith("#")]


def _colmap_cameras_txt(text: str) -> dict:
    out = {}
    for ln in _data_lines(text):
        if not ln:
            continue
        tok = ln.split()
        model = tok[1]
        if model not in _COLMAP_BY_NAME:
            raise InputError(f"COLMAP camera model {model!r} is unknown")
        params = [float(v) for v in tok[4:]]
        if len(params) != _COLMAP_BY_NAME[model][1]:
            raise InputError(f"COLMAP camera {tok[0]} ({model}) has {len(params)} parameters")
        out[int(tok[0])] = (model, int(tok[2]), int(tok[3]), params)
    return out


def _colmap_images_txt(text: str) -> list:
    lines = _data_lines(text)
    out, i = [], 0
    while i < len(lines):
        if not lines[i]:
            i += 1
            continue
        tok = lines[i].split()
        if len(tok) < 10:
            raise InputError(f"COLMAP images.txt line {lines[i][:40]!r} has fewer than 10 fields")
        q = [float(v) for v in tok[1:5]]
        t = [float(v) for v in tok[5:8]]
        # The name may contain spaces; the line after each image lists its 2D points (maybe empty).
        out.append((int(tok[8]), q, t, " ".join(tok[9:])))
        i += 2
    return out


def _colmap_cameras_bin(buf: bytes) -> dict:
    (n,), off, out = struct.unpack_from("<Q", buf, 0), 8, {}
    for _ in range(n):
        cam_id, model_id, w, h = struct.unpack_from("<iiQQ", buf, off)
        off += 24
        if model_id not in _COLMAP_MODELS:
            raise InputError(f"COLMAP camera model id {model_id} is unknown")
        model, k = _COLMAP_MODELS[model_id]
        params = list(struct.unpack_from(f"<{k}d", buf, off))
        off += 8 * k
        out[cam_id] = (model, w, h, params)
    return out


def _colmap_images_bin(buf: bytes) -> list:
    (n,), off, out = struct.unpack_from("<Q", buf, 0), 8, []
    for _ in range(n):
        vals = struct.unpack_from("<i7di", buf, off)
        off += 64
        end = buf.index(b"\x00", off)
        name = buf[off:end].decode("utf-8")
        off = end + 1
        (npts,) = struct.unpack_from("<Q", buf, off)
        off += 8 + 24 * npts  # skip the 2D points: x, y (double), point3D id (int64)
        if off > len(buf):
            raise InputError("COLMAP images.bin is truncated")
        out.append((vals[8], vals[1:5], vals[5:8], name))
    return out


def load_colmap_points(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The sparse points of a COLMAP model (a folder holding points3D.bin or .txt, or its parent with
    sparse/0): positions (P, 3) float64 and colours (P, 3) uint8. Fitting tools start from them."""
    path = Path(path)
    for d in (path, path / "sparse" / "0", path / "sparse"):
        for ext in (".bin", ".txt"):
            f = d / f"points3D{ext}"
            if f.is_file():
                try:
                    if ext == ".bin":
                        return _colmap_points_bin(f.read_bytes())
                    return _colmap_points_txt(f.read_text(encoding="utf-8"))
                except (struct.error, ValueError, IndexError, UnicodeDecodeError) as e:
                    raise InputError(f"COLMAP points in {f} do not parse: {e}") from None
    raise InputError(f"{path} holds no COLMAP points3D.bin or points3D.txt")


def _colmap_points_bin(buf: bytes) -> tuple[np.ndarray, np.ndarray]:
    (n,), off = struct.unpack_from("<Q", buf, 0), 8
    if n > len(buf) // 51:  # each point takes at least 51 bytes: refuse before allocating
        raise InputError(f"COLMAP points3D.bin declares {n} points in {len(buf)} bytes")
    xyz, rgb = np.empty((n, 3)), np.empty((n, 3), dtype=np.uint8)
    for i in range(n):
        # id, x, y, z, r, g, b, reprojection error, track length; then the track (image id, point2D id).
        vals = struct.unpack_from("<Q3d3BdQ", buf, off)
        xyz[i], rgb[i] = vals[1:4], vals[4:7]
        off += 51 + 8 * vals[8]
    if off > len(buf):
        raise InputError("COLMAP points3D.bin is truncated")
    return xyz, rgb


def _colmap_points_txt(text: str) -> tuple[np.ndarray, np.ndarray]:
    rows = [ln.split() for ln in _data_lines(text) if ln]
    xyz = np.array([[float(v) for v in r[1:4]] for r in rows], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([[int(v) for v in r[4:7]] for r in rows], dtype=np.uint8).reshape(-1, 3)
    return xyz, rgb


# ---------------------------------------------------------------------------
# Views for scenes that come without cameras; sampling and splits
# ---------------------------------------------------------------------------


CORE_DISTANCES = 6.0


def robust_bounds(scene, quantile: float = 0.002, min_opacity: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box (lo, hi) holding the bulk of a scene's visible Gaussians.

    Gaussians beyond the scene's core (a background, far floaters) and below ``min_opacity`` are
    ignored (unless that leaves too few), and the rest weigh by opacity into per-axis ``quantile`` /
    ``1 - quantile`` quantiles, so sparse floaters do not stretch the box.
    """
    means = scene.means.detach().cpu().double().numpy().reshape(-1, 3)
    if len(means) == 0:
        raise InputError("scene has zero Gaussians")
    alpha = 1.0 / (1.0 + np.exp(-scene.opacities.detach().cpu().double().numpy().reshape(-1)))
    # A capture's background shell and far floaters can be far more than `quantile` of the Gaussians: keep
    # only those within CORE_DISTANCES median distances of the median, the region the position codec keeps
    # uncontracted (gspc/codec/positions.py). Bounded objects lie wholly inside (statues reach 4.2).
    dist = np.sqrt(((means - np.median(means, axis=0)) ** 2).sum(1))
    core = dist <= CORE_DISTANCES * np.median(dist) if np.median(dist) > 0 else np.ones(len(means), bool)
    means, alpha = means[core], alpha[core]
    keep = alpha >= min_opacity
    if keep.sum() < max(1, 0.01 * len(means)):
        keep[:] = True
    means, alpha = means[keep], np.maximum(alpha[keep], 1e-6)
    lo, hi = np.empty(3), np.empty(3)
    for d in range(3):
        order = np.argsort(means[:, d], kind="stable")
        cw = np.cumsum(alpha[order])
        cw /= cw[-1]
        lo[d] = means[order[min(np.searchsorted(cw, quantile), len(cw) - 1)], d]
        hi[d] = means[order[min(np.searchsorted(cw, 1.0 - quantile), len(cw) - 1)], d]
    return lo, hi


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """World-to-camera (OpenCV axes) for a camera at ``eye`` looking at ``target``; image up ~ ``up``."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    fwd = target - eye
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-6:
        # Looking along ``up``: borrow the world axis least aligned with the view direction.
        right = np.cross(fwd, np.eye(3)[np.argmin(np.abs(fwd))])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])  # rows: camera axes in world coordinates
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return w2c


def synthesize_views(
    scene,
    n: int,
    width: int = 512,
    height: int = 512,
    fov_deg: float = 50.0,
    margin: float = 1.25,
    up: Sequence[float] = (0.0, 0.0, 1.0),
) -> list[Camera]:
    """``n`` cameras on a Fibonacci sphere around the scene's robust box, all looking at its centre.

    ``fov_deg`` is the horizontal field of view. The distance makes the box's bounding sphere fit in
    the view with ``margin`` to spare (so every camera is outside the box); the sphere's poles lie
    along ``up``. Deterministic: the same scene and arguments give the same cameras.
    """
    if int(n) < 1:
        raise InputError(f"number of views must be at least 1, got {n}")
    if not 0.0 < fov_deg < 180.0:
        raise InputError(f"field of view {fov_deg} degrees is outside (0, 180)")
    if margin < 1.0:
        raise InputError(f"margin {margin} must be at least 1")
    lo, hi = robust_bounds(scene)
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo) / 2)
    radius = max(radius, 1e-3 * max(1.0, float(np.abs(centre).max())))
    fx = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    half = min(math.atan(0.5 * width / fx), math.atan(0.5 * height / fx))
    # A sphere of radius r seen from distance d subtends a half-angle asin(r / d).
    dist = margin * radius / math.sin(half)
    up_v = np.asarray(up, dtype=np.float64).reshape(3)
    if not np.linalg.norm(up_v) > 0:
        raise InputError(f"up vector {tuple(up)} has no direction")
    up_v /= np.linalg.norm(up_v)
    # Orthonormal frame whose third axis is ``up``.
    a = np.cross(up_v, np.eye(3)[np.argmin(np.abs(up_v))])
    a /= np.linalg.norm(a)
    b = np.cross(up_v, a)
    golden = math.pi * (3.0 - math.sqrt(5.0))
    K = _intrinsics(fx, fx, width / 2, height / 2)
    cams = []
    for i in range(int(n)):
        z = 1.0 - 2.0 * (i + 0.5) / n
        r = math.sqrt(max(0.0, 1.0 - z * z))
        d = r * math.cos(golden * i) * a + r * math.sin(golden * i) * b + z * up_v
        eye = centre + dist * d
        cams.append(Camera(look_at(eye, centre, up_v), K.copy(), width, height, f"view_{i:04d}"))
    return cams


def _order(cameras: Sequence[Camera]) -> list[int]:
    return sorted(range(len(cameras)), key=lambda i: natural_key(cameras[i].name))


def limit_size(cameras: list[Camera], max_side: int) -> list[Camera]:
    """The same views, scaled down where the longer side exceeds ``max_side`` pixels."""
    return [
        c.scaled(max_side / max(c.width, c.height)) if max(c.width, c.height) > max_side else c
        for c in cameras
    ]


def sample_views(cameras: Sequence[Camera], fraction: float) -> list[int]:
    """Indices (ascending) of ``round(fraction * n)`` views (at least 1), evenly spaced over the
    cameras in name order."""
    try:
        f = float(fraction)
    except (TypeError, ValueError):
        raise InputError(f"view fraction {fraction!r} is not a number") from None
    if not 0.0 < f <= 1.0:
        raise InputError(f"view fraction {fraction} is outside (0, 1]")
    n = len(cameras)
    if n == 0:
        raise InputError("no cameras to sample views from")
    m = min(n, max(1, round(f * n)))
    order = _order(cameras)
    # Centre of each of m equal slices of the sorted list; distinct because n / m >= 1.
    return sorted(order[int((k + 0.5) * n / m)] for k in range(m))


def split_test_views(cameras: Sequence[Camera], every: int = 8) -> tuple[list[int], list[int]]:
    """3DGS convention: every ``every``-th camera by sorted name (starting with the first) is a test
    view. Returns (train indices, test indices), each ascending."""
    if int(every) < 2:
        raise InputError(f"test-view interval {every} must be at least 2")
    order = _order(cameras)
    test = sorted(order[::every])
    test_set = set(test)
    train = [i for i in range(len(cameras)) if i not in test_set]
    return train, test
