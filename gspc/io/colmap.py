"""COLMAP sparse models: cameras and images (.txt or .bin) and the sparse points."""

from __future__ import annotations

import struct
import warnings
from pathlib import Path, PurePosixPath

import numpy as np

from gspc.cameras import Camera
from gspc.errors import InputError
from gspc.io.camera_common import frame_name, intrinsics_matrix

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


def colmap_files(d: Path) -> tuple[Path, Path] | None:
    for ext in (".bin", ".txt"):
        c, i = d / f"cameras{ext}", d / f"images{ext}"
        if c.is_file() and i.is_file():
            return c, i
    return None


def load_colmap(d: Path) -> list[Camera]:
    files = colmap_files(d)
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
        w2c = np.eye(4)
        w2c[:3, :3] = _quat_to_rot(_unit_quaternion(q, name))
        w2c[:3, 3] = t
        cams.append((name, Camera(w2c, intrinsics_matrix(fx, fy, cx, cy), w, h, name)))
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
    stems = [frame_name(n, i) for i, (n, _) in enumerate(named)]
    if len(set(stems)) != len(stems):
        stems = [str(PurePosixPath(n).with_suffix("")) for n, _ in named]
        if len(set(stems)) != len(stems):
            raise InputError("COLMAP model names the same image more than once")
    for s, (_, cam) in zip(stems, named, strict=True):
        cam.name = s
    return [cam for _, cam in named]


def _unit_quaternion(q, name: str) -> np.ndarray:
    """``q`` scaled to unit length; InputError for a zero or non-finite one. Scaled by its largest component
    first, so huge components (1e300, whose squares overflow) normalise without overflow or warnings."""
    q = np.asarray(q, dtype=np.float64)
    if not np.isfinite(q).all():
        raise InputError(f"COLMAP image {name!r} has a non-finite quaternion {q.tolist()}")
    big = np.abs(q).max()
    if not big > 0:
        raise InputError(f"COLMAP image {name!r} has a zero quaternion")
    q = q / big
    return q / np.linalg.norm(q)


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
                        xyz, rgb = _colmap_points_bin(f.read_bytes())
                    else:
                        xyz, rgb = _colmap_points_txt(f.read_text(encoding="utf-8"))
                except (struct.error, ValueError, IndexError, OverflowError, UnicodeDecodeError) as e:
                    raise InputError(f"COLMAP points in {f} do not parse: {e}") from None
                if not np.isfinite(xyz).all():
                    raise InputError(f"COLMAP points in {f} hold a non-finite position")
                return xyz, rgb
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
