"""Writer for glTF 2.0 binary (.glb) with KHR_gaussian_splatting (Khronos, release candidate).

One mesh with one POINTS primitive whose attributes are, per Gaussian, all float32 in one buffer:

  POSITION                                    VEC3   the mean (with the min and max glTF requires)
  KHR_gaussian_splatting:ROTATION             VEC4   unit quaternion, glTF order x, y, z, w
  KHR_gaussian_splatting:SCALE                VEC3   linear scales: exp of gspc's log scales
  KHR_gaussian_splatting:OPACITY              SCALAR linear opacity in [0, 1]: sigmoid of the logit
  KHR_gaussian_splatting:SH_DEGREE_0_COEF_0   VEC3   the DC coefficients, as stored (colour = 0.5 + C0 dc)
  KHR_gaussian_splatting:SH_DEGREE_l_COEF_n   VEC3   degree l, n = 0 .. 2l (order m = -l .. l): INRIA's
                                                     basis, which is the extension's
  COLOR_0                                     VEC4   unsigned byte, normalised: the fallback colour of
                                                     viewers without the extension (linear RGB, opacity)

The primitive's extension object names the "ellipse" kernel and the "srgb_rec709_display" colour space
(3DGS scenes are trained on sRGB images and composited as display values). glTF is Y-up, +Z front,
right-handed ("LUF", gspc/io/coordinates.py): the scene is converted into it, positions, rotations and
SH alike, as the extension asks of pre-trained data; an unstated scene is taken to be OPENCV (RDF).

A .glb holds one JSON chunk (padded with spaces) and one binary chunk (padded with zeros), each starting
on a 4-byte boundary; lengths are uint32, so a file stops below 4 GiB.
"""

from __future__ import annotations

import json
import os
import struct
from typing import BinaryIO

import numpy as np
import torch

from gspc import __version__
from gspc.atomic import atomic_write
from gspc.errors import InputError
from gspc.io.coordinates import GLTF, oriented
from gspc.scene import SH_C0, GaussianScene

EXTENSION = "KHR_gaussian_splatting"
GLB_MAGIC = b"glTF"
GLB_VERSION = 2
JSON_CHUNK = 0x4E4F534A  # "JSON"
BIN_CHUNK = 0x004E4942  # "BIN\0"
FLOAT = 5126
UNSIGNED_BYTE = 5121
ARRAY_BUFFER = 34962
POINTS = 0
MAX_GLB_BYTES = (1 << 32) - 1
FLOAT32_MAX = float(np.finfo(np.float32).max)


def _f32(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to("cpu", torch.float32).numpy())


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """COLOR_0 holds linear values (glTF 2.0), the extension's colours are sRGB-encoded."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _attributes(scene: GaussianScene) -> list[tuple[str, np.ndarray, int]]:
    """(semantic, array (N, components) or (N,), glTF component type) for every attribute, in file order."""
    log_scales = scene.log_scales.detach().to("cpu", torch.float64)
    scales = _f32(log_scales.exp())
    if not np.isfinite(scales).all():
        raise InputError(
            f"a log scale of {float(log_scales.max()):.4g} is beyond float32 as a linear glTF SCALE "
            f"(log scales stop at {np.log(FLOAT32_MAX):.4g})"
        )
    quats = scene.quats.detach().to("cpu", torch.float64)
    unit = (quats / quats.norm(dim=1, keepdim=True))[:, [1, 2, 3, 0]]
    opacity = torch.sigmoid(scene.opacities.detach().to("cpu", torch.float64))
    dc = scene.sh_dc.detach().to("cpu", torch.float64).numpy()
    colour = _srgb_to_linear(np.clip(0.5 + SH_C0 * dc, 0.0, 1.0))
    rgba = np.concatenate([colour, opacity.numpy()[:, None]], axis=1)
    out = [
        ("POSITION", _f32(scene.means), FLOAT),
        (f"{EXTENSION}:ROTATION", _f32(unit), FLOAT),
        (f"{EXTENSION}:SCALE", scales, FLOAT),
        (f"{EXTENSION}:OPACITY", _f32(opacity), FLOAT),
        (f"{EXTENSION}:SH_DEGREE_0_COEF_0", _f32(scene.sh_dc), FLOAT),
    ]
    k = 0
    for degree in range(1, scene.sh_degree + 1):
        for n in range(2 * degree + 1):
            out.append((f"{EXTENSION}:SH_DEGREE_{degree}_COEF_{n}", _f32(scene.sh_rest[:, k]), FLOAT))
            k += 1
    out.append(("COLOR_0", np.clip(np.floor(rgba * 255.0 + 0.5), 0, 255).astype(np.uint8), UNSIGNED_BYTE))
    return out


_TYPES = {1: "SCALAR", 3: "VEC3", 4: "VEC4"}


def _json_chunk(attributes: list[tuple[str, np.ndarray, int]]) -> tuple[bytes, int]:
    """The glTF JSON (padded) and the binary buffer's length; every view starts on a 4-byte boundary."""
    views, accessors, semantics, at = [], [], {}, 0
    for i, (semantic, array, component) in enumerate(attributes):
        views.append({"buffer": 0, "byteOffset": at, "byteLength": array.nbytes, "target": ARRAY_BUFFER})
        accessor = {
            "bufferView": i,
            "componentType": component,
            "count": len(array),
            "type": _TYPES[1 if array.ndim == 1 else array.shape[1]],
        }
        if component == UNSIGNED_BYTE:
            accessor["normalized"] = True
        if semantic == "POSITION":  # required by glTF; float32 values are exact in JSON's doubles
            accessor["min"] = [float(v) for v in array.min(axis=0)]
            accessor["max"] = [float(v) for v in array.max(axis=0)]
        accessors.append(accessor)
        semantics[semantic] = i
        at += -(-array.nbytes // 4) * 4
    primitive = {
        "attributes": semantics,
        "mode": POINTS,
        "extensions": {EXTENSION: {"kernel": "ellipse", "colorSpace": "srgb_rec709_display"}},
    }
    gltf = {
        "asset": {"version": "2.0", "generator": f"gspc {__version__}"},
        "extensionsUsed": [EXTENSION],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [primitive]}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": at}],
    }
    text = json.dumps(gltf, separators=(",", ":"), allow_nan=False).encode()
    return text + b" " * (-len(text) % 4), at


def write_glb(scene: GaussianScene, path: str | os.PathLike) -> None:
    """Write ``scene`` as a .glb with KHR_gaussian_splatting, atomically; InputError for a scene a .glb
    cannot hold (a linear scale beyond float32, 4 GiB or more)."""
    scene.validate()
    scene = oriented(scene.to("cpu"), GLTF)
    attributes = _attributes(scene)
    text, bin_length = _json_chunk(attributes)
    total = 12 + 8 + len(text) + 8 + bin_length
    if total > MAX_GLB_BYTES:
        raise InputError(f"the .glb would take {total:,} bytes; the format stops at {MAX_GLB_BYTES:,}")

    def write(f: BinaryIO) -> None:
        f.write(GLB_MAGIC + struct.pack("<II", GLB_VERSION, total))
        f.write(struct.pack("<II", len(text), JSON_CHUNK) + text)
        f.write(struct.pack("<II", bin_length, BIN_CHUNK))
        for _, array, _ in attributes:
            f.write(memoryview(array).cast("B"))
            f.write(bytes(-array.nbytes % 4))

    atomic_write(path, write)
