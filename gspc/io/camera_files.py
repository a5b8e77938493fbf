"""Camera files: the one entry point, :func:`load_cameras`, which tells the formats apart."""

from __future__ import annotations

from pathlib import Path

from gspc.cameras import Camera, sort_cameras
from gspc.errors import InputError
from gspc.io.camera_common import read_json
from gspc.io.cameras_json import parse_inria
from gspc.io.colmap import colmap_files, load_colmap
from gspc.io.transforms import parse_transforms


def load_cameras(path: str | Path, width: int | None = None, height: int | None = None) -> list[Camera]:
    """Cameras from an INRIA ``cameras.json``, a NeRF/instant-ngp ``transforms.json`` or a COLMAP
    sparse model (a folder with cameras/images as .txt or .bin), sorted by name (natural order).

    ``width``/``height`` give the image size for a transforms.json that states none and has no
    readable first image; where the file or image states a size, they must agree with it.
    """
    path = Path(path)
    if (width is None) != (height is None):
        raise InputError("give both width and height, or neither")
    if path.is_dir():
        for sub in (path, path / "sparse" / "0", path / "sparse"):
            if colmap_files(sub) is not None:
                return sort_cameras(load_colmap(sub))
        for name in ("cameras.json", "transforms.json"):
            if (path / name).is_file():
                return load_cameras(path / name, width, height)
        raise InputError(f"{path} holds no cameras.json, transforms.json or COLMAP cameras/images files")
    if path.name in ("cameras.bin", "images.bin", "cameras.txt", "images.txt"):
        return sort_cameras(load_colmap(path.parent))
    if not path.exists():
        raise InputError(f"camera file {path} does not exist")
    data = read_json(path)
    if isinstance(data, list):
        cams = parse_inria(data, path)
    elif isinstance(data, dict) and "frames" in data:
        cams = parse_transforms(data, path, width, height)
    else:
        raise InputError(
            f"{path} is neither an INRIA cameras.json (a list) nor a transforms.json (with 'frames')"
        )
    names = [c.name for c in cams]
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise InputError(f"{path} names image {dup!r} more than once")
    return sort_cameras(cams)
