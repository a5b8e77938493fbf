"""INRIA 3DGS PLY: the layout written by the reference training code and read by every viewer.

One ``vertex`` element with float properties ``x y z``, optional normals ``nx ny nz``, ``f_dc_0..2``,
``f_rest_0..3K-1`` (channel-major: the K red coefficients, then green, then blue), ``opacity`` (logit),
``scale_0..2`` (log) and ``rot_0..3`` (w, x, y, z, unnormalised). Any other vertex property is kept in
``scene.extra`` and written back unchanged. Infinite opacity logits and tiny or huge quaternions, which
other tools write, are mapped to what they mean (gspc/io/interop.py); double values beyond float32 are
refused by name.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement

from gspc.atomic import atomic_write
from gspc.errors import InputError
from gspc.io.coordinates import OPENCV, oriented
from gspc.io.interop import finite_opacity_logits, float32_column, normalise_extreme_quaternions
from gspc.scene import GaussianScene, num_sh_rest, sh_degree_from_rest

POSITION = ("x", "y", "z")
NORMALS = ("nx", "ny", "nz")
DC = ("f_dc_0", "f_dc_1", "f_dc_2")
SCALES = ("scale_0", "scale_1", "scale_2")
ROTATION = ("rot_0", "rot_1", "rot_2", "rot_3")
OPACITY = "opacity"


def rest_names(k: int) -> list[str]:
    """Names of the 3K channel-major f_rest properties for K coefficients per channel."""
    return [f"f_rest_{i}" for i in range(3 * k)]


def inria_bytes_per_gaussian(sh_degree: int) -> int:
    """Size of one vertex in the INRIA layout (float32, normals included): 248 at degree 3."""
    return 4 * (3 + 3 + 3 + 3 * num_sh_rest(sh_degree) + 1 + 3 + 4)


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split()) or type(err).__name__


MAX_HEADER_BYTES = 1 << 20  # a PLY header lists elements and properties: kilobytes
_SCALAR_BYTES = {
    **dict.fromkeys(("char", "uchar", "int8", "uint8"), 1),
    **dict.fromkeys(("short", "ushort", "int16", "uint16"), 2),
    **dict.fromkeys(("int", "uint", "float", "int32", "uint32", "float32"), 4),
    **dict.fromkeys(("double", "float64"), 8),
}


def _check_counts(path: Path, head: bytes, size: int) -> None:
    """InputError when the header's element counts need more bytes than the file has, checked before the
    parser allocates arrays of those counts (bench/robustness.md, "Moved from code comments"):
    a binary row takes at least the bytes of its properties (a list at least its count), an ASCII row at
    least two characters per property (a digit and a separator)."""
    end = head.find(b"end_header")
    if end < 0:
        return  # the parser reports a missing or oversized header itself
    lines = head[:end].decode("ascii", "replace").splitlines()
    ascii_body = any(ln.split()[:2] == ["format", "ascii"] for ln in lines if ln.strip())
    need, count, row = 0, 0, 0
    for words in (ln.split() for ln in lines):
        if words[:1] == ["element"] and len(words) == 3 and words[2].isdigit():
            need += count * row
            count, row = int(words[2]), 0
        elif words[:1] == ["property"] and len(words) >= 3:
            kind = words[2] if words[1] == "list" else words[1]
            row += 2 if ascii_body else _SCALAR_BYTES.get(kind, 1)
    need += count * row
    if need > size - end:
        raise InputError(f"{path}: the PLY header declares rows of {need:,} bytes; the file has {size:,}")


def load_plydata(path: str | os.PathLike) -> PlyData:
    """Parse a PLY file fully (no memory map, so truncation is caught here); InputError otherwise."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a PLY file")
    with open(path, "rb") as f:
        if f.read(4) not in (b"ply\n", b"ply\r"):
            raise InputError(f"{path}: not a PLY file (no 'ply' magic line)")
        f.seek(0)
        _check_counts(path, f.read(MAX_HEADER_BYTES), path.stat().st_size)
        f.seek(0)
        try:
            return PlyData.read(f)
        except Exception as err:  # plyfile raises several types (parse errors, ValueError, struct errors)
            raise InputError(f"{path}: unreadable or truncated PLY ({_one_line(err)})") from err


