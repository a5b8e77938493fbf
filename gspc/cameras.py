"""Camera: a pinhole camera in OpenCV convention (x right, y down, z forward).

Kept as float64 numpy so cameras serialise exactly (container header, cameras.json); the
renderer converts to the scene's dtype and device.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gspc.errors import InputError


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
        self.width, self.height = int(self.width), int(self.height)
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"camera {self.name!r} has non-positive size {self.width}x{self.height}")
        if not (np.isfinite(self.world_to_cam).all() and np.isfinite(self.K).all()):
            raise InputError(f"camera {self.name!r} has NaN or Inf in its matrices")

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
        """Plain msgpack/JSON-friendly form (used by the container header)."""
        return {
            "name": self.name,
            "width": self.width,
            "height": self.height,
            "K": [float(v) for v in self.K.reshape(-1)],
            "world_to_cam": [float(v) for v in self.world_to_cam.reshape(-1)],
        }

    @staticmethod
    def from_dict(d: dict) -> Camera:
        try:
            return Camera(np.array(d["world_to_cam"]), np.array(d["K"]), d["width"], d["height"], d.get("name", ""))
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"camera record does not parse: {e}") from None
