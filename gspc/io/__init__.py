"""Scene files in and out: INRIA PLY (read and write), PlayCanvas SOG and compressed PLY, Niantic SPZ (read).

``read_scene`` picks the reader from the file's content, not its name: a zip is SOG, a gzip stream or an
``NGSP`` header is SPZ, a PLY with a ``chunk`` element is PlayCanvas compressed PLY, any other PLY is the
INRIA layout.
"""

from __future__ import annotations

import os
from pathlib import Path

from gspc.errors import InputError
from gspc.io.compressed_ply import is_compressed, read_compressed_ply, scene_from_compressed
from gspc.io.ply import load_plydata, read_ply, scene_from_plydata, write_ply
from gspc.io.sog import read_sog
from gspc.io.spz import is_spz, read_spz
from gspc.scene import GaussianScene

ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")

__all__ = ["read_compressed_ply", "read_ply", "read_scene", "read_sog", "read_spz", "write_ply"]


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
