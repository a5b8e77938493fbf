"""Reader for Niantic SPZ, versions 2, 3 and 4: fixed-point and 8-bit attributes, gzip or zstd.

Versions 2 and 3 are one gzip stream: a 16-byte header, optional extension records (flags & 2), then the
attribute blocks back to back. Version 4 keeps a 32-byte header in the clear, then extension records
(bytes 32 to ``toc_offset``), a table of contents of ``(compressed, uncompressed)`` uint64 sizes, one per
stream, and one zstd frame per non-empty attribute block. All integers are little-endian.

  16-byte header   uint32 magic 0x5053474E ("NGSP"), uint32 version, uint32 count, uint8 sh_degree,
                   uint8 fractional_bits, uint8 flags (1: antialiased, 2: has extensions), uint8 reserved
  32-byte header   the same, the reserved byte being the stream count, then uint32 toc_offset, 12 reserved
  positions        3 x 24-bit two's complement per Gaussian, value = integer / 2^fractional_bits
  alphas           1 byte: alpha * 255
  colours          3 bytes: 0.15 * f_dc * 255 + 127.5 (SPZ scales DC by 0.15, not SH C0, so colours a
                   little outside [0, 1] survive)
  scales           3 bytes: (log scale + 10) * 16
  rotations        version 2: 3 bytes x, y, z as (q + 1) * 127.5 of the unit quaternion with w >= 0;
                   version 3+: uint32 smallest-three: bits 31-30 index (x, y, z, w order) of the largest
                   component, then for the other three in order, 10 bits each: sign bit, 9-bit magnitude
                   of |q| / sqrt(1/2) * 511
  sh rest          K x 3 bytes (coefficient-major, colour channel innermost): (byte - 128) / 128. Writers
                   may zero low bits (fewer effective bits); the stored width is always 8.

Extension records (flags & 2) are ``uint32 type, uint32 length, payload``: in versions 2-3 after the
attribute blocks, inside the gzip stream; in version 4 between the header and the table of contents.

Coordinates are returned as stored. A coordinate-system record (type 0xADBE0003, SPZ_ADOBE_coordinate_system:
a uint32, a convention's number 1-16 in gspc/format/coordinates.py's order) states the convention the data
is in, and becomes the scene's ``coordinates``. Without one a file states nothing gspc trusts: Niantic's
library calls the default RUB, but its own ply_to_spz, splat-transform and spz-js store a PLY's coordinates
unchanged and viewers read such files as they read PLY (bench/outputs.md, "Coordinate conventions"), so gspc
leaves the scene unstated and a PLY -> SPZ -> gspc round trip through those tools keeps the scene in place.
"""

from __future__ import annotations

import io
import math
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zstandard

from gspc.errors import InputError
from gspc.format.coordinates import CONVENTIONS
from gspc.limits import max_scene_gaussians
from gspc.scene import GaussianScene, alpha_to_logit, make_scene, num_sh_rest, validate_named

MAGIC = 0x5053474E
NGSP = struct.pack("<I", MAGIC)  # what a version-4 file starts with
GZIP_MAGIC = b"\x1f\x8b"
SUPPORTED_VERSIONS = (2, 3, 4)
LEGACY_HEADER = struct.Struct("<IIIBBBB")
V4_HEADER = struct.Struct("<IIIBBBBI12s")
TOC_ENTRY = struct.Struct("<QQ")
EXTENSION_RECORD = struct.Struct("<II")

FLAG_ANTIALIASED = 0x1
FLAG_EXTENSIONS = 0x2
# Adobe's SH-quantisation extension rescales the SH bytes onto a stored [min, max]; gspc cannot honour it.
SH_QUANTISATION_EXTENSION = 0xADBE0001
# Adobe's coordinate-system record: the convention the stored data is in (one uint32, 1-16).
COORDINATE_SYSTEM_EXTENSION = 0xADBE0003
COORDINATE_SYSTEM_RECORD = struct.Struct("<III")  # type, length (4), convention number

COLOUR_SCALE = 0.15
MAX_FRACTIONAL_BITS = 24
MAX_SPZ_DEGREE = 4  # the format's limit; gspc itself stops at 3
# Gaussian counts beyond this are refused before anything is allocated (far beyond the largest published
# scenes); the per-file bound below usually bites first.
MAX_POINTS = 1 << 27
# Neither deflate nor zstd at the settings SPZ writers use expands data more than about 1032:1, so a count
# needing more decompressed bytes than this times the file size is a lie (a zip bomb or a corrupt header).
MAX_EXPANSION = 1032
# Room for extension records inside a legacy gzip stream (their length is only known after inflating).
MAX_EXTENSION_BYTES = 1 << 16


