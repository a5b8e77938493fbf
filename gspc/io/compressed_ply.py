"""Reader for PlayCanvas "compressed PLY" (SuperSplat / splat-transform): chunked, quantised splats.

Elements:
  chunk   one row per 256 consecutive splats: float min_/max_ x, y, z (positions), min_/max_scale_ x, y, z
          (log scales) and, in newer files, min_/max_ r, g, b (colour); older files store colour raw.
  vertex  uint packed_position (11-10-11 bits x, y, z), packed_scale (11-10-11), packed_color (8-8-8-8
          r, g, b, opacity; MSB first), packed_rotation (2-bit index of the dropped largest component of
          (w, x, y, z), then three 10-bit components in [-1/sqrt2, 1/sqrt2]).
  sh      optional uint8 f_rest_0..3K-1 (channel-major as INRIA), each mapping to [-4, 4].
Fields are fractions of the chunk range: value = min + (max - min) * q / (2^bits - 1).
"""

from __future__ import annotations

import math
import os

import numpy as np
from plyfile import PlyData

from gspc.codec.quantisers import place_largest
from gspc.errors import InputError
from gspc.io.ply import load_plydata, rest_names
from gspc.scene import SH_C0, GaussianScene, alpha_to_logit, make_scene, sh_degree_from_rest, validate_named

CHUNK_SIZE = 256

_BOUNDS = ("min", "max")
CHUNK_GEOMETRY = tuple(f"{b}_{axis}" for b in _BOUNDS for axis in "xyz") + tuple(
    f"{b}_scale_{axis}" for b in _BOUNDS for axis in "xyz"
)
CHUNK_COLOUR = tuple(f"{b}_{c}" for b in _BOUNDS for c in "rgb")
PACKED = ("packed_position", "packed_rotation", "packed_scale", "packed_color")


def is_compressed(ply: PlyData) -> bool:
    return any(e.name == "chunk" for e in ply.elements)


def _field(packed: np.ndarray, shift: int, bits: int) -> np.ndarray:
    return ((packed >> np.uint32(shift)) & np.uint32((1 << bits) - 1)).astype(np.float64) / ((1 << bits) - 1)


def _lerp(lo: np.ndarray, hi: np.ndarray, t: np.ndarray) -> np.ndarray:
    return lo * (1.0 - t) + hi * t


def _unpack_111011(packed: np.ndarray) -> np.ndarray:
    return np.stack([_field(packed, 21, 11), _field(packed, 11, 10), _field(packed, 0, 11)], axis=1)


def _unpack_rotation(packed: np.ndarray) -> np.ndarray:
    abc = np.stack([_field(packed, 20, 10), _field(packed, 10, 10), _field(packed, 0, 10)], axis=1)
    abc = (abc - 0.5) * math.sqrt(2.0)
    mode = (packed >> np.uint32(30)).astype(np.int64)
    return place_largest(mode, abc)


def _finite(element: np.ndarray, name: str, source: str) -> np.ndarray:
    """A chunk's bound as float64; InputError naming it where one is NaN or infinite (the interpolation
    would turn it into NaN)."""
    values = np.asarray(element[name], np.float64)
    if not np.isfinite(values).all():
        bad = values[~np.isfinite(values)][0]
        raise InputError(f"{source}: chunk property '{name}' holds {bad} (a chunk's bounds must be finite)")
    return values


def _packed(vertex: np.ndarray, name: str, source: str) -> np.ndarray:
    """A packed vertex field as uint32: an unsigned integer property (splat-transform writes uint), or a
    float or signed one whose every value is a whole number in 0 .. 2^32 - 1; InputError naming it otherwise
    (a float NaN would cast to an arbitrary integer)."""
    values = np.asarray(vertex[name])
    if values.dtype.kind == "u" and values.dtype.itemsize <= 4:
        return values.astype(np.uint32)
    wide = values.astype(np.float64)
    good = (wide >= 0) & (wide <= 0xFFFFFFFF) & (np.floor(wide) == wide)  # False for NaN, no warning
    if not good.all():
        raise InputError(
            f"{source}: vertex property '{name}' holds {float(wide[~good][0])!r}, not a packed field (an "
            "integer in 0..2^32 - 1)"
        )
    return wide.astype(np.uint32)


