"""Reader for PlayCanvas SOG (version 2): a zip (or a folder) of meta.json plus lossless WebP maps.

Every map holds one Gaussian per pixel, row-major; ``meta.count`` may be smaller than width*height.
  means_l / means_u  RGB: low and high bytes of a 16-bit value per axis, mapped linearly onto
                     [mins, maxs] of the log-transformed position n = sign(x) * ln(1 + |x|).
  quats              RGBA: smallest-three; RGB are the kept components in [-1/sqrt2, 1/sqrt2],
                     A - 252 is the index (into w, x, y, z) of the dropped largest one, taken >= 0.
  scales             RGB: indices into a 256-entry codebook of log scales.
  sh0                RGB: indices into a 256-entry codebook of DC coefficients; A: opacity * 255.
  shN (optional)     labels RG: 16-bit palette index; centroids RGB: indices into a 256-entry codebook,
                     64 palette entries per row, each entry K consecutive pixels (one per coefficient).
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import imagecodecs
import numpy as np

from gspc.codec.quantisers import place_largest
from gspc.errors import CodecError, InputError
from gspc.format.image_headers import coded_size
from gspc.limits import (
    MAX_SOG_MAP_PIXELS,
    MAX_SOG_MEMBER_BYTES,
    MAX_SOG_META_BYTES,
    SOG_MAP_FLOOR,
    SOG_MAX_MEMBER_RATIO,
    SOG_MEMBER_FLOOR,
    SOG_PIXELS_PER_ENTRY,
    max_scene_gaussians,
)
from gspc.scene import GaussianScene, alpha_to_logit, make_scene, num_sh_rest, validate_named

SOG_VERSION = 2
QUAT_TAG_BASE = 252


def _unlog(n: np.ndarray) -> np.ndarray:
    return np.sign(n) * np.expm1(np.abs(n))


@contextmanager
def _loader(path: Path) -> Iterator[Callable[[str], bytes]]:
    """A function returning the bytes of a named member, from a .sog zip or a SOG folder.

    Members are read only when asked for, each after its size (the zip's central directory, or the file's)
    is checked against MAX_SOG_MEMBER_BYTES: an archive's unneeded or oversized members cost nothing.
    """
    if path.is_dir() or path.name == "meta.json":
        folder = path if path.is_dir() else path.parent

        def from_folder(name: str) -> bytes:
            member = folder / name
            if not member.is_file():
                raise InputError(f"{path}: SOG file '{name}' is missing")
            _check_member_size(path, name, member.stat().st_size)
            return member.read_bytes()

        yield from_folder
        return
    try:
        z = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, EOFError, ValueError, NotImplementedError) as err:
        raise InputError(f"{path}: not a readable SOG zip ({err})") from err
    with z:
        infos = {info.filename: info for info in z.infolist() if not info.is_dir()}

        def from_zip(name: str) -> bytes:
            if name not in infos:
                raise InputError(f"{path}: SOG archive has no member '{name}'")
            _check_member_size(path, name, infos[name].file_size, infos[name].compress_size)
            try:
                # zipfile stops at the size the directory states and checks the CRC: no more is read.
                return z.read(infos[name])
            except (zipfile.BadZipFile, OSError, EOFError, ValueError, NotImplementedError) as err:
                raise InputError(f"{path}: SOG member '{name}' does not read ({err})") from err

        yield from_zip


def _check_member_size(path: Path, name: str, size: int, stored: int | None = None) -> None:
    """A member's uncompressed size against the caps; ``stored``: its compressed size in a zip."""
    cap = MAX_SOG_META_BYTES if name == "meta.json" else MAX_SOG_MEMBER_BYTES
    if stored is not None:
        cap = min(cap, max(SOG_MEMBER_FLOOR, SOG_MAX_MEMBER_RATIO * stored))
    if size > cap:
        packed = "" if stored is None else f" ({stored:,} compressed)"
        raise InputError(f"{path}: SOG member '{name}' is {size:,} bytes{packed}; the limit is {cap:,}")


