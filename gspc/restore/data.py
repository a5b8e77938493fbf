"""The restorer's training data as tools/make_restorer_data.py writes it and tools/train_restorer.py and
tools/bench_restorer.py read it: a folder of one ``.npz`` per (scene, rate point, view) and a manifest.

Each ``.npz`` holds ``degraded`` (I~, float16), ``residual`` (R = I - I~, float16) and, per stored distance
``k``, the decoded side information R~ as the residual codec's 8-bit symbols ``q_<k>`` with ``gain_<k>`` and
``offset_<k>`` (gain 0: no residual sent) and ``scale_<k>`` when coded below full resolution.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from gspc.codec import residuals
from gspc.errors import InputError
from gspc.metrics import psnr, quantize8
from gspc.restore.nafnet import NAFNet
from gspc.restore.restorer import Restorer

MANIFEST = "manifest.json"
FORMAT = 1


def side_info_from_npz(data, k: int) -> np.ndarray:
    """Decoded R~ number ``k`` of a stored view (float32, exactly as decode_residual gives it)."""
    gain = np.float32(data[f"gain_{k}"])
    h, w = data["residual"].shape[:2]
    if gain == 0:
        return np.zeros((h, w, 3), np.float32)
    r = ((data[f"q_{k}"].astype(np.float32) - np.float32(data[f"offset_{k}"])) / gain).astype(np.float32)
    scale = int(data[f"scale_{k}"]) if f"scale_{k}" in data else 1
    return residuals.upsample(r, scale, h, w) if scale != 1 else r


def read_manifest(data_dir: Path) -> list[dict]:
    path = data_dir / MANIFEST
    if not path.is_file():
        raise InputError(f"{path} does not exist: run tools/make_restorer_data.py first")
    return json.loads(path.read_text())["entries"]


def load_view(data_dir: Path, entry: dict) -> dict:
    """One stored view as CHW tensors: I~ and R in float16, every R~ in float16."""
    with np.load(data_dir / entry["file"]) as z:
        n = len(z["distances"])
        side = [torch.from_numpy(side_info_from_npz(z, k)).permute(2, 0, 1).half() for k in range(n)]
        return {
            "degraded": torch.from_numpy(z["degraded"]).permute(2, 0, 1).contiguous(),
            "residual": torch.from_numpy(z["residual"]).permute(2, 0, 1).contiguous(),
            "side": [s.contiguous() for s in side],
            "entry": entry,
        }


@torch.no_grad()
def validate(model: NAFNet, views: list[dict], rate: str | None = None) -> dict:
    """Mean PSNR (dB) over whole views of I~, I~ + R~ (planned distance) and the restored view."""
    restorer = Restorer("candidate", model)
    side_only = Restorer("none", None)
    sums = {"degraded": [], "side": [], "restored": []}
    try:
        for v in views:
            if rate is not None and v["entry"]["rate"] != rate:
                continue
            d = v["degraded"].float().permute(1, 2, 0)
            r = v["residual"].float().permute(1, 2, 0)
            s = v["side"][0].float().permute(1, 2, 0)
            ref = quantize8(d + r)
            sums["degraded"].append(float(psnr(quantize8(d), ref)))
            sums["side"].append(float(psnr(quantize8(side_only.restore(d, s)), ref)))
            sums["restored"].append(float(psnr(quantize8(restorer.restore(d, s)), ref)))
    finally:
        model.train()
    out = {k: float(np.mean(v)) if v else float("nan") for k, v in sums.items()}
    out["gain"] = out["restored"] - out["side"]
    out["views"] = len(sums["side"])
    return out
