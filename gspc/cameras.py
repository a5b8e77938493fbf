"""Camera: a pinhole camera in OpenCV convention (x right, y down, z forward), and the natural name
order every gspc tool works in. Camera files are read and written in gspc/io/ (camera_files.py); views
are synthesised and sampled in gspc/views.py.

Kept as float64 numpy so cameras serialise exactly (container header, cameras.json); the
renderer converts to the scene's dtype and device.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gspc.errors import InputError
from gspc.limits import MAX_CAMERA_SIDE

FLOAT32_MAX = float(np.finfo(np.float32).max)


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
        # Cameras are rendered and stored in binary32 (spec 10.8): a larger value would overflow there.
        for what, m in (("pose", self.world_to_cam), ("intrinsics", self.K)):
            if np.abs(m).max() > FLOAT32_MAX:
                raise InputError(
                    f"camera {self.name!r} has {float(m.flat[np.abs(m).argmax()]):g} in its {what}, beyond "
                    f"binary32's range ({FLOAT32_MAX:.3g})"
                )
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


_NAME_PARTS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple:
    """Sort key that orders embedded numbers by value, so ``r_2`` comes before ``r_10``."""
    parts = _NAME_PARTS.split(name)
    # re.split with a capture group alternates text, number, text, ...: types line up between keys.
    return tuple(int(p) if i % 2 else p.lower() for i, p in enumerate(parts)) + (name,)


def sort_cameras(cameras: Sequence[Camera]) -> list[Camera]:
    """Cameras in natural order of their names (the order every gspc tool works in)."""
    return sorted(cameras, key=lambda c: natural_key(c.name))
