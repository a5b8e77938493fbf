"""Side-information candidates: the residuals of the sampled views, coded at one resolution each.

A candidate is what the SIDE chunk would carry (spec 10.9): one record per view, the residual images of the
views worth one, and the packed payload. The policy (policy.py) weighs candidates against each other and
against spending their bytes on attributes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.codec import residuals
from gspc.format.side_chunk import pack_side
from gspc.format.view_records import CameraRecord, ViewRecord


@dataclass
class SideCandidate:
    """One form of the side information: per-view records, residual images, the SIDE payload."""

    scale: int  # residuals coded at 1/scale resolution
    records: list[ViewRecord]  # per view: its camera, and its residual's record where one is sent
    images: dict[int, bytes]  # view number -> residual image
    payload: bytes | None  # None: no view's residual was worth sending

    @property
    def views_with_residual(self) -> int:
        return len(self.images)


def view_residuals(original: list[torch.Tensor], coded: list[torch.Tensor]) -> list[np.ndarray]:
    """R = I - I~ per view, float32 (H, W, 3) on the CPU (the residual image codecs are numpy)."""
    return [(a - b).cpu().numpy().astype(np.float32) for a, b in zip(original, coded)]


def side_candidate(
    view_cams: list[Camera], res: list[np.ndarray], distances: list[float | None], codec: str, scale: int
) -> SideCandidate:
    """Code each view's residual at its planned distance (None: no residual for that view) and 1/``scale``."""
    records, images = [], {}
    for k, (cam, r, d) in enumerate(zip(view_cams, res, distances)):
        residual = None
        if d is not None:
            params = residuals.ResidualParams(codec=codec, distance=d, scale=scale)
            images[k], residual = residuals.encode_residual(r, params)
        records.append(ViewRecord(CameraRecord.from_camera(cam), residual))
    return SideCandidate(scale, records, images, pack_side(records, images) if images else None)
