"""What the camera-file readers share: reading JSON, building intrinsics and poses, checking rotations."""

from __future__ import annotations

import json
from pathlib import Path, PurePosixPath

import numpy as np

from gspc.errors import InputError


def read_json(path: Path):
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


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def rigid_inverse(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 inverse of x -> R x + t for a rotation R."""
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def check_rotation(R: np.ndarray, what: str) -> None:
    if not np.isfinite(R).all():
        raise InputError(f"{what} has NaN or Inf in its rotation")
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        raise InputError(f"{what} has a rotation that is not orthonormal and right-handed")


def frame_name(file_path: str, index: int) -> str:
    if not file_path:
        return f"frame_{index:05d}"
    name = PurePosixPath(file_path.replace("\\", "/")).name
    for ext in (".png", ".jpg", ".jpeg", ".exr", ".webp"):
        if name.lower().endswith(ext):
            return name[: -len(ext)]
    return name