def _meta(path: Path, load: Callable[[str], bytes]) -> dict:
    try:
        meta = json.loads(load("meta.json"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(f"{path}: meta.json is not valid JSON ({err})") from err
    if not isinstance(meta, dict):
        raise InputError(f"{path}: meta.json is not a JSON object")
    version = meta.get("version")
    if version != SOG_VERSION:
        raise InputError(f"{path}: SOG version {version!r} is not supported (only version {SOG_VERSION})")
    for key in ("count", "means", "scales", "quats", "sh0"):
        if key not in meta:
            raise InputError(f"{path}: meta.json lacks '{key}'")
    count = meta["count"]
    if not isinstance(count, int) or isinstance(count, bool) or count < 0:
        raise InputError(f"{path}: meta.json count {count!r} is not a non-negative integer")
    if count == 0:
        raise InputError(f"{path}: scene has zero Gaussians")
    if count > MAX_SOG_MAP_PIXELS:
        raise InputError(f"{path}: meta.json count {count:,} exceeds the limit {MAX_SOG_MAP_PIXELS:,}")
    # A lossless WebP of one colour is tiny whatever its size: the count is bounded by the archive's bytes
    # before any map is decoded (gspc/limits.py).
    size = _source_bytes(path)
    if count > max_scene_gaussians(size):
        raise InputError(
            f"{path}: meta.json count {count:,} is more than a {size:,}-byte SOG may hold (at most "
            f"{max_scene_gaussians(size):,})"
        )
    return meta


def _source_bytes(path: Path) -> int:
    """Bytes of a SOG: the zip's, or those of the regular files in its folder."""
    folder = path if path.is_dir() else path.parent if path.name == "meta.json" else None
    if folder is None:
        return path.stat().st_size
    return sum(p.stat().st_size for p in folder.iterdir() if p.is_file())


def _files(path: Path, meta: dict, key: str, n: int) -> list[str]:
    files = meta[key].get("files") if isinstance(meta[key], dict) else None
    if not isinstance(files, list) or len(files) < n or not all(isinstance(f, str) for f in files[:n]):
        raise InputError(f"{path}: meta.json '{key}.files' must list {n} file name(s)")
    return files[:n]


# Bounds on meta.json's numbers, checked before any arithmetic so that huge finite values (1e308) give this
# error, not numpy overflow warnings and then a blame on the decoded scene (issue 26): codebook entries must
# fit float32 (the scene's type), and the log-transformed position bounds must expand to float32 positions
# (e^88 - 1 = 1.65e38, under float32's 3.4e38).
FLOAT32_MAX = float(np.finfo(np.float32).max)
MAX_LOG_POSITION = 88.0


def _floats(
    path: Path, meta: dict, key: str, field: str, length: int | None, bound: float = FLOAT32_MAX
) -> np.ndarray:
    try:
        values = np.asarray(meta[key][field], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as err:
        raise InputError(f"{path}: meta.json '{key}.{field}' is missing or not numeric") from err
    if values.ndim != 1 or (length is not None and len(values) != length):
        raise InputError(f"{path}: meta.json '{key}.{field}' must be a list of {length} numbers")
    if not np.isfinite(values).all():
        raise InputError(f"{path}: meta.json '{key}.{field}' has NaN or Inf values")
    if values.size and np.abs(values).max() > bound:
        raise InputError(f"{path}: meta.json '{key}.{field}' holds a value beyond +-{bound:g}")
    return values


def _check_map_size(path: Path, name: str, data: bytes, entries: int) -> None:
    """A WebP map's declared size, before decoding, against the entries it holds (gspc/limits.py)."""
    try:
        w, h = coded_size("webp", data)
    except CodecError:
        raise InputError(f"{path}: SOG image '{name}' is not a WebP image with a size header") from None
    allowed = min(MAX_SOG_MAP_PIXELS, max(SOG_MAP_FLOOR, SOG_PIXELS_PER_ENTRY * entries))
    if w * h > allowed:
        raise InputError(
            f"{path}: SOG image '{name}' is {w}x{h} = {w * h:,} pixels for {entries:,} entries; the limit is "
            f"{allowed:,}"
        )


def _pixels(
    path: Path, load: Callable[[str], bytes], name: str, count: int | None, entries: int | None = None
) -> np.ndarray:
    """Decode a WebP map to RGBA uint8; the first ``count`` pixels in row-major order if given.

    ``entries`` (default ``count``): how many pixels the map needs, which bounds its declared size."""
    data = load(name)
    _check_map_size(path, name, data, entries if entries is not None else count or 0)
    try:
        img = imagecodecs.webp_decode(data, hasalpha=True)
    except InputError:
        raise
    except Exception as err:  # imagecodecs raises WebpError (and others) on corrupt data
        raise InputError(f"{path}: cannot decode SOG image '{name}' ({err})") from err
    if img.ndim != 3 or img.shape[2] != 4:
        raise InputError(f"{path}: SOG image '{name}' has shape {img.shape}, expected (H, W, 4)")
    if count is None:
        return img
    flat = img.reshape(-1, 4)
    if len(flat) < count:
        raise InputError(f"{path}: SOG image '{name}' has {len(flat)} pixels for {count} Gaussians")
    return flat[:count]


def _quats(q: np.ndarray, path: Path) -> np.ndarray:
    mode = q[:, 3].astype(np.int64) - QUAT_TAG_BASE
    if ((mode < 0) | (mode > 3)).any():
        bad = int(((mode < 0) | (mode > 3)).sum())
        raise InputError(f"{path}: {bad} quaternion(s) have an invalid mode byte (not 252-255)")
    abc = (q[:, :3].astype(np.float64) / 255.0 * 2.0 - 1.0) / math.sqrt(2.0)
    # Component order is rot_0..rot_3 (w, x, y, z); ``mode`` names the dropped one, as in gspc's codec.
    return place_largest(mode, abc)


def _sh_rest(path: Path, load: Callable[[str], bytes], meta: dict, count: int) -> tuple[np.ndarray, int]:
    shn = meta.get("shN")
    if not shn:
        return np.zeros((count, 0, 3)), 0
    if not isinstance(shn, dict):
        raise InputError(f"{path}: meta.json 'shN' is not an object")
    bands, palette = shn.get("bands"), shn.get("count")
    if bands not in (1, 2, 3):
        raise InputError(f"{path}: meta.json shN.bands {bands!r} is not 1, 2 or 3")
    if not isinstance(palette, int) or not 1 <= palette <= 65536:
        raise InputError(f"{path}: meta.json shN.count {palette!r} is not in 1-65536")
    k = num_sh_rest(bands)
    codebook = _floats(path, meta, "shN", "codebook", 256)
    centroids_name, labels_name = _files(path, meta, "shN", 2)
    centroids = _pixels(path, load, centroids_name, None, 64 * k * ((palette + 63) // 64))
    labels = _pixels(path, load, labels_name, count)
    index = labels[:, 0].astype(np.int64) | (labels[:, 1].astype(np.int64) << 8)
    if (index >= palette).any():
        bad = int((index >= palette).sum())
        raise InputError(f"{path}: {bad} SH labels exceed the palette size {palette}")
    rows_needed = (palette + 63) // 64
    if centroids.shape[0] < rows_needed or centroids.shape[1] < 64 * k:
        raise InputError(
            f"{path}: SH centroid image {centroids.shape[1]}x{centroids.shape[0]} is too small "
            f"for {palette} entries of {k} coefficients"
        )
    # Palette entry e, coefficient c lives at pixel (x = (e % 64) * k + c, y = e // 64).
    entries = centroids[:rows_needed, : 64 * k, :3].reshape(rows_needed * 64, k, 3)[:palette]
    table = codebook[entries]  # (palette, K, 3) coefficient-major, as GaussianScene wants
    return table[index], bands


def read_sog(path: str | os.PathLike) -> GaussianScene:
    """Read a PlayCanvas SOG scene (.sog zip, a folder holding meta.json, or the meta.json itself)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    with _loader(path) as load:
        return _read(path, load)


def _read(path: Path, load: Callable[[str], bytes]) -> GaussianScene:
    meta = _meta(path, load)
    count = meta["count"]

    lo_name, hi_name = _files(path, meta, "means", 2)
    lo = _pixels(path, load, lo_name, count)[:, :3].astype(np.int64)
    hi = _pixels(path, load, hi_name, count)[:, :3].astype(np.int64)
    mins = _floats(path, meta, "means", "mins", 3, MAX_LOG_POSITION)
    maxs = _floats(path, meta, "means", "maxs", 3, MAX_LOG_POSITION)
    t = (lo | (hi << 8)) / 65535.0
    means = _unlog(mins + (maxs - mins) * t)

    quats = _quats(_pixels(path, load, _files(path, meta, "quats", 1)[0], count), path)

    scale_book = _floats(path, meta, "scales", "codebook", 256)
    log_scales = scale_book[_pixels(path, load, _files(path, meta, "scales", 1)[0], count)[:, :3]]

    colour_book = _floats(path, meta, "sh0", "codebook", 256)
    sh0 = _pixels(path, load, _files(path, meta, "sh0", 1)[0], count)
    sh_dc = colour_book[sh0[:, :3]]
    opacities = alpha_to_logit(sh0[:, 3] / 255.0)

    sh_rest, degree = _sh_rest(path, load, meta, count)

    return validate_named(make_scene(means, quats, log_scales, opacities, sh_dc, sh_rest, degree), path)
