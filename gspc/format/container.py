"""The .gspc container: a msgpack header and typed, checksummed chunks, exactly as spec/gspc-format.md says.

It knows nothing of the codecs whose payloads it carries. Reading checks every length against the bytes that
remain before it slices or allocates anything, so memory stays proportional to the file size.
"""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import msgpack

from gspc.atomic import atomic_write_bytes
from gspc.errors import FormatError, InputError
from gspc.format.chunks import KNOWN_TYPES  # the registry of chunk types; the default of unpack and read

MAGIC = b"\x89GSPC\r\n\x1a"
END_MARKER = b"GEND"
VERSION = (1, 4)  # what this module writes; it reads every 1.x
PREAMBLE = struct.Struct("<8sHHII")  # magic, major, minor, header_length, header_crc
TRAILER = struct.Struct("<4sI")  # end marker, file_crc
ALIGN = 8
FLAG_REQUIRED = 1

MAX_HEADER_LENGTH = 1 << 24
MAX_CHUNKS = 65535
MAX_CHUNK_LENGTH = (1 << 48) - 1
MAX_U32 = (1 << 32) - 1
MAX_DEPTH = 32

_TYPE_CHARS = frozenset(b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789")
_ENTRY_KEYS = ("type", "flags", "index", "length", "crc")


class BadMagic(FormatError):
    """The file does not start with the gspc magic, or does not end with the end marker."""


class UnsupportedVersion(FormatError):
    """The major format version is not one this reader implements."""


class Truncated(FormatError):
    """The file ends before a region it declares (or a length field points past the end)."""


class ChecksumMismatch(FormatError):
    """A CRC-32 (header, chunk or whole file) does not match the bytes."""


class BadHeader(FormatError):
    """The header is not valid msgpack or breaks the header rules."""


class LimitExceeded(FormatError):
    """A length or count is beyond the limits of the spec."""


class DuplicateChunk(FormatError):
    """Two chunk table entries share a type and an index."""


class UnknownRequiredChunk(FormatError):
    """A chunk marked required has a type this reader does not know."""


class BadPadding(FormatError):
    """An alignment padding byte is not zero."""


class TrailingBytes(FormatError):
    """Bytes follow the trailer."""


@dataclass(frozen=True)
class Chunk:
    type: str  # 4 ASCII letters or digits, e.g. "POSN"
    payload: bytes
    required: bool = True
    index: int = 0  # distinguishes repeated types, e.g. one "RESI" per side-information view


@dataclass(frozen=True)
class Container:
    version: tuple[int, int]
    header: dict
    chunks: list[Chunk]
    skipped: list[Chunk] = field(
        default_factory=list
    )  # unknown optional chunks, verified but not interpreted
    file_size: int = 0  # bytes of the whole file
    header_length: int = 0  # bytes of the msgpack header (spec section 2)

    def find(self, type: str, index: int = 0) -> Chunk | None:
        """The chunk with this type and index, or None."""
        return next((c for c in self.chunks if c.type == type and c.index == index), None)


@dataclass(frozen=True)
class _Entry:
    type: str
    flags: int
    index: int
    length: int
    crc: int
    offset: int  # of the payload in the file

    @property
    def name(self) -> str:
        return f"{self.type}#{self.index}"

    @property
    def required(self) -> bool:
        return bool(self.flags & FLAG_REQUIRED)


@dataclass(frozen=True)
class _Parsed:
    version: tuple[int, int]
    header_length: int
    meta: dict
    entries: list[_Entry]
    data: bytes


def crc32(data: bytes | memoryview) -> int:
    """CRC-32/ISO-HDLC (zlib, PNG): polynomial 0x04C11DB7 reflected, init and final XOR 0xFFFFFFFF."""
    return zlib.crc32(data) & 0xFFFFFFFF


def _align(n: int) -> int:
    return (n + ALIGN - 1) // ALIGN * ALIGN


def _valid_type(t: object) -> bool:
    return isinstance(t, str) and len(t) == 4 and t.isascii() and all(ord(c) in _TYPE_CHARS for c in t)


def _is_int(x: object) -> bool:
    return type(x) is int  # bool is an int subclass in Python but not a msgpack integer


# ----------------------------------------------------------------------------------------------- writing


def _check_value(obj: Any, path: str) -> None:
    """Refuse (ValueError) header values a gspc reader would refuse: keeps writers honest."""
    stack = [(obj, path, 1)]
    while stack:
        value, where, depth = stack.pop()
        if depth > MAX_DEPTH and isinstance(value, (list, tuple, dict)):
            raise ValueError(f"header nests deeper than {MAX_DEPTH} levels at {where}")
        if value is None or isinstance(value, (bool, int, float, str, bytes)):
            if _is_int(value) and not -(1 << 63) <= value < (1 << 64):
                raise ValueError(f"header integer at {where} does not fit in 64 bits")
            continue
        if isinstance(value, (list, tuple)):
            stack.extend((v, f"{where}[{i}]", depth + 1) for i, v in enumerate(value))
        elif isinstance(value, dict):
            for k, v in value.items():
                if not isinstance(k, str):
                    raise ValueError(f"header map key {k!r} at {where} is not a str")
                stack.append((v, f"{where}.{k}", depth + 1))
        else:
            raise ValueError(f"header value at {where} has type {type(value).__name__}, not a msgpack type")


def pack(header: dict, chunks: list[Chunk], version: tuple[int, int] = VERSION) -> bytes:
    """The bytes of a gspc file holding `header` (the codecs' metadata) and `chunks`, marked with
    `version` (default the newest this module writes; spec section 3: a writer marks the lowest minor
    version whose features the file uses)."""
    if not isinstance(header, dict):
        raise ValueError(f"header must be a dict, not {type(header).__name__}")
    _check_value({"meta": header}, "header")
    if len(chunks) > MAX_CHUNKS:
        raise ValueError(f"{len(chunks)} chunks; a gspc file holds at most {MAX_CHUNKS}")
    seen: set[tuple[str, int]] = set()
    table = []
    for c in chunks:
        if not isinstance(c.payload, (bytes, bytearray)):  # len() of other buffers need not count bytes
            raise ValueError(f"chunk {c.type} payload is a {type(c.payload).__name__}, not bytes")
        if not _valid_type(c.type):
            raise ValueError(f"chunk type {c.type!r} is not 4 ASCII letters or digits")
        if not (_is_int(c.index) and 0 <= c.index <= MAX_U32):
            raise ValueError(f"chunk {c.type} index {c.index!r} is not in 0..{MAX_U32}")
        if (c.type, c.index) in seen:
            raise ValueError(f"chunk {c.type}#{c.index} appears twice")
        if len(c.payload) > MAX_CHUNK_LENGTH:
            raise ValueError(f"chunk {c.type}#{c.index} is longer than {MAX_CHUNK_LENGTH} bytes")
        seen.add((c.type, c.index))
        flags = FLAG_REQUIRED if c.required else 0
        table.append(
            {
                "type": c.type,
                "flags": flags,
                "index": c.index,
                "length": len(c.payload),
                "crc": crc32(c.payload),
            }
        )
    head = msgpack.packb({"chunks": table, "meta": header}, use_bin_type=True)
    if len(head) > MAX_HEADER_LENGTH:
        raise ValueError(f"header is {len(head)} bytes; the limit is {MAX_HEADER_LENGTH}")
    parts = [PREAMBLE.pack(MAGIC, *version, len(head), crc32(head)), head]
    size = PREAMBLE.size + len(head)
    for c in [None, *chunks]:  # None: the padding after the header
        if c is not None:
            parts.append(bytes(c.payload))
            size += len(c.payload)
        parts.append(bytes(_align(size) - size))
        size = _align(size)
    body = b"".join(parts) + END_MARKER
    return body + struct.pack("<I", crc32(body))


def write(path: str | os.PathLike, header: dict, chunks: list[Chunk]) -> None:
    """Write a gspc file atomically: a temporary file beside `path`, then a rename over it."""
    atomic_write_bytes(path, pack(header, chunks), fsync=True)


# ----------------------------------------------------------------------------------------------- reading


def _decode_header(raw: bytes) -> dict:
    """msgpack -> dict with every msgpack length bounded by the header length (spec: Header)."""
    n = len(raw)

    def pairs_to_dict(pairs: list) -> dict:
        out = {}
        for k, v in pairs:
            if not isinstance(k, str):
                raise BadHeader(f"header map key {k!r} is not a string")
            if k in out:
                raise BadHeader(f"header map key {k!r} appears twice")
            out[k] = v
        return out

    def refuse_ext(code: int, data: bytes) -> None:
        raise BadHeader(f"header uses msgpack extension type {code}, which gspc does not allow")

    try:
        obj = msgpack.unpackb(
            raw,
            raw=False,
            use_list=True,
            strict_map_key=False,  # keys are checked in pairs_to_dict, with a clearer message
            object_pairs_hook=pairs_to_dict,
            ext_hook=refuse_ext,
            timestamp=0,
            max_str_len=n,
            max_bin_len=n,
            max_array_len=n,
            max_map_len=n,
            max_ext_len=n,
        )
    except BadHeader:
        raise
    except msgpack.ExtraData:
        raise BadHeader(f"header holds bytes after its msgpack map (offset {PREAMBLE.size})") from None
    except msgpack.StackError:
        raise BadHeader("header msgpack nests too deeply") from None
    except (ValueError, TypeError) as e:  # msgpack's format, limit, UTF-8 and truncation errors
        raise BadHeader(f"header is not valid msgpack ({type(e).__name__}: {e or 'malformed'})") from None
    if not isinstance(obj, dict):
        raise BadHeader(f"header is a msgpack {type(obj).__name__}, not a map")
    _check_tree(obj)
    return obj


def _check_tree(top: dict) -> None:
    """Nesting depth and value types; the stack holds one iterator per level, so memory is O(depth)."""
    stack = [iter(top.values())]
    while stack:
        for value in stack[-1]:
            if isinstance(value, (list, dict)):
                if len(stack) >= MAX_DEPTH:
                    raise BadHeader(f"header nests deeper than {MAX_DEPTH} levels")
                stack.append(iter(value.values() if isinstance(value, dict) else value))
                break
            if not (value is None or isinstance(value, (bool, int, float, str, bytes))):
                raise BadHeader(
                    f"header holds a msgpack extension value ({type(value).__name__}), which gspc forbids"
                )
        else:
            stack.pop()


def _entries(top: dict, data_start: int) -> list[_Entry]:
    """The chunk table, validated field by field, with each payload's offset."""
    for key, kind in (("chunks", list), ("meta", dict)):
        if key not in top:
            raise BadHeader(f"header has no {key!r} key")
        if not isinstance(top[key], kind):
            raise BadHeader(f"header {key!r} is a {type(top[key]).__name__}, not a {kind.__name__}")
    table = top["chunks"]
    if len(table) > MAX_CHUNKS:
        raise LimitExceeded(f"chunk table has {len(table)} entries; the limit is {MAX_CHUNKS}")
    entries = []
    offset = data_start
    for i, e in enumerate(table):
        where = f"chunk table entry {i}"
        if not isinstance(e, dict):
            raise BadHeader(f"{where} is a {type(e).__name__}, not a map")
        for key in _ENTRY_KEYS:
            if key not in e:
                raise BadHeader(f"{where} has no {key!r}")
        if not _valid_type(e["type"]):
            raise BadHeader(f"{where} has type {e['type']!r}, not 4 ASCII letters or digits")
        for key in ("flags", "index", "crc"):
            if not (_is_int(e[key]) and 0 <= e[key] <= MAX_U32):
                raise BadHeader(f"{where} ({e['type']}) has {key} {e[key]!r}, not an integer in 0..{MAX_U32}")
        length = e["length"]
        if not (_is_int(length) and length >= 0):
            raise BadHeader(f"{where} ({e['type']}) has length {length!r}, not a non-negative integer")
        if length > MAX_CHUNK_LENGTH:
            raise LimitExceeded(f"{where} ({e['type']}) has length {length}; the limit is {MAX_CHUNK_LENGTH}")
        entries.append(_Entry(e["type"], e["flags"], e["index"], length, e["crc"], offset))
        offset = _align(offset + length)
    return entries


def _region_at(pos: int, header_length: int, entries: list[_Entry], trailer_at: int) -> str:
    """Name of the region that byte `pos` belongs to (for error messages)."""
    fixed = [(8, "magic"), (12, "version"), (16, "header_length"), (20, "header_crc")]
    for end, name in fixed:
        if pos < end:
            return name
    if pos < 20 + header_length:
        return "header"
    for e in entries:
        if pos < e.offset:
            return "padding before chunk " + e.name
        if pos < e.offset + e.length:
            return f"chunk {e.name} payload"
    return "padding before the trailer" if pos < trailer_at else "trailer"


def _parse(data: bytes, known_types: Collection[str] | None) -> _Parsed:
    """Every check of spec section 8, in its order. known_types=None skips the required-chunk rule."""
    n = len(data)
    head = _parse_head(lambda start, end: data[start:end], n, known_types)
    header_length, entries, data_start, trailer_at = (
        head.header_length,
        head.entries,
        head.data_start,
        head.trailer_at,
    )
    # 7. padding and chunk checksums, in file order
    _check_zero(data, PREAMBLE.size + header_length, data_start, "header")
    for e in entries:
        got = crc32(memoryview(data)[e.offset : e.offset + e.length])
        if got != e.crc:
            raise ChecksumMismatch(
                f"chunk {e.name} (payload at offset {e.offset}, {e.length} bytes) has CRC-32 {got:08x}, "
                f"the chunk table says {e.crc:08x}"
            )
        _check_zero(data, e.offset + e.length, _align(e.offset + e.length), "chunk " + e.name)
    # 8. trailer
    marker, file_crc = TRAILER.unpack_from(data, trailer_at)
    if marker != END_MARKER:
        raise BadMagic(
            f"end marker at offset {trailer_at} is {marker.hex()}, expected {END_MARKER.hex()} (GEND)"
        )
    got = crc32(memoryview(data)[: n - 4])
    if got != file_crc:
        raise ChecksumMismatch(
            f"whole file (bytes 0-{n - 5}) has CRC-32 {got:08x}, "
            f"the trailer at offset {n - 4} says {file_crc:08x}"
        )
    return _Parsed(head.version, header_length, head.meta, entries, data)


@dataclass(frozen=True)
class Head:
    """What spec section 8's checks 1 to 8 read: the preamble, the header and the chunk table, with each
    payload's offset; enough to find any chunk without reading the others (spec 10.14, partial reading)."""

    version: tuple[int, int]
    header_length: int
    meta: dict
    entries: list[_Entry]
    data_start: int
    trailer_at: int
    file_size: int


def _parse_head(get: Callable[[int, int], bytes], n: int, known_types: Collection[str] | None) -> Head:
    """Checks 1 to 8 of spec section 8 on a file of ``n`` bytes, reading bytes ``start:end`` with ``get``."""
    first = get(0, min(n, PREAMBLE.size))
    # 1. magic
    if n < len(MAGIC):
        if first == MAGIC[:n]:
            raise Truncated(f"file ends at offset {n}, inside the magic")
        raise BadMagic(f"not a gspc file: the first {n} bytes {first.hex()} are not the gspc magic")
    if first[:8] != MAGIC:
        raise BadMagic(f"not a gspc file: bytes 0-7 are {first[:8].hex()}, the gspc magic is {MAGIC.hex()}")
    # 2. version
    if n < 12:
        raise Truncated(f"file ends at offset {n}, inside the version (offset 8)")
    major, minor = struct.unpack_from("<HH", first, 8)
    if major != VERSION[0]:
        newer = "a newer" if major > VERSION[0] else "an older"
        raise UnsupportedVersion(
            f"gspc format version {major}.{minor} is {newer} major version; this reader reads {VERSION[0]}.x"
        )
    # 3. header length and checksum
    if n < PREAMBLE.size:
        raise Truncated(f"file ends at offset {n}, inside the preamble (20 bytes)")
    _, _, _, header_length, header_crc = PREAMBLE.unpack_from(first, 0)
    if header_length > MAX_HEADER_LENGTH:
        raise LimitExceeded(
            f"header_length {header_length} at offset 12 exceeds the limit {MAX_HEADER_LENGTH}"
        )
    if header_length > n - PREAMBLE.size:
        raise Truncated(
            f"file ends at offset {n}, inside the header: header_length {header_length} at offset 12 "
            f"needs {PREAMBLE.size + header_length} bytes"
        )
    if header_length == 0:
        raise BadHeader("header_length at offset 12 is 0; the header must be a msgpack map")
    raw = get(PREAMBLE.size, PREAMBLE.size + header_length)
    if crc32(raw) != header_crc:
        raise ChecksumMismatch(
            f"header (offset 20, {header_length} bytes) has CRC-32 {crc32(raw):08x}, "
            f"the preamble says {header_crc:08x}"
        )
    # 4. header contents and chunk table
    top = _decode_header(raw)
    data_start = _align(PREAMBLE.size + header_length)
    entries = _entries(top, data_start)
    # 5. duplicates, then required chunks this reader cannot interpret
    seen: dict[tuple[str, int], int] = {}
    for i, e in enumerate(entries):
        if (e.type, e.index) in seen:
            raise DuplicateChunk(
                f"chunk {e.name} appears twice in the chunk table (entries {seen[e.type, e.index]} and {i})"
            )
        seen[e.type, e.index] = i
    if known_types is not None:
        for i, e in enumerate(entries):
            if e.required and e.type not in known_types:
                raise UnknownRequiredChunk(
                    f"required chunk {e.name} (table entry {i}, payload at offset {e.offset}) has a type "
                    f"this reader does not know; a newer gspc is needed"
                )
    # 6. file size against the layout the header declares
    trailer_at = _align(entries[-1].offset + entries[-1].length) if entries else data_start
    expected = trailer_at + TRAILER.size
    if n < expected:
        raise Truncated(
            f"file ends at offset {n}, inside the {_region_at(n, header_length, entries, trailer_at)}; "
            f"the header declares {expected} bytes"
        )
    if n > expected:
        raise TrailingBytes(f"{n - expected} bytes follow the trailer, which ends at offset {expected}")
    return Head((major, minor), header_length, top["meta"], entries, data_start, trailer_at, n)


def read_head(f: BinaryIO, known_types: Collection[str] = KNOWN_TYPES) -> Head:
    """Checks 1 to 8 of spec section 8 on an open file, reading only its preamble and header (and its
    size): a reader that decodes part of a file then reads just the chunks it needs (:func:`read_chunk`)."""
    n = os.fstat(f.fileno()).st_size

    def get(start: int, end: int) -> bytes:
        f.seek(start)
        return f.read(end - start)

    return _parse_head(get, n, known_types)


def read_chunk(f: BinaryIO, head: Head, index: int) -> Chunk:
    """Chunk ``index`` of the table ``head`` read from ``f``, its CRC and padding checked (spec section 8,
    check 9, for this chunk alone)."""
    e = head.entries[index]
    end = _align(e.offset + e.length)
    f.seek(e.offset)
    data = f.read(end - e.offset)
    if len(data) != end - e.offset:
        raise Truncated(f"file ends inside chunk {e.name}")
    got = crc32(memoryview(data)[: e.length])
    if got != e.crc:
        raise ChecksumMismatch(
            f"chunk {e.name} (payload at offset {e.offset}, {e.length} bytes) has CRC-32 {got:08x}, "
            f"the chunk table says {e.crc:08x}"
        )
    if data[e.length :].count(0) != end - e.offset - e.length:
        raise BadPadding(f"padding after chunk {e.name} is not zero")
    return Chunk(e.type, bytes(data[: e.length]), e.required, e.index)


def _check_zero(data: bytes, start: int, end: int, after: str) -> None:
    pad = data[start:end]
    if pad.count(0) != len(pad):
        bad = start + next(i for i, b in enumerate(pad) if b)
        raise BadPadding(f"padding byte at offset {bad} after the {after} is {data[bad]:#04x}, not 0")


def unpack(data: bytes | bytearray | memoryview, known_types: Collection[str] = KNOWN_TYPES) -> Container:
    """Parse and verify a whole gspc file; raises a FormatError subclass naming what is wrong and where.

    Unknown optional chunks are verified and returned in `skipped`; an unknown required one is refused.
    """
    if not isinstance(data, bytes):
        data = bytes(data)
    p = _parse(data, known_types)
    view = memoryview(data)
    kept, skipped = [], []
    for e in p.entries:
        chunk = Chunk(e.type, bytes(view[e.offset : e.offset + e.length]), e.required, e.index)
        (kept if e.type in known_types else skipped).append(chunk)
    return Container(p.version, p.meta, kept, skipped, len(data), p.header_length)


def read_bytes(path: str | os.PathLike) -> bytes:
    """The file's bytes; InputError (one line) when it cannot be read."""
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise InputError(f"cannot read {path}: {e.strerror or e}") from None


def read(path: str | os.PathLike, known_types: Collection[str] = KNOWN_TYPES) -> Container:
    """unpack() the file at `path`."""
    return unpack(read_bytes(path), known_types)


def align(n: int) -> int:
    """``n`` rounded up to a multiple of 8: where the next payload starts (spec section 2)."""
    return _align(n)


def check_stream(f: BinaryIO, head: Head, block: int = 1 << 20) -> None:
    """Spec section 8's header padding, end marker and whole-file CRC on an open file, read in blocks (the
    chunks themselves are checked where read: :func:`read_chunk`)."""
    pad_start = PREAMBLE.size + head.header_length
    f.seek(pad_start)
    pad = f.read(head.data_start - pad_start)
    if pad.count(0) != len(pad):
        raise BadPadding(f"padding after the header (offset {pad_start}) is not zero")
    f.seek(head.trailer_at)
    marker, file_crc = TRAILER.unpack(f.read(TRAILER.size))
    if marker != END_MARKER:
        raise BadMagic(f"end marker at offset {head.trailer_at} is {marker.hex()}, expected GEND")
    f.seek(0)
    crc, left = 0, head.file_size - 4
    while left > 0:
        data = f.read(min(block, left))
        if not data:
            raise Truncated("the file ended while its checksum was read")
        crc = zlib.crc32(data, crc)
        left -= len(data)
    if crc != file_crc:
        raise ChecksumMismatch(f"whole file has CRC-32 {crc:08x}, the trailer says {file_crc:08x}")


def stored_size(chunk: Chunk) -> int:
    """Bytes a chunk takes in the file: its payload and the padding after it (every payload starts at a
    multiple of 8, spec section 2)."""
    return _align(len(chunk.payload))


def describe(data_or_path: bytes | bytearray | memoryview | str | os.PathLike) -> dict:
    """What `gspc info` prints: version, header size, each chunk, and the bytes spent on each part.

    Validates the file like unpack() except that unknown required chunks are listed rather than refused.
    `bytes_per_type` maps each chunk type to its bytes on disk (payloads and their padding); `totals` adds
    "header" (preamble, msgpack header, its padding and the trailer), so its values sum to `file_size`.
    """
    if isinstance(data_or_path, (bytes, bytearray, memoryview)):
        data = bytes(data_or_path)
    else:
        data = read_bytes(data_or_path)
    p = _parse(data, None)
    header_total = _align(PREAMBLE.size + p.header_length) + TRAILER.size
    chunks = []
    per_type: dict[str, int] = {}
    for e in p.entries:
        stored = _align(e.offset + e.length) - e.offset
        chunks.append(
            {
                "type": e.type,
                "index": e.index,
                "flags": e.flags,
                "required": e.required,
                "known": e.type in KNOWN_TYPES,
                "offset": e.offset,
                "size": e.length,
                "stored": stored,
                "crc": f"{e.crc:08x}",
            }
        )
        per_type[e.type] = per_type.get(e.type, 0) + stored
    return {
        "version": p.version,
        "file_size": len(data),
        "header_size": p.header_length,
        "meta_keys": sorted(p.meta),
        "chunks": chunks,
        "bytes_per_type": per_type,
        "totals": {"header": header_total, **per_type},
    }