def scene_from_compressed(ply: PlyData, source: str = "PLY") -> GaussianScene:
    """Decode a parsed compressed PLY into a validated scene."""
    names = [e.name for e in ply.elements]
    for required in ("chunk", "vertex"):
        if required not in names:
            raise InputError(f"{source}: compressed PLY has no '{required}' element")
    chunk, vertex = ply["chunk"].data, ply["vertex"].data
    chunk_props, vertex_props = set(chunk.dtype.names or ()), set(vertex.dtype.names or ())
    missing = [p for p in CHUNK_GEOMETRY if p not in chunk_props]
    if missing:
        raise InputError(f"{source}: missing chunk properties: {', '.join(missing)}")
    missing = [p for p in PACKED if p not in vertex_props]
    if missing:
        raise InputError(f"{source}: missing vertex properties: {', '.join(missing)}")
    n = len(vertex)
    if n == 0:
        raise InputError(f"{source}: scene has zero Gaussians")
    if len(chunk) * CHUNK_SIZE < n:
        raise InputError(f"{source}: {len(chunk)} chunks cannot hold {n} splats ({CHUNK_SIZE} per chunk)")

    ci = np.arange(n) // CHUNK_SIZE

    def bounds(prefix: str, axes) -> tuple[np.ndarray, np.ndarray]:
        lo = np.stack([_finite(chunk, f"min_{prefix}{a}", source) for a in axes], axis=1)[ci]
        hi = np.stack([_finite(chunk, f"max_{prefix}{a}", source) for a in axes], axis=1)[ci]
        return lo, hi

    packed = {p: _packed(vertex, p, source) for p in PACKED}
    means = _lerp(*bounds("", "xyz"), _unpack_111011(packed["packed_position"]))
    log_scales = _lerp(*bounds("scale_", "xyz"), _unpack_111011(packed["packed_scale"]))
    quats = _unpack_rotation(packed["packed_rotation"])

    c = packed["packed_color"]
    rgb = np.stack([_field(c, 24, 8), _field(c, 16, 8), _field(c, 8, 8)], axis=1)
    if all(p in chunk_props for p in CHUNK_COLOUR):
        rgb = _lerp(*bounds("", "rgb"), rgb)
    sh_dc = (rgb - 0.5) / SH_C0
    opacities = alpha_to_logit(_field(c, 0, 8))

    degree, sh_rest = 0, np.zeros((n, 0, 3))
    if "sh" in names:
        sh = ply["sh"].data
        count = len(sh.dtype.names or ())
        if count % 3:
            raise InputError(f"{source}: sh element has {count} properties, not a multiple of 3")
        k = count // 3
        try:
            degree = sh_degree_from_rest(k)
        except InputError as err:
            raise InputError(f"{source}: sh element's {count} properties match no SH degree 0-3") from err
        missing = [p for p in rest_names(k) if p not in sh.dtype.names]
        if missing:
            raise InputError(f"{source}: missing sh properties: {', '.join(missing)}")
        if len(sh) != n:
            raise InputError(f"{source}: sh element has {len(sh)} rows for {n} splats")
        q = np.stack([np.asarray(sh[p]).astype(np.float64) for p in rest_names(k)], axis=1)
        # splat-transform's mapping: byte centres, with 0 and 255 pinned to the ends of [-4, 4].
        t = np.where(q == 0, 0.0, np.where(q == 255, 1.0, (q + 0.5) / 256.0))
        sh_rest = ((t - 0.5) * 8.0).reshape(n, 3, k).transpose(0, 2, 1)

    return validate_named(make_scene(means, quats, log_scales, opacities, sh_dc, sh_rest, degree), source)


def read_compressed_ply(path: str | os.PathLike) -> GaussianScene:
    """Read a PlayCanvas compressed PLY scene."""
    ply = load_plydata(path)
    if not is_compressed(ply):
        raise InputError(f"{path}: not a compressed PLY (no 'chunk' element)")
    return scene_from_compressed(ply, source=str(path))