@dataclass(frozen=True)
class SpzHeader:
    version: int
    num_points: int
    sh_degree: int
    fractional_bits: int
    flags: int

    @property
    def antialiased(self) -> bool:
        """Trained with Mip-Splatting's antialiasing; gspc renders without it and only reports it."""
        return bool(self.flags & FLAG_ANTIALIASED)

    @property
    def has_extensions(self) -> bool:
        return bool(self.flags & FLAG_EXTENSIONS)

    def block_sizes(self) -> list[tuple[str, int]]:
        """Bytes of each attribute block, in file order."""
        n, k = self.num_points, num_sh_rest(self.sh_degree)
        rotation = 3 if self.version == 2 else 4
        return [
            ("positions", 9 * n),
            ("alphas", n),
            ("colours", 3 * n),
            ("scales", 3 * n),
            ("rotations", rotation * n),
            ("sh", 3 * k * n),
        ]

    def payload_size(self) -> int:
        return sum(size for _, size in self.block_sizes())


def _check_header(h: SpzHeader, magic: int, file_size: int, source: object) -> None:
    if magic != MAGIC:
        raise InputError(f"{source}: not an SPZ file (magic 0x{magic:08x}, expected 0x{MAGIC:08x})")
    if h.version not in SUPPORTED_VERSIONS:
        raise InputError(f"{source}: SPZ version {h.version} is not supported (versions 2, 3 and 4 are)")
    if h.num_points == 0:
        raise InputError(f"{source}: scene has zero Gaussians")
    if h.sh_degree > MAX_SPZ_DEGREE:
        raise InputError(f"{source}: SPZ header declares SH degree {h.sh_degree} (the format allows 0-4)")
    if h.sh_degree > 3:
        raise InputError(f"{source}: SH degree {h.sh_degree} is not supported (gspc reads degrees 0-3)")
    if h.fractional_bits > MAX_FRACTIONAL_BITS:
        raise InputError(f"{source}: {h.fractional_bits} fractional position bits (positions have 24 in all)")
    # Both rules before anything is inflated: what the streams can expand to, and what a file of this size
    # may ask a reader to hold (gspc/limits.py).
    if (
        h.num_points > MAX_POINTS
        or h.payload_size() > MAX_EXPANSION * file_size + 4096
        or h.num_points > max_scene_gaussians(file_size)
    ):
        raise InputError(
            f"{source}: header declares {h.num_points:,} Gaussians, more than a {file_size:,}-byte SPZ "
            "file can hold (gspc/limits.py)"
        )


def _read_extensions(block: bytes, source: object) -> str | None:
    """Walk ``type, length, payload`` records: the coordinate convention a record states (None: none
    stated); refuses the record gspc cannot honour and any malformed block; skips the others."""
    at, coordinates = 0, None
    while at < len(block):
        if at + EXTENSION_RECORD.size > len(block):
            raise InputError(f"{source}: SPZ extension block ends inside a record header")
        kind, length = EXTENSION_RECORD.unpack_from(block, at)
        if kind == SH_QUANTISATION_EXTENSION:
            raise InputError(f"{source}: SPZ uses the SH-quantisation extension 0xADBE0001, not supported")
        payload = block[at + EXTENSION_RECORD.size : at + EXTENSION_RECORD.size + length]
        at += EXTENSION_RECORD.size + length
        if at > len(block):
            raise InputError(f"{source}: SPZ extension 0x{kind:08x} runs past the extension block")
        if kind == COORDINATE_SYSTEM_EXTENSION:
            coordinates = _coordinate_system(payload, source)
    return coordinates


def _coordinate_system(payload: bytes, source: object) -> str | None:
    """The convention a coordinate-system record names; 0 (UNSPECIFIED) is, as Niantic reads it, no record."""
    if len(payload) != 4:
        raise InputError(f"{source}: SPZ coordinate-system record holds {len(payload)} bytes, not 4")
    (number,) = struct.unpack("<I", payload)
    if number > len(CONVENTIONS):
        raise InputError(
            f"{source}: SPZ coordinate-system record names system {number}, not one of 1-{len(CONVENTIONS)}"
        )
    return CONVENTIONS[number - 1] if number else None