def scene_from_plydata(ply: PlyData, source: str = "PLY") -> GaussianScene:
    """Build a validated scene from a parsed INRIA-layout PLY."""
    names = [e.name for e in ply.elements]
    if "vertex" not in names:
        raise InputError(f"{source}: no 'vertex' element (elements: {', '.join(names) or 'none'})")
    vertex = ply["vertex"]
    data = vertex.data
    props = list(data.dtype.names or ())
    n = len(data)
    if n == 0:
        raise InputError(f"{source}: scene has zero Gaussians")

    rest_present = [p for p in props if p.startswith("f_rest_")]
    if len(rest_present) % 3:
        raise InputError(f"{source}: {len(rest_present)} f_rest properties is not a multiple of 3")
    k = len(rest_present) // 3
    try:
        deg = sh_degree_from_rest(k)
    except InputError as err:
        raise InputError(f"{source}: {len(rest_present)} f_rest properties match no SH degree 0-3") from err

    required = [*POSITION, *DC, *rest_names(k), OPACITY, *SCALES, *ROTATION]
    missing = [p for p in required if p not in props]
    if missing:
        raise InputError(f"{source}: missing vertex properties: {', '.join(missing)}")

    def column(name: str) -> np.ndarray:
        return float32_column(data[name], name, source)

    def stack(cols) -> torch.Tensor:
        return torch.from_numpy(np.stack([column(c) for c in cols], axis=1))

    # Filled column by column: stacking the 3K columns first and then reordering them would hold two more
    # copies of the SH rest, the largest part of a degree-3 scene (bench/scale.md, "Reading").
    rest = np.empty((n, k, 3), np.float32)
    for i, name in enumerate(rest_names(k)):  # channel-major: f_rest_{c K + j} is coefficient j of channel c
        rest[:, i % k, i // k] = column(name)
    sh_rest = torch.from_numpy(rest)
    known = set(required)
    extra = {p: np.array(data[p]) for p in props if p not in known}
    scene = GaussianScene(
        means=stack(POSITION),
        quats=torch.from_numpy(normalise_extreme_quaternions(stack(ROTATION).numpy())),
        log_scales=stack(SCALES),
        opacities=torch.from_numpy(finite_opacity_logits(column(OPACITY))),
        sh_dc=stack(DC),
        sh_rest=sh_rest,
        sh_degree=deg,
        extra=extra,
    )
    try:
        return scene.validate()
    except InputError as err:
        raise InputError(f"{source}: {err}") from err


def read_ply(path: str | os.PathLike) -> GaussianScene:
    """Read an INRIA-layout 3DGS PLY (binary either endianness, or ASCII)."""
    return scene_from_plydata(load_plydata(path), source=str(path))


def _f32(t: torch.Tensor) -> np.ndarray:
    return t.detach().to("cpu", torch.float32).numpy()


def scene_to_vertex_array(scene: GaussianScene) -> np.ndarray:
    """The scene as one structured array in INRIA property order, extras appended."""
    scene.validate()
    n, k = scene.num_gaussians, num_sh_rest(scene.sh_degree)
    columns: list[tuple[str, np.ndarray]] = []
    means = _f32(scene.means)
    columns += [(name, means[:, i]) for i, name in enumerate(POSITION)]
    for name in NORMALS:  # INRIA writes zero normals; keep real ones when a source had them
        columns.append((name, scene.extra[name] if name in scene.extra else np.zeros(n, np.float32)))
    dc = _f32(scene.sh_dc)
    columns += [(name, dc[:, i]) for i, name in enumerate(DC)]
    # Coefficient-major -> channel-major as strided views, not a copy: at SH degree 3 a copy is 180 bytes per
    # Gaussian on top of the scene and the output rows (issue 26 measures a decode's peak memory).
    rest = _f32(scene.sh_rest).transpose(0, 2, 1)  # (n, 3, k)
    columns += [(name, rest[:, i // k, i % k]) for i, name in enumerate(rest_names(k))]
    columns.append((OPACITY, _f32(scene.opacities).reshape(n)))
    scales = _f32(scene.log_scales)
    columns += [(name, scales[:, i]) for i, name in enumerate(SCALES)]
    quats = _f32(scene.quats)
    columns += [(name, quats[:, i]) for i, name in enumerate(ROTATION)]
    taken = {name for name, _ in columns}
    for name, values in scene.extra.items():
        if name in taken:
            continue
        values = np.asarray(values)
        if values.shape != (n,):
            raise InputError(f"extra property {name} has shape {values.shape}, expected ({n},)")
        columns.append((name, values))

    def le(dtype: np.dtype) -> str:
        return np.dtype(dtype).newbyteorder("<").str

    dtype = [(name, le(np.float32) if name in taken else le(values.dtype)) for name, values in columns]
    out = np.empty(n, dtype=dtype)
    for name, values in columns:
        out[name] = values
    return out


def write_ply(scene: GaussianScene, path: str | os.PathLike) -> None:
    """Write ``scene`` as a binary little-endian INRIA PLY, atomically (temp file + rename). A scene that
    states its axis convention is converted to INRIA's, OpenCV's (gspc/io/coordinates.py): PLY states none."""
    path = Path(path)
    vertices = scene_to_vertex_array(oriented(scene, OPENCV))
    element = PlyElement.describe(vertices, "vertex")
    ply = PlyData([element], text=False, byte_order="<")
    atomic_write(path, ply.write)


# --- large scenes: rows read on demand, rows written in pieces --------------------------------------------

_LE_FLOAT = np.dtype("<f4")


class PlyRows:
    """An INRIA PLY of little-endian float32 vertex properties, memory-mapped: columns and rows are read from
    the file when asked for, so a scene larger than memory can be coded tile by tile (gspc/encoder/tiles.py).
    Picklable (it holds the path): a worker process maps the file itself."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = str(path)
        self._data: np.ndarray | None = None
        head, offset, n, names = _binary_float_layout(Path(path))
        self.num_gaussians = n
        self.offset = offset
        self.names = names
        k = len([p for p in names if p.startswith("f_rest_")]) // 3
        self.sh_degree = sh_degree_from_rest(k)
        self.coordinates = None
        required = [*POSITION, *DC, *rest_names(k), OPACITY, *SCALES, *ROTATION]
        missing = [p for p in required if p not in names]
        if missing:
            raise InputError(f"{path}: missing vertex properties: {', '.join(missing)}")

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_data": None}

    @property
    def data(self) -> np.ndarray:
        if self._data is None:
            dtype = np.dtype([(p, _LE_FLOAT) for p in self.names])
            self._data = np.memmap(self.path, dtype, "r", self.offset, (self.num_gaussians,))
        return self._data

    def column(self, names: tuple[str, ...], rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        """The float32 columns ``names`` (N x len) of ``rows``, each checked finite where read."""
        return np.stack([float32_column(np.asarray(self.data[p][rows]), p, self.path) for p in names], 1)

    def positions(self) -> np.ndarray:
        """Every Gaussian's position (N x 3, float64)."""
        return self.column(POSITION).astype(np.float64)

    def log_scales(self) -> np.ndarray:
        """Every Gaussian's log scales (N x 3, float64)."""
        return self.column(SCALES).astype(np.float64)

    def tile(self, rows: np.ndarray) -> tuple[PlyRows, np.ndarray]:
        """What a tile's job carries: this file and the tile's rows (a worker maps the file itself)."""
        return self, rows

    def rows(self, rows: np.ndarray) -> GaussianScene:
        """The Gaussians ``rows`` (input indices) as a validated scene."""
        part = np.asarray(self.data[np.asarray(rows)])
        ply = PlyData([PlyElement.describe(part, "vertex")], text=False, byte_order="<")
        return scene_from_plydata(ply, source=self.path)


def _binary_float_layout(path: Path) -> tuple[bytes, int, int, list[str]]:
    """(header, data offset, vertex count, property names) of a PLY whose only element is ``vertex`` of
    little-endian float32 properties; InputError for any other (those are read whole: gspc/io/__init__.py)."""
    with open(path, "rb") as f:
        head = f.read(MAX_HEADER_BYTES)
    end = head.find(b"end_header\n")
    if not head.startswith(b"ply\n") or end < 0:
        raise InputError(f"{path}: not a PLY file with an end_header line")
    lines = head[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise InputError(f"{path}: not a binary little-endian PLY")
    names, count, elements = [], 0, 0
    for line in lines:
        words = line.split()
        if words[:1] == ["element"]:
            elements += 1
            if len(words) != 3 or words[1] != "vertex" or not words[2].isdigit():
                raise InputError(f"{path}: holds an element other than one vertex element")
            count = int(words[2])
        elif words[:1] == ["property"]:
            if len(words) != 3 or words[1] not in ("float", "float32"):
                raise InputError(f"{path}: vertex property {' '.join(words[1:])} is not a float32")
            names.append(words[2])
    offset = end + len(b"end_header\n")
    if elements != 1 or count == 0:
        raise InputError(f"{path}: no vertex element of Gaussians")
    if path.stat().st_size < offset + count * 4 * len(names):
        raise InputError(f"{path}: truncated PLY (its header declares {count:,} Gaussians)")
    return head[:offset], offset, count, names


def ply_header(n: int, sh_degree: int) -> bytes:
    """The header write_ply writes for ``n`` Gaussians of ``sh_degree`` and no extra property."""
    props = [*POSITION, *NORMALS, *DC, *rest_names(num_sh_rest(sh_degree)), OPACITY, *SCALES, *ROTATION]
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    lines += [f"property float {p}" for p in props]
    return ("\n".join([*lines, "end_header"]) + "\n").encode("ascii")


def write_ply_parts(f, parts, n: int, sh_degree: int) -> int:
    """Write to the open binary file ``f`` the INRIA PLY of ``n`` Gaussians of ``sh_degree`` given as the
    scenes ``parts`` yields (a tiled file's tiles), one at a time: memory follows the largest part. Returns
    the Gaussians written; ValueError where ``parts`` holds another count (the caller's bug)."""
    f.write(ply_header(n, sh_degree))
    written = 0
    for scene in parts:
        if scene.sh_degree != sh_degree or not set(scene.extra) <= set(NORMALS):
            raise ValueError("a part of another SH degree or with extra properties")
        f.write(scene_to_vertex_array(oriented(scene, OPENCV)).tobytes())
        written += scene.num_gaussians
    if written != n:
        raise ValueError(f"wrote {written} Gaussians of a PLY that declares {n}")
    return written
