"""Small input files for tests, written from known values: a COLMAP model (text and binary) and a compressed
PLY (PlayCanvas's layout) with the values a reader should decode from it. Shared by tests/test_cameras.py,
tests/test_input_edges.py and tests/test_io.py; SOG archives are tools/sog_files.py's (tools/fuzz_inputs.py
writes them too)."""

import math
import struct
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

from gspc.scene import num_sh_rest

# Written out, not imported: the expected decodes do not lean on gspc's own constant.
SH_C0 = 0.28209479177387814

# (camera id, model, width, height, params), (image id, quaternion wxyz, t, camera id, name)
COLMAP_CAMS = [
    (1, "PINHOLE", 64, 48, [50.0, 55.0, 31.0, 23.0]),
    (2, "SIMPLE_PINHOLE", 40, 30, [35.0, 20.0, 15.0]),
]
COLMAP_IMGS = [
    (3, [0.9, 0.1, -0.3, 0.2], [0.5, -1.0, 4.0], 1, "DSC_10.JPG"),
    (1, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 3.0], 2, "DSC_9.JPG"),
]


def write_colmap_txt(d: Path, cams=COLMAP_CAMS, imgs=COLMAP_IMGS) -> None:
    """A COLMAP text model in the new folder ``d``: cameras.txt and images.txt, no 2D points."""
    d.mkdir(parents=True)
    lines = ["# Camera list with one line of data per camera:"]
    lines += [f"{c} {m} {w} {h} " + " ".join(map(str, p)) for c, m, w, h, p in cams]
    (d / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:", "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    for i, q, t, c, name in imgs:
        lines += [f"{i} {' '.join(map(str, q))} {' '.join(map(str, t))} {c} {name}", ""]  # no 2D points
    (d / "images.txt").write_text("\n".join(lines) + "\n")


def write_colmap_bin(d: Path) -> None:
    """:data:`COLMAP_CAMS` and :data:`COLMAP_IMGS` as a COLMAP binary model in the new folder ``d``."""
    ids = {"SIMPLE_PINHOLE": 0, "PINHOLE": 1}
    d.mkdir(parents=True)
    buf = struct.pack("<Q", len(COLMAP_CAMS))
    for c, m, w, h, p in COLMAP_CAMS:
        buf += struct.pack("<iiQQ", c, ids[m], w, h) + struct.pack(f"<{len(p)}d", *p)
    (d / "cameras.bin").write_bytes(buf)
    buf = struct.pack("<Q", len(COLMAP_IMGS))
    for k, (i, q, t, c, name) in enumerate(COLMAP_IMGS):
        buf += struct.pack("<i7di", i, *q, *t, c) + name.encode() + b"\0"
        buf += struct.pack("<Q", k) + struct.pack("<ddq", 1.5, 2.5, -1) * k  # some 2D points to skip
    (d / "images.bin").write_bytes(buf)


def _pack(fields: list[tuple[np.ndarray, int]]) -> np.ndarray:
    """Pack unsigned integer fields MSB first."""
    out = np.zeros(len(fields[0][0]), np.uint64)
    for values, bits in fields:
        out = (out << np.uint64(bits)) | values.astype(np.uint64)
    return out.astype(np.uint32)


def make_compressed_ply(path: Path, n: int = 300, colour_bounds: bool = False, sh_bands: int = 0, seed=0):
    """A compressed PLY with random content packed per the layout; returns the expected decode."""
    rng = np.random.default_rng(seed)
    chunks = -(-n // 256)
    ci = np.arange(n) // 256
    geo = [f"{b}_{a}" for b in ("min", "max") for a in "xyz"] + [
        f"{b}_scale_{a}" for b in ("min", "max") for a in "xyz"
    ]
    names = geo + ([f"{b}_{c}" for b in ("min", "max") for c in "rgb"] if colour_bounds else [])
    chunk = np.empty(chunks, dtype=[(k, "<f4") for k in names])
    lo, hi = (
        rng.uniform(-2, 0, (chunks, 3)).astype(np.float32),
        rng.uniform(0.1, 2, (chunks, 3)).astype(np.float32),
    )
    slo, shi = (
        rng.uniform(-9, -5, (chunks, 3)).astype(np.float32),
        rng.uniform(-4, 0, (chunks, 3)).astype(np.float32),
    )
    for i, a in enumerate("xyz"):
        chunk[f"min_{a}"], chunk[f"max_{a}"] = lo[:, i], hi[:, i]
        chunk[f"min_scale_{a}"], chunk[f"max_scale_{a}"] = slo[:, i], shi[:, i]
    clo, chi = np.zeros((chunks, 3), np.float32), np.ones((chunks, 3), np.float32)
    if colour_bounds:
        clo, chi = (
            rng.uniform(-0.2, 0.3, (chunks, 3)).astype(np.float32),
            rng.uniform(0.6, 1.3, (chunks, 3)).astype(np.float32),
        )
        for i, c in enumerate("rgb"):
            chunk[f"min_{c}"], chunk[f"max_{c}"] = clo[:, i], chi[:, i]

    p = np.stack([rng.integers(0, 2048, n), rng.integers(0, 1024, n), rng.integers(0, 2048, n)], 1)
    s = np.stack([rng.integers(0, 2048, n), rng.integers(0, 1024, n), rng.integers(0, 2048, n)], 1)
    c = rng.integers(0, 256, (n, 4))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    mode = np.abs(q).argmax(1)
    q *= np.sign(q[np.arange(n), mode])[:, None]
    kept = np.stack([np.delete(row, m) for row, m in zip(q, mode, strict=True)])
    k10 = np.round((kept / math.sqrt(2) + 0.5) * 1023).astype(np.int64)
    vertex = np.empty(
        n, dtype=[(k, "<u4") for k in ("packed_position", "packed_rotation", "packed_scale", "packed_color")]
    )
    vertex["packed_position"] = _pack([(p[:, 0], 11), (p[:, 1], 10), (p[:, 2], 11)])
    vertex["packed_scale"] = _pack([(s[:, 0], 11), (s[:, 1], 10), (s[:, 2], 11)])
    vertex["packed_color"] = _pack([(c[:, 0], 8), (c[:, 1], 8), (c[:, 2], 8), (c[:, 3], 8)])
    vertex["packed_rotation"] = _pack([(mode, 2), (k10[:, 0], 10), (k10[:, 1], 10), (k10[:, 2], 10)])
    elements = [PlyElement.describe(chunk, "chunk"), PlyElement.describe(vertex, "vertex")]
    k = num_sh_rest(sh_bands)
    sh_bytes = rng.integers(0, 256, (n, 3 * k))
    if sh_bands:
        sh = np.empty(n, dtype=[(f"f_rest_{i}", "u1") for i in range(3 * k)])
        for i in range(3 * k):
            sh[f"f_rest_{i}"] = sh_bytes[:, i]
        elements.append(PlyElement.describe(sh, "sh"))
    PlyData(elements).write(str(path))
    steps = np.array([2047, 1023, 2047])
    rgb = clo[ci] + (chi[ci] - clo[ci]) * c[:, :3] / 255
    t = np.where(sh_bytes == 0, 0.0, np.where(sh_bytes == 255, 1.0, (sh_bytes + 0.5) / 256))
    return {
        "means": lo[ci] + (hi[ci] - lo[ci]) * p / steps,
        "log_scales": slo[ci] + (shi[ci] - slo[ci]) * s / steps,
        "sh_dc": (rgb - 0.5) / SH_C0,
        "alpha": c[:, 3] / 255,
        "quats": q,
        "sh_rest": ((t - 0.5) * 8).reshape(n, 3, k).transpose(0, 2, 1),
    }
