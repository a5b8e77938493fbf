"""INRIA 3DGS ``cameras.json``: a list of per-image records (reader and writer)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gspc.atomic import atomic_write_bytes
from gspc.cameras import Camera
from gspc.errors import InputError
from gspc.io.camera_common import check_rotation, intrinsics_matrix, rigid_inverse


def parse_inria(entries: list, path: Path) -> list[Camera]:
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
            K = intrinsics_matrix(
                float(e["fx"]), float(e["fy"]), float(e.get("cx", w / 2)), float(e.get("cy", h / 2))
            )
        except (TypeError, ValueError, OverflowError) as err:
            raise InputError(f"{path}: entry {i} ({name!r}) does not parse: {err}") from None
        check_rotation(R_c2w, f"{path}: camera {name!r}")
        cams.append(Camera(rigid_inverse(R_c2w, pos), K, w, h, name))
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