def _inflate_legacy(data: bytes, source: object) -> tuple[SpzHeader, bytes, str | None]:
    """Header, attribute bytes and stated convention of a gzip SPZ; never inflates more than the header
    implies."""
    inflater = zlib.decompressobj(16 + zlib.MAX_WBITS)
    try:
        head = inflater.decompress(data, LEGACY_HEADER.size)
        if len(head) < LEGACY_HEADER.size:
            raise InputError(f"{source}: truncated SPZ file (gzip stream ends inside the 16-byte header)")
        magic, version, count, degree, frac, flags, _reserved = LEGACY_HEADER.unpack(head)
        header = SpzHeader(version, count, degree, frac, flags)
        if magic == MAGIC and version == 4:
            raise InputError(f"{source}: SPZ version {version} inside gzip (version 4 files are zstd)")
        _check_header(header, magic, len(data), source)
        expected = header.payload_size()
        limit = expected + (MAX_EXTENSION_BYTES if header.has_extensions else 0)
        parts, got = [], 0
        tail = inflater.unconsumed_tail
        while not inflater.eof and got <= limit:
            chunk = inflater.decompress(tail, limit + 1 - got)
            tail = inflater.unconsumed_tail
            if not chunk and not tail:
                break
            parts.append(chunk)
            got += len(chunk)
    except zlib.error as err:
        raise InputError(f"{source}: corrupt gzip stream in SPZ file ({err})") from err
    body = b"".join(parts)
    if got > limit:
        raise InputError(f"{source}: gzip stream holds more than the {expected:,} bytes the header implies")
    if not inflater.eof:
        raise InputError(f"{source}: truncated SPZ file (gzip stream ends early)")
    if len(body) < expected:
        raise InputError(f"{source}: truncated SPZ data ({len(body):,} of {expected:,} bytes)")
    # Extension records follow the attribute blocks (present only with the extension flag: ``limit``).
    return header, body[:expected], _read_extensions(body[expected:], source)


def _unzstd(frame: bytes, size: int, name: str, source: object) -> bytes:
    """Decompress one zstd frame of exactly ``size`` bytes, reading at most one byte more."""
    try:
        reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(frame), read_across_frames=False)
        out = bytearray()
        while len(out) <= size:
            chunk = reader.read(size + 1 - len(out))
            if not chunk:
                break
            out += chunk
    except zstandard.ZstdError as err:
        raise InputError(f"{source}: corrupt zstd stream for SPZ {name} ({err})") from err
    if len(out) != size:
        raise InputError(f"{source}: SPZ {name} stream decompresses to {len(out):,} bytes, expected {size:,}")
    return bytes(out)


def _read_v4(data: bytes, source: object) -> tuple[SpzHeader, bytes, str | None]:
    if len(data) < V4_HEADER.size:
        raise InputError(f"{source}: truncated SPZ file ({len(data)} bytes, the header alone is 32)")
    magic, version, count, degree, frac, flags, streams, toc, _ = V4_HEADER.unpack_from(data)
    if version < 4 and version in SUPPORTED_VERSIONS:
        raise InputError(f"{source}: SPZ version {version} with a plain header (versions 2-3 are gzip)")
    header = SpzHeader(version, count, degree, frac, flags)
    _check_header(header, magic, len(data), source)
    blocks = [(name, size) for name, size in header.block_sizes() if size]
    if streams == 6 and len(blocks) == 5:
        blocks.append(("sh", 0))  # a writer may list the empty SH stream
    if streams != len(blocks):
        raise InputError(f"{source}: SPZ lists {streams} streams, expected {len(blocks)}")
    toc_end = toc + streams * TOC_ENTRY.size
    if toc < V4_HEADER.size or toc_end > len(data):
        raise InputError(f"{source}: SPZ table of contents at byte {toc} lies outside the file")
    coordinates = _read_extensions(data[V4_HEADER.size : toc], source) if header.has_extensions else None
    at, out = toc_end, []
    for i, (name, size) in enumerate(blocks):
        packed, unpacked = TOC_ENTRY.unpack_from(data, toc + i * TOC_ENTRY.size)
        if unpacked != size:
            raise InputError(f"{source}: SPZ {name} stream holds {unpacked:,} bytes, expected {size:,}")
        if packed > len(data) - at:
            raise InputError(f"{source}: truncated SPZ file ({name} stream runs past the end)")
        if size:
            out.append(_unzstd(data[at : at + packed], size, name, source))
        at += packed
    if at != len(data):
        raise InputError(f"{source}: {len(data) - at:,} bytes after the last SPZ stream")
    return header, b"".join(out), coordinates


