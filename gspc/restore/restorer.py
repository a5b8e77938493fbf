"""Restorers: turn a degraded render I~ and decoded side information R~ into a restored image I^.

``load_restorer(name)`` returns a :class:`Restorer`. ``"none"`` is the paper's side-information-only
mode (I^ = I~ + R~); any other name is a network whose weights live in
``gspc/restore/weights/<file>`` and are listed in ``weights/MANIFEST.json`` as
``{name: {"architecture": ..., "file": ..., "sha256": ..., "config": {constructor kwargs}}}``, the
architecture one of gspc/restore/architectures.py (NAFNet when the entry names none). The hash is
checked before loading, and loading uses ``torch.load(weights_only=True)`` so a weights file cannot run code.

Inference is tiled with overlapping, feathered tiles so large views fit in memory; it runs under
``torch.no_grad`` in eval mode, and on one device/thread count gives the same bits every call.
Tiles differ from one full-image pass only through NAFNet's global channel attention (a per-tile
mean) and the convolutions' context at tile borders, which the overlap hides.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import torch

from gspc.atomic import atomic_write
from gspc.device import float32_math
from gspc.errors import CodecError, InputError
from gspc.restore.architectures import DEFAULT_ARCHITECTURE, build
from gspc.restore.nafnet import NAFNet

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
MANIFEST = "MANIFEST.json"
_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")


class Restorer:
    """Restores (H, W, 3) renders; ``model=None`` adds the side information and nothing more."""

    def __init__(self, name: str, model: NAFNet | None = None, tile: int = 512, overlap: int = 48):
        if tile <= 2 * overlap:
            raise InputError(f"restorer tile size {tile} must exceed twice the overlap {overlap}")
        self.name, self.model, self.tile, self.overlap = name, model, int(tile), int(overlap)
        if model is not None:
            model.eval()

    @float32_math()  # full float32 on CUDA too (no TF32 convolutions)
    def restore(self, degraded: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
        """I^ = I~ + R^ for one view; inputs and output are (H, W, 3) float tensors."""
        if degraded.ndim != 3 or degraded.shape[-1] != 3 or degraded.shape != residual.shape:
            raise InputError(
                f"restorer {self.name!r} needs two HxWx3 images of one size, got "
                f"{tuple(degraded.shape)} and {tuple(residual.shape)}"
            )
        if self.model is None:
            return degraded + residual.to(degraded.dtype)
        with torch.no_grad():
            p = next(self.model.parameters())
            x = torch.cat([degraded, residual.to(degraded.dtype)], dim=-1)
            x = x.to(device=p.device, dtype=p.dtype).permute(2, 0, 1)[None]
            r_hat = self._tiled(x)[0].permute(1, 2, 0)
        return degraded + r_hat.to(device=degraded.device, dtype=degraded.dtype)

    def _tiled(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        if h <= self.tile and w <= self.tile:
            return self.model(x)
        out = x.new_zeros(1, 3, h, w)
        weight = x.new_zeros(1, 1, h, w)
        m = self.model.multiple
        for y0, th in _spans(h, self.tile, self.overlap, m):
            wy = _ramp(y0, th, h, self.overlap, x)
            for x0, tw in _spans(w, self.tile, self.overlap, m):
                wx = _ramp(x0, tw, w, self.overlap, x)
                ys, xs = slice(y0, y0 + th), slice(x0, x0 + tw)
                wt = wy[:, None] * wx[None, :]
                out[..., ys, xs] += self.model(x[..., ys, xs]) * wt
                weight[..., ys, xs] += wt
        return out / weight


def _spans(length: int, tile: int, overlap: int, multiple: int) -> list[tuple[int, int]]:
    """(origin, size) of the tiles along one axis.

    Origins are multiples of the net's downsampling factor so every tile sees the same
    stride-2 phase as a full-image pass; the last tile ends flush with the image (it may be up to
    ``multiple - 1`` pixels larger than ``tile``); neighbours overlap by at least ``overlap``.
    """
    if length <= tile:
        return [(0, length)]
    step = max(multiple, (tile - overlap) // multiple * multiple)
    last = (length - tile) // multiple * multiple
    starts = list(range(0, last, step)) + [last]
    return [(s, tile) for s in starts[:-1]] + [(last, length - last)]


def _ramp(start: int, size: int, length: int, overlap: int, like: torch.Tensor) -> torch.Tensor:
    """Feathering weights along one axis: linear ramps on sides shared with a neighbouring tile."""
    r = like.new_ones(size)
    edge = (torch.arange(overlap, dtype=like.dtype, device=like.device) + 1) / (overlap + 1)
    if start > 0:
        r[:overlap] = edge
    if start + size < length:
        r[size - overlap :] = edge.flip(0)
    return r


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _read_manifest(weights_dir: Path, name: str) -> dict:
    path = weights_dir / MANIFEST
    if not path.is_file():
        raise CodecError(f"restorer {name!r}: no {MANIFEST} in {weights_dir}")
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise CodecError(f"restorer {name!r}: {path} does not parse: {e}") from None


def available_restorers(weights_dir: str | Path | None = None) -> list[str]:
    """Names a decoder can load: 'none' plus every restorer in the weights manifest."""
    path = (Path(weights_dir) if weights_dir is not None else WEIGHTS_DIR) / MANIFEST
    try:
        names = sorted(json.loads(path.read_text()))
    except (OSError, ValueError):
        names = []
    return ["none", *names]


def load_restorer(
    name: str,
    weights_dir: str | Path | None = None,
    tile: int = 512,
    overlap: int = 48,
    device: str | torch.device = "cpu",
) -> Restorer:
    """The restorer called ``name``; raises CodecError when its weights are missing or altered."""
    if name == "none":
        return Restorer("none", None, tile, overlap)
    weights_dir = Path(weights_dir) if weights_dir is not None else WEIGHTS_DIR
    entry = _read_manifest(weights_dir, name).get(name)
    if not isinstance(entry, dict) or "file" not in entry or "sha256" not in entry:
        raise CodecError(f"restorer {name!r} is not listed in {weights_dir / MANIFEST}")
    path = weights_dir / entry["file"]
    if not path.is_file():
        raise CodecError(f"restorer {name!r}: weights file {path} is missing")
    if _sha256(path) != entry["sha256"]:
        raise CodecError(f"restorer {name!r}: weights file {path} does not match its SHA-256 in the manifest")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
        model = build(entry.get("architecture", DEFAULT_ARCHITECTURE), entry.get("config", {}), name)
        model.load_state_dict(state)
    except CodecError:
        raise
    except Exception as e:  # unpickling, shape or key mismatches: all mean unusable weights
        raise CodecError(f"restorer {name!r}: weights in {path.name} do not load: {e}") from None
    return Restorer(name, model.to(device), tile, overlap)


def save_restorer(
    model: NAFNet,
    config: dict,
    name: str,
    weights_dir: str | Path | None = None,
    architecture: str = DEFAULT_ARCHITECTURE,
) -> Path:
    """Write ``<name>.pt`` and its manifest entry (both atomically); returns the weights path."""
    if not _NAME.match(name) or name == "none":
        raise InputError(f"restorer name {name!r} must be letters, digits, '_', '.', '-' and not 'none'")
    weights_dir = Path(weights_dir) if weights_dir is not None else WEIGHTS_DIR
    weights_dir.mkdir(parents=True, exist_ok=True)
    path = weights_dir / f"{name}.pt"
    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    atomic_write(path, lambda f: torch.save(state, f))
    manifest_path = weights_dir / MANIFEST
    manifest = json.loads(manifest_path.read_text()) if manifest_path.is_file() else {}
    manifest[name] = {
        "architecture": architecture,
        "file": path.name,
        "sha256": _sha256(path),
        "config": config,
    }
    text = json.dumps(manifest, indent=2, sort_keys=True) + "\n"
    atomic_write(manifest_path, lambda f: f.write(text.encode()))
    return path
