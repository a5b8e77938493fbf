"""Scene files in and out: INRIA PLY, Niantic SPZ and glTF binary with KHR_gaussian_splatting (read and
write, .glb write only), PlayCanvas SOG and compressed PLY (read).

``read_scene`` picks the reader from the file's content, not its name: a zip is SOG, a gzip stream or an
``NGSP`` header is SPZ, a PLY with a ``chunk`` element is PlayCanvas compressed PLY, any other PLY is the
INRIA layout. ``write_scene`` picks the writer from the output's extension (``scene_writer``); a name
without one, such as /dev/null or a named pipe, gets the INRIA PLY.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from gspc.errors import InputError
from gspc.io.compressed_ply import is_compressed, read_compressed_ply, scene_from_compressed
from gspc.io.glb import write_glb
from gspc.io.ply import load_plydata, read_ply, scene_from_plydata, write_ply
from gspc.io.sog import read_sog
from gspc.io.spz import is_spz, read_spz
from gspc.io.spz_writer import write_spz
from gspc.scene import GaussianScene

ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")
SceneWriter = Callable[[GaussianScene, "str | os.PathLike"], None]
WRITERS: dict[str, SceneWriter] = {".ply": write_ply, ".spz": write_spz, ".glb": write_glb}
DEFAULT_WRITER = write_ply  # outputs without an extension

__all__ = [
    "read_compressed_ply",
    "read_ply",
    "read_scene",
    "read_sog",
    "read_spz",
    "scene_writer",
    "write_glb",
    "write_ply",
    "write_scene",
    "write_spz",
]


def read_scene(path: str | os.PathLike) -> GaussianScene:
    """Read a scene from any supported file (or a SOG folder); raises InputError on bad input."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if path.is_dir():
        if (path / "meta.json").is_file():
            return read_sog(path)
        raise InputError(f"{path}: is a directory without a SOG meta.json")
    with open(path, "rb") as f:
        head = f.read(4)
    if head in ZIP_MAGIC or path.name == "meta.json":
        return read_sog(path)
    if is_spz(head) or path.suffix.lower() == ".spz":
        return read_spz(path)
    if head[:3] == b"ply":
        ply = load_plydata(path)
        if is_compressed(ply):
            return scene_from_compressed(ply, source=str(path))
        return scene_from_plydata(ply, source=str(path))
    if not head:
        raise InputError(f"{path}: file is empty")
    raise InputError(f"{path}: unrecognised scene file (expected a PLY, a SOG zip or an SPZ file)")


def scene_writer(path: str | os.PathLike) -> SceneWriter:
    """The writer for an output path, by its extension (case ignored); InputError naming the choices for an
    extension gspc does not write. Callers look it up before any work, so a long decode does not end in it."""
    suffix = Path(path).suffix.lower()
    if not suffix:
        return DEFAULT_WRITER
    if suffix not in WRITERS:
        *first, last = WRITERS
        choices = f"{', '.join(first)} or {last}"
        raise InputError(f"{path}: gspc does not write '{suffix}' files; name the output {choices}")
    return WRITERS[suffix]


def write_scene(scene: GaussianScene, path: str | os.PathLike) -> None:
    """Write ``scene`` in the format its output's extension names, atomically."""
    scene_writer(path)(scene, path)