def _int24(raw: np.ndarray) -> np.ndarray:
    b = raw.astype(np.int32)
    v = b[..., 0] | (b[..., 1] << 8) | (b[..., 2] << 16)
    return np.where(v >= 1 << 23, v - (1 << 24), v)


def _rotations_v2(raw: np.ndarray) -> np.ndarray:
    xyz = raw.astype(np.float64) / 127.5 - 1.0
    w = np.sqrt(np.maximum(0.0, 1.0 - (xyz * xyz).sum(1)))
    return np.concatenate([w[:, None], xyz], axis=1)


def _rotations_v3(raw: np.ndarray) -> np.ndarray:
    word = raw.astype(np.uint32)
    word = word[:, 0] | (word[:, 1] << 8) | (word[:, 2] << 16) | (word[:, 3] << 24)
    largest = (word >> 30).astype(np.int64)
    xyzw = np.zeros((len(word), 4))
    rows = np.arange(len(word))
    # The last kept component sits in the lowest 10 bits: walk the slots from w down to x.
    for slot in range(3, -1, -1):
        kept = largest != slot
        field = word & 0x3FF
        value = (field & 0x1FF).astype(np.float64) / 511.0 * math.sqrt(0.5)
        value = np.where(field & 0x200, -value, value)
        xyzw[kept, slot] = value[kept]
        word = np.where(kept, word >> 10, word)
    xyzw[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - (xyzw * xyzw).sum(1)))
    return xyzw[:, [3, 0, 1, 2]]


def _scene(header: SpzHeader, payload: bytes, coordinates: str | None, source: object) -> GaussianScene:
    n, k = header.num_points, num_sh_rest(header.sh_degree)
    blocks, at = {}, 0
    for name, size in header.block_sizes():
        blocks[name] = np.frombuffer(payload, np.uint8, size, at).reshape(n, size // n)
        at += size
    means = _int24(blocks["positions"].reshape(n, 3, 3)) / float(1 << header.fractional_bits)
    opacities = alpha_to_logit(blocks["alphas"][:, 0] / 255.0)
    sh_dc = (blocks["colours"] / 255.0 - 0.5) / COLOUR_SCALE
    log_scales = blocks["scales"] / 16.0 - 10.0
    rot = blocks["rotations"]
    quats = _rotations_v2(rot) if header.version == 2 else _rotations_v3(rot)
    sh_rest = (blocks["sh"].reshape(n, k, 3).astype(np.float64) - 128.0) / 128.0
    scene = make_scene(means, quats, log_scales, opacities, sh_dc, sh_rest, header.sh_degree)
    scene.coordinates = coordinates
    return validate_named(scene, source)


def decode_spz(data: bytes, source: object = "SPZ") -> tuple[SpzHeader, GaussianScene]:
    """Header and scene of SPZ bytes; InputError (naming ``source``) on anything malformed."""
    if data[:4] == NGSP:
        header, payload, coordinates = _read_v4(data, source)
    elif data[:2] == GZIP_MAGIC:
        header, payload, coordinates = _inflate_legacy(data, source)
    elif not data:
        raise InputError(f"{source}: file is empty")
    elif len(data) < len(NGSP) and NGSP.startswith(data):
        raise InputError(f"{source}: truncated SPZ file ({len(data)} bytes)")
    else:
        raise InputError(f"{source}: not an SPZ file (neither gzip nor an NGSP header)")
    return header, _scene(header, payload, coordinates, source)


def is_spz(head: bytes) -> bool:
    """Whether a file's first bytes look like SPZ (gspc reads no other gzip or NGSP files)."""
    return head[:4] == NGSP or head[:2] == GZIP_MAGIC


def read_spz(path: str | os.PathLike) -> GaussianScene:
    """Read a Niantic SPZ scene (version 2, 3 or 4)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file" if not path.exists() else f"{path}: is not a file")
    return decode_spz(path.read_bytes(), path)[1]
