"""Tiny SOG archives (PlayCanvas's format) with random quantised content and the values a reader should
decode from them: shared by tests/test_io.py, tests/test_hostile.py and tools/fuzz_inputs.py."""

import json
import math
import zipfile
from pathlib import Path

import imagecodecs
import numpy as np

from gspc.scene import num_sh_rest


def _webp(rgba: np.ndarray) -> bytes:
    return imagecodecs.webp_encode(rgba, lossless=True)


def _image(pixels: np.ndarray, width: int) -> np.ndarray:
    """Row-major pixels (n, 4) padded into an (H, width, 4) image."""
    h = -(-len(pixels) // width)
    img = np.zeros((h * width, 4), np.uint8)
    img[: len(pixels)] = pixels
    return img.reshape(h, width, 4)


def _encode_quats(q: np.ndarray) -> np.ndarray:
    """Smallest-three as the SOG spec describes: drop the largest |component|, made positive."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    mode = np.abs(q).argmax(1)
    q = q * np.sign(q[np.arange(len(q)), mode])[:, None]
    kept = np.stack([np.delete(row, m) for row, m in zip(q, mode, strict=True)])
    bytes3 = np.round((kept * math.sqrt(2) * 0.5 + 0.5) * 255).astype(np.uint8)
    return np.concatenate([bytes3, (252 + mode)[:, None].astype(np.uint8)], axis=1), q


def make_sog(path: Path, n: int = 10, bands: int = 0, seed: int = 0, meta_override=None) -> dict:
    """A tiny SOG zip with random quantised content; returns what a decoder should produce."""
    rng = np.random.default_rng(seed)
    width = 4
    qpos = rng.integers(0, 65536, (n, 3))
    mins, maxs = np.array([-1.0, -0.5, 0.0]), np.array([1.0, 2.0, 0.25])
    lo = np.concatenate([qpos & 255, np.full((n, 1), 255)], 1).astype(np.uint8)
    hi = np.concatenate([qpos >> 8, np.full((n, 1), 255)], 1).astype(np.uint8)
    quat_px, unit = _encode_quats(rng.normal(size=(n, 4)))
    scale_idx = rng.integers(0, 256, (n, 3))
    colour_idx = rng.integers(0, 256, (n, 3))
    alpha = rng.integers(1, 255, n)
    alpha[0], alpha[1] = 0, 255
    scale_book = np.sort(rng.uniform(-10, 0, 256))
    colour_book = np.linspace(-1.7, 1.7, 256)
    meta = {
        "version": 2,
        "count": n,
        "means": {"mins": mins.tolist(), "maxs": maxs.tolist(), "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": scale_book.tolist(), "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": colour_book.tolist(), "files": ["sh0.webp"]},
    }
    pad = np.full((n, 1), 255, np.uint8)
    files = {
        "means_l.webp": _webp(_image(lo, width)),
        "means_u.webp": _webp(_image(hi, width)),
        "quats.webp": _webp(_image(quat_px, width)),
        "scales.webp": _webp(_image(np.concatenate([scale_idx.astype(np.uint8), pad], 1), width)),
        "sh0.webp": _webp(_image(np.concatenate([colour_idx, alpha[:, None]], 1).astype(np.uint8), width)),
    }
    t = mins + (maxs - mins) * qpos / 65535
    expected = {
        "means": np.sign(t) * (np.exp(np.abs(t)) - 1),
        "quats": unit,
        "log_scales": scale_book[scale_idx],
        "sh_dc": colour_book[colour_idx],
        "alpha": alpha / 255,
        "sh_rest": np.zeros((n, 0, 3)),
    }
    if bands:
        k = num_sh_rest(bands)
        palette = 70  # more than one row of 64 entries
        labels = rng.integers(0, palette, n)
        entries = rng.integers(0, 256, (palette, k, 3))
        rows = -(-palette // 64)
        cent = np.zeros((rows * 64, k, 4), np.uint8)
        cent[:palette, :, :3] = entries
        cent[..., 3] = 255
        sh_book = np.linspace(-0.5, 0.5, 256)
        meta["shN"] = {
            "count": palette,
            "bands": bands,
            "codebook": sh_book.tolist(),
            "files": ["shN_centroids.webp", "shN_labels.webp"],
        }
        files["shN_centroids.webp"] = _webp(cent.reshape(rows, 64 * k, 4))
        lab = np.stack([labels & 255, labels >> 8, np.zeros(n, int), np.full(n, 255)], 1).astype(np.uint8)
        files["shN_labels.webp"] = _webp(_image(lab, width))
        expected["sh_rest"] = sh_book[entries[labels]]
    if meta_override:
        meta_override(meta)
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as z:
        for name, data in files.items():
            z.writestr(name, data)
        z.writestr("meta.json", json.dumps(meta))
    return expected
