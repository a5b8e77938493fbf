"""Make the gspc conformance vectors in spec/vectors/ and their manifest (MANIFEST.json, README.md).

    python tools/make_vectors.py            # (re)write spec/vectors/
    python tools/make_vectors.py --check    # exit 1 if spec/vectors/ differs from what this script makes

Files are assembled here byte by byte from spec/gspc-format.md, not with gspc.format.container, so the vectors
and the reader are two independent readings of the spec. The expected outcome of each vector is stated here;
generation fails if the reader disagrees with it. The codec vectors (codec_*) hold payloads from gspc's
encoder; their expected decoded values come from gspc's decoder, and tests/test_conformance.py requires the
same of tests/spec_reader.py, a decoder written from the spec alone.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import struct
import sys
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import msgpack
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "spec" / "vectors"
MAGIC = b"\x89GSPC\r\n\x1a"


def crc(b: bytes) -> int:
    return zlib.crc32(b) & 0xFFFFFFFF


def pad8(n: int) -> int:
    return -n % 8


def payload(name: str, n: int) -> bytes:
    """Deterministic filler bytes, different for each name."""
    out = b""
    while len(out) < n:
        out += hashlib.sha256(name.encode() + len(out).to_bytes(4, "little")).digest()
    return out[:n]


def entry(type_: str, data: bytes, index: int = 0, flags: int = 1, **extra) -> dict:
    return {"type": type_, "flags": flags, "index": index, "length": len(data), "crc": crc(data), **extra}


def frame(header_raw: bytes, payloads: list[bytes], major: int = 1, minor: int = 0) -> bytes:
    """Preamble, header, zero padding, padded payloads, end marker, file CRC (spec: File layout)."""
    head = MAGIC + struct.pack("<HHII", major, minor, len(header_raw), crc(header_raw)) + header_raw
    body = head + bytes(pad8(len(head)))
    for p in payloads:
        body += p + bytes(pad8(len(p)))
    body += b"GEND"
    return body + struct.pack("<I", crc(body))


def build(meta: dict, chunks: list[tuple[dict, bytes]], major: int = 1, minor: int = 0, **top) -> bytes:
    header = msgpack.packb({"chunks": [e for e, _ in chunks], "meta": meta, **top}, use_bin_type=True)
    return frame(header, [p for _, p in chunks], major, minor)


def refresh_file_crc(data: bytes) -> bytes:
    return data[:-4] + struct.pack("<I", crc(data[:-4]))


def flip(data: bytes, offset: int, bit: int = 0) -> bytes:
    return data[:offset] + bytes([data[offset] ^ (1 << bit)]) + data[offset + 1 :]


def to_json(value):
    """msgpack value -> JSON value; bin becomes {"$bin": hex} (the manifest's only extension)."""
    if isinstance(value, bytes):
        return {"$bin": value.hex()}
    if isinstance(value, dict):
        return {k: to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json(v) for v in value]
    return value


@dataclass
class Vector:
    name: str
    data: bytes
    description: str
    error: str | None = None  # FormatError subclass name; None: the file is valid
    message_contains: list[str] = field(default_factory=list)
    version: tuple[int, int] = (1, 0)
    meta: dict | None = None
    kept: list[tuple[dict, bytes]] = field(default_factory=list)  # chunks a 1.0 reader returns, in file order
    skipped: list[tuple[dict, bytes]] = field(default_factory=list)  # unknown optional chunks
    codec: dict | None = None  # codec vectors: decoded attribute digests, or the codec error

    def manifest(self) -> dict:
        out = {
            "file": self.name + ".gspc",
            "size": len(self.data),
            "sha256": hashlib.sha256(self.data).hexdigest(),
            "description": self.description,
        }
        if self.error:
            out.update(expect="error", error=self.error, message_contains=self.message_contains)
            return out

        def chunk_list(chunks):
            return [
                {
                    "type": e["type"],
                    "index": e["index"],
                    "required": bool(e["flags"] & 1),
                    "length": len(p),
                    "sha256": hashlib.sha256(p).hexdigest(),
                }
                for e, p in chunks
            ]

        out.update(
            expect="ok",
            version=list(self.version),
            meta=to_json(self.meta),
            chunks=chunk_list(self.kept),
            skipped=chunk_list(self.skipped),
        )
        if self.codec is not None:
            out["codec"] = self.codec
        return out


def valid(
    name: str, description: str, meta: dict, chunks, skipped=(), minor: int = 0, data=None, **top
) -> Vector:
    """A valid vector: `chunks` (kept by a reader), then `skipped` (unknown optional), in file order."""
    all_chunks = list(chunks) + list(skipped)
    data = data if data is not None else build(meta, all_chunks, 1, minor, **top)
    return Vector(name, data, description, None, [], (1, minor), meta, list(chunks), list(skipped))


def bad(name: str, data: bytes, error: str, description: str, *contains: str) -> Vector:
    return Vector(name, data, description, error, list(contains))


CAMERAS = [
    {
        "name": f"view{i:03d}",
        "width": 64,
        "height": 48,
        "K": [[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]],
        "world_to_cam": [[1.0, 0.0, 0.0, 0.1 * i], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0, 0, 0, 1]],
    }
    for i in range(2)
]
REGISTRY = ["POSN", "OPAC", "SCAL", "ROTN", "SHDC", "SHRS", "RESI"]  # the 1.0 types


def side_payload() -> bytes:
    """A SIDE payload (spec 10.9) for CAMERAS: view 1 carries a half-resolution 8-bit residual of 5 bytes."""
    from gspc.cameras import Camera
    from gspc.format.side_chunk import pack_side
    from gspc.format.view_records import ViewRecord

    views = [
        {"camera": Camera(np.array(c["world_to_cam"]), np.array(c["K"]), 64, 48).to_dict()} for c in CAMERAS
    ]
    views[1]["residual"] = {
        "codec": "jxl",
        "shape": [24, 32],
        "bits": 8,
        "gain": 64.0,
        "offset": 128,
        "scale": 2,
        "full_shape": [48, 64],
    }
    return pack_side([ViewRecord.from_dict(v) for v in views], {1: b"image"})


def valid_vectors() -> list[Vector]:
    vs = [
        valid(
            "valid_minimal", "smallest valid file: empty meta, no chunks (the spec's worked hex dump)", {}, []
        )
    ]
    for i, t in enumerate(REGISTRY):
        if t == "RESI":
            chunks = [
                (entry(t, payload(f"{t}{v}", 5 + v), index=v), payload(f"{t}{v}", 5 + v)) for v in range(3)
            ]
            desc = "three RESI chunks, indices 0, 1, 2 (one per side-information view)"
        else:
            data = payload(t, 9 + 3 * i)
            chunks = [(entry(t, data), data)]
            desc = f"one {t} chunk of {len(data)} bytes (padded to a multiple of 8)"
        vs.append(valid(f"valid_chunk_{t}", desc, {"codec": {"id": "test", "version": 1}}, chunks))
    side = side_payload()
    vs.append(
        valid(
            "valid_chunk_SIDE",
            f"version 1.1: one SIDE chunk of {len(side)} bytes, two views (spec 10.9), one with a residual",
            {"side_info": {"background": [1.0, 1.0, 1.0], "restorer": "none"}},
            [(entry("SIDE", side), side)],
            minor=1,
        )
    )
    full_meta = {
        "scene": {"count": 1000, "sh_degree": 3, "bbox": [[-1.5, -1.0, -0.5], [1.5, 1.0, 0.5]]},
        "codec": {
            "positions": {"id": "posn-test", "bits": 16},
            "attributes": {"id": "attr-test", "lambda": 0.002},
        },
        "cameras": CAMERAS,
        "note": "bin values, nil, booleans and negative numbers are all allowed",
        "blob": b"\x00\x01\xfe\xff",
        "flags": [None, True, False, -1, -(2**40), 2**63, 0.5],
    }
    full = []
    for t in REGISTRY:
        for v in range(2 if t == "RESI" else 1):
            data = payload(f"full{t}{v}", 17 + len(full))
            full.append((entry(t, data, index=v), data))
    vs.append(
        valid(
            "valid_all_types", "every gspc 1.0 chunk type, a realistic header with cameras", full_meta, full
        )
    )
    lengths = [(entry("RESI", payload("len", n), index=n), payload("len", n)) for n in range(10)]
    vs.append(valid("valid_lengths_0_to_9", "RESI chunks of 0..9 bytes: every padding amount", {}, lengths))
    opt = payload("OPAC-optional", 6)
    vs.append(
        valid(
            "valid_optional_known",
            "a known type marked optional is returned",
            {},
            [(entry("OPAC", opt, flags=0), opt)],
        )
    )
    posn, extra = payload("POSN-u", 12), payload("xTRA", 21)
    vs.append(
        valid(
            "valid_unknown_optional",
            "an unknown optional chunk (xTRA) is verified and skipped",
            {},
            [(entry("POSN", posn), posn)],
            [(entry("xTRA", extra, flags=0), extra)],
        )
    )
    newt = payload("NEWT", 11)
    vs.append(
        valid(
            "valid_newer_minor",
            "version 1.10: unknown top-level and entry keys, a reserved flag bit, an unknown optional chunk",
            {"codec": {"id": "future"}},
            [(entry("POSN", posn, flags=0b11, note="entry keys a 1.0 reader ignores"), posn)],
            [(entry("NEWT", newt, flags=0), newt)],
            minor=10,
            future={"anything": [1, 2, 3]},
        )
    )
    # Same content with msgpack written the long way: keys reordered, ints in wider encodings than needed.
    e_posn = entry("POSN", posn)
    raw = (
        b"\xde\x00\x02"  # map16, 2 pairs
        + b"\xd9\x04meta"  # str8 "meta"
        + b"\xdf\x00\x00\x00\x00"  # map32, empty
        + b"\xd9\x06chunks"
        + b"\xdc\x00\x01"  # array16, 1 entry
        + b"\x85"
        + b"\xa3crc"
        + b"\xce"
        + struct.pack(">I", e_posn["crc"])
        + b"\xa6length\xcf"
        + struct.pack(">Q", len(posn))  # uint64
        + b"\xa5index\xd3"
        + struct.pack(">q", 0)  # int64
        + b"\xa5flags\xcd\x00\x01"  # uint16
        + b"\xa4type\xdb\x00\x00\x00\x04POSN"  # str32
    )
    vs.append(
        valid(
            "valid_noncanonical_msgpack",
            "keys out of the usual order and integers in wider msgpack encodings than needed",
            {},
            [(e_posn, posn)],
            data=frame(raw, [posn]),
        )
    )
    return vs


def layout(data: bytes) -> dict[str, int]:
    """Offsets of the regions of a file made by build() (for truncations and bit flips)."""
    (h,) = struct.unpack_from("<I", data, 12)
    top = msgpack.unpackb(data[20 : 20 + h])
    pos = 20 + h
    out = {"header": 20, "header_padding": pos}
    pos += pad8(pos)
    for e in top["chunks"]:
        name = f"{e['type']}{e['index']}"
        out[f"chunk_{name}"] = pos
        pos += e["length"]
        out[f"chunk_{name}_padding"] = pos
        pos += pad8(pos)
    out["end_marker"] = pos
    out["file_crc"] = pos + 4
    return out


def invalid_vectors() -> list[Vector]:
    posn, resi = payload("base-POSN", 13), payload("base-RESI", 8)
    base_chunks = [(entry("POSN", posn), posn), (entry("RESI", resi, index=1), resi)]
    base = build({"scene": "base"}, base_chunks)
    reg = layout(base)
    assert reg["header_padding"] % 8 and reg["chunk_POSN0_padding"] % 8, "base must exercise both paddings"
    vs = [
        bad("invalid_magic_png", b"\x89PNG\r\n\x1a\n" + base[8:], "BadMagic", "a PNG signature", "magic"),
        bad("invalid_magic_text", b"GSPC 1.0\n", "BadMagic", "short text file", "magic"),
        bad(
            "invalid_magic_crlf",
            base.replace(b"\r\n", b"\n", 1),
            "BadMagic",
            "CR LF in the magic turned into LF (text-mode transfer)",
            "magic",
        ),
        bad("invalid_major_2", build({}, [], major=2), "UnsupportedVersion", "major version 2", "2.0"),
        bad("invalid_major_0", build({}, [], major=0), "UnsupportedVersion", "major version 0", "0.0"),
        bad(
            "invalid_major_2_other_layout",
            MAGIC + struct.pack("<HH", 2, 3) + b"a different layout",
            "UnsupportedVersion",
            "a newer major version may change everything after byte 12",
            "2.3",
        ),
    ]
    zz = payload("ZZZZ", 4)
    vs.append(
        bad(
            "invalid_unknown_required",
            build({}, [*base_chunks, (entry("ZZZZ", zz), zz)]),
            "UnknownRequiredChunk",
            "a required chunk of unknown type ZZZZ",
            "ZZZZ#0",
        )
    )
    vs.append(
        bad(
            "invalid_duplicate_chunk",
            build({}, [base_chunks[0], base_chunks[0]]),
            "DuplicateChunk",
            "POSN#0 twice",
            "POSN#0",
        )
    )
    r0, r1 = payload("dupR0", 3), payload("dupR1", 5)
    vs.append(
        bad(
            "invalid_duplicate_index",
            build({}, [(entry("RESI", r0, index=2), r0), (entry("RESI", r1, index=2), r1)]),
            "DuplicateChunk",
            "two RESI chunks with index 2",
            "RESI#2",
        )
    )
    vs.append(
        bad(
            "invalid_duplicate_unknown_optional",
            build({}, [(entry("xTRA", r0, flags=0), r0), (entry("xTRA", r0, flags=0), r0)]),
            "DuplicateChunk",
            "duplicates are refused even among chunks a reader would skip",
            "xTRA#0",
        )
    )
    vs.append(
        bad(
            "invalid_trailing_bytes",
            base + b"extra!!!",
            "TrailingBytes",
            "8 bytes after the trailer",
            "8 bytes",
        )
    )
    vs.append(
        bad(
            "invalid_trailing_zero",
            base + b"\x00",
            "TrailingBytes",
            "one zero byte after the trailer",
            "1 bytes",
        )
    )

    # Truncation at every region boundary of the base file, and one byte short.
    cuts = {0: "magic (empty file)", 4: "middle of the magic", 8: "major", 10: "minor", 12: "header_length"}
    cuts[16] = "header_crc"
    for region, off in reg.items():
        cuts.setdefault(off, region.replace("_", " "))
    cuts.setdefault(len(base) - 1, "last byte of the file CRC")
    for off, region in sorted(cuts.items()):
        vs.append(
            bad(
                f"invalid_truncated_{off:03d}",
                base[:off],
                "Truncated",
                f"base file cut to {off} bytes: it ends where the {region} begins",
                f"offset {off}",
            )
        )

    # One flipped bit in each region (no checksum repaired).
    flips = [
        ("magic", 3, 0, "BadMagic"),
        ("major", 8, 1, "UnsupportedVersion"),
        ("minor", 10, 0, "ChecksumMismatch"),
        ("header_length_low", 12, 0, "ChecksumMismatch"),
        ("header_length_high", 15, 7, "LimitExceeded"),
        ("header_length_mid", 13, 1, "Truncated"),
        ("header_crc", 17, 4, "ChecksumMismatch"),
        ("header", reg["header"] + 5, 2, "ChecksumMismatch"),
        ("header_padding", reg["header_padding"], 0, "BadPadding"),
        ("posn_payload", reg["chunk_POSN0"] + 6, 5, "ChecksumMismatch"),
        ("posn_padding", reg["chunk_POSN0_padding"] + 1, 3, "BadPadding"),
        ("resi_payload", reg["chunk_RESI1"], 7, "ChecksumMismatch"),
        ("end_marker", reg["end_marker"] + 2, 1, "BadMagic"),
        ("file_crc", reg["file_crc"] + 3, 6, "ChecksumMismatch"),
    ]
    where = {"header": "header", "posn_payload": "POSN#0", "resi_payload": "RESI#1", "file_crc": "whole file"}
    for region, off, bit, error in flips:
        vs.append(
            bad(
                f"invalid_flip_{region}",
                flip(base, off, bit),
                error,
                f"bit {bit} of byte {off} flipped ({region.replace('_', ' ')})",
                *([where[region]] if region in where else []),
            )
        )

    # Lengths pointing past the end, and absurd lengths and counts.
    def with_header(raw: bytes, payloads=(posn, resi)) -> bytes:
        return frame(raw, list(payloads))

    h_len = struct.unpack_from("<I", base, 12)[0]
    past = base[:12] + struct.pack("<I", len(base)) + base[16:]
    vs.append(
        bad("invalid_header_length_past_end", past, "Truncated", "header_length = file size", "offset 12")
    )
    absurd = base[:12] + b"\xff\xff\xff\xff" + base[16:]
    vs.append(
        bad("invalid_header_length_absurd", absurd, "LimitExceeded", "header_length = 2^32-1", "offset 12")
    )
    long_posn = dict(base_chunks[0][0], length=1000)
    vs.append(
        bad(
            "invalid_chunk_length_past_end",
            build({}, [(long_posn, posn), base_chunks[1]]),
            "Truncated",
            "POSN length 1000 in a file of about 200 bytes (checksums valid)",
            "POSN#0",
        )
    )
    huge = dict(base_chunks[0][0], length=2**64 - 1)
    vs.append(
        bad(
            "invalid_chunk_length_absurd",
            build({}, [(huge, posn)]),
            "LimitExceeded",
            "POSN length 2^64-1",
            "POSN",
        )
    )

    def head(chunks_raw: bytes, meta_raw: bytes = b"\x80") -> bytes:
        return b"\x82\xa6chunks" + chunks_raw + b"\xa4meta" + meta_raw

    vs += [
        bad(
            "invalid_chunk_count_absurd",
            with_header(head(b"\xdd\xff\xff\xff\xff")),
            "BadHeader",
            "chunk table array32 of 2^32-1 entries",
            "msgpack",
        ),
        bad(
            "invalid_map_count_absurd",
            with_header(head(b"\x90", b"\xdf\xff\xff\xff\xff")),
            "BadHeader",
            "meta map32 of 2^32-1 pairs",
            "msgpack",
        ),
        bad(
            "invalid_str_length_absurd",
            with_header(head(b"\x90", b"\x81\xdb\xff\xff\xff\xff")),
            "BadHeader",
            "a str32 of 2^32-1 bytes",
            "msgpack",
        ),
        bad(
            "invalid_bin_length_absurd",
            with_header(head(b"\x90", b"\x81\xa1k\xc6\xff\xff\xff\xf0")),
            "BadHeader",
            "a bin32 of 2^32-16 bytes",
            "msgpack",
        ),
        bad("invalid_header_zero_length", frame(b"", []), "BadHeader", "header_length 0", "0"),
        bad(
            "invalid_header_not_map",
            frame(msgpack.packb([[], {}]), []),
            "BadHeader",
            "header is an array",
            "not a map",
        ),
        bad(
            "invalid_header_no_chunks",
            frame(msgpack.packb({"meta": {}}), []),
            "BadHeader",
            "no 'chunks' key",
            "'chunks'",
        ),
        bad(
            "invalid_header_no_meta",
            frame(msgpack.packb({"chunks": []}), []),
            "BadHeader",
            "no 'meta' key",
            "'meta'",
        ),
        bad(
            "invalid_header_meta_not_map",
            frame(msgpack.packb({"chunks": [], "meta": [1]}), []),
            "BadHeader",
            "meta is an array",
            "'meta'",
        ),
        bad(
            "invalid_header_extra_bytes",
            frame(msgpack.packb({"chunks": [], "meta": {}}) + b"\xc0", []),
            "BadHeader",
            "a msgpack nil after the header map, inside header_length",
            "after",
        ),
        bad(
            "invalid_header_incomplete",
            frame(b"\x82\xa6chunks\x90\xa4meta", []),
            "BadHeader",
            "header map missing its last value",
            "msgpack",
        ),
        bad(
            "invalid_header_reserved_byte",
            frame(b"\x82\xa6chunks\x90\xa4meta\xc1", []),
            "BadHeader",
            "msgpack's never-used byte 0xc1",
            "msgpack",
        ),
        bad(
            "invalid_header_bad_utf8",
            frame(b"\x82\xa6chunks\x90\xa4meta\x81\xa2\xff\xfe\xc0", []),
            "BadHeader",
            "a str that is not UTF-8",
            "msgpack",
        ),
        bad(
            "invalid_header_ext_type",
            frame(head(b"\x90", b"\x81\xa1t\xd4\x05\x00"), []),
            "BadHeader",
            "msgpack extension type 5",
            "extension",
        ),
        bad(
            "invalid_header_timestamp",
            frame(head(b"\x90", b"\x81\xa1t\xd6\xff\x00\x00\x00\x01"), []),
            "BadHeader",
            "msgpack timestamp (extension -1)",
            "extension",
        ),
        bad(
            "invalid_header_int_key",
            frame(head(b"\x90", b"\x81\x01\xc0"), []),
            "BadHeader",
            "a map key that is an integer",
            "key",
        ),
        bad(
            "invalid_header_duplicate_key",
            frame(head(b"\x90", b"\x82\xa1a\x01\xa1a\x02"), []),
            "BadHeader",
            "meta has key 'a' twice",
            "'a'",
        ),
        bad(
            "invalid_header_too_deep",
            frame(head(b"\x90", b"\x81\xa1d" + b"\x91" * 40 + b"\xc0"), []),
            "BadHeader",
            "40 nested arrays",
            "deeper",
        ),
    ]

    def table_vec(name: str, e: dict, desc: str, *contains: str) -> Vector:
        return bad(name, build({}, [(e, posn)]), "BadHeader", desc, *contains)

    e0 = entry("POSN", posn)
    vs += [
        table_vec("invalid_entry_short_type", dict(e0, type="POS"), "chunk type of 3 characters", "'POS'"),
        table_vec("invalid_entry_symbol_type", dict(e0, type="PO$N"), "chunk type with a '$'", "'PO$N'"),
        table_vec("invalid_entry_int_type", dict(e0, type=1234), "chunk type is an integer", "1234"),
        table_vec("invalid_entry_negative_index", dict(e0, index=-1), "index -1", "index"),
        table_vec("invalid_entry_big_index", dict(e0, index=2**32), "index 2^32", "index"),
        table_vec("invalid_entry_bool_length", dict(e0, length=True), "length is a boolean", "length"),
        table_vec("invalid_entry_negative_length", dict(e0, length=-1), "length -1", "length"),
        table_vec("invalid_entry_float_crc", dict(e0, crc=1.5), "crc is a float", "crc"),
        table_vec(
            "invalid_entry_no_crc", {k: v for k, v in e0.items() if k != "crc"}, "entry without crc", "'crc'"
        ),
        table_vec("invalid_entry_not_map", [1, 2, 3], "entry is an array", "entry 0"),
    ]

    # Damage from a checksum-repairing attacker or a buggy writer: checksums valid, rules broken.
    hp = reg["header_padding"]
    vs.append(
        bad(
            "invalid_nonzero_padding",
            refresh_file_crc(base[:hp] + b"\x01" + base[hp + 1 :]),
            "BadPadding",
            "a header padding byte is 1 (file CRC repaired)",
            f"offset {hp}",
        )
    )
    po = reg["chunk_POSN0"]
    vs.append(
        bad(
            "invalid_chunk_crc",
            refresh_file_crc(base[:po] + b"X" + base[po + 1 :]),
            "ChecksumMismatch",
            "POSN payload changed, file CRC repaired",
            "POSN#0",
        )
    )
    em = reg["end_marker"]
    vs.append(
        bad(
            "invalid_end_marker",
            refresh_file_crc(base[:em] + b"GEN!" + base[em + 4 :]),
            "BadMagic",
            "end marker GEN!",
            "end marker",
        )
    )
    assert h_len > 0
    return vs


# ------------------------------------------------------------------ codec vectors (spec section 10)
#
# Tiny real encodes by gspc's encoder (gspc.codec), framed here by build(); the expected decoded attributes
# are digests of gspc's reference decoder, which tests/test_conformance.py also requires of the separate
# spec-following reader tests/spec_reader.py. Invalid ones take a valid file and break one rule of section 10
# each; their containers stay valid.

ATTRS = ("means", "quats", "log_scales", "opacities", "sh_dc", "sh_rest")
BACKGROUND = [1.0, 1.0, 1.0]


def tiny_scene(n: int, degree: int, seed: int, rest_fraction: float = 0.5):
    """A blob of n Gaussians; about rest_fraction of them with view-dependent colour."""
    from gspc.scene import make_scene

    g = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    rest = g.normal(0, 0.08, (n, k, 3)) * (g.uniform(size=(n, 1, 1)) < rest_fraction)
    return make_scene(
        g.normal(0, 0.5, (n, 3)),
        g.normal(0, 1, (n, 4)),
        g.normal(-3, 0.4, (n, 3)),
        g.normal(1.5, 1.0, n),
        g.normal(0, 0.4, (n, 3)),
        rest,
        degree,
    )


def unbounded_scene(n: int, far: int, seed: int, far_growth: float, degree: int = 1):
    """tiny_scene's blob (within about 2 of the origin) with ``far`` Gaussians 20-40 away, their size
    ``far_growth`` x their distance (0: the blob's): a contracted grid (10.1), with a far set when large."""
    import torch

    scene = tiny_scene(n + far, degree, seed)
    g = np.random.default_rng(seed + 100)
    d = g.normal(size=(far, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dist = g.uniform(20.0, 40.0, (far, 1))
    scene.means[n:] = torch.from_numpy((d * dist).astype(np.float32))
    if far_growth:
        scene.log_scales[n:] = torch.from_numpy(np.log(far_growth * dist).astype(np.float32))
    return scene


def encode_scene(scene) -> tuple[dict, dict[str, bytes]]:
    """(meta["attributes"], attribute payloads) from gspc's uniform attribute encoder (versions 1 to 3) at
    lambda 8, the low preset's before per-Gaussian precision: these vectors keep their bytes."""
    from gspc.encoder.coding import encode_attributes
    from gspc.encoder.params import CodecParams

    enc = encode_attributes(scene, CodecParams(lam=8.0))
    return enc.section.to_dict(), enc.chunks


def synthetic_significance(n: int, degree: int, seed: int):
    """A Significance (gspc/encoder/precision_plan.py) of ``n`` Gaussians from seeded random measures spread
    over six orders of magnitude, as a real scene's are: the encoder plans classes and SH degrees from it.
    Made without rendering, so the vectors do not move with the renderer or the views."""
    from gspc.encoder.precision_plan import Significance
    from gspc.scene import ATTRIBUTE_NAMES

    g = np.random.default_rng(seed)
    gradient = {name: 10.0 ** g.uniform(-4, 2, n) for name in ATTRIBUTE_NAMES}
    return Significance(10.0 ** g.uniform(-7, -1, n), gradient, 10.0 ** g.uniform(-5, 1, (n, degree)), 20)


def encode_classed(
    scene, exponents: tuple[int, int], seed: int, codebook: int = 0
) -> tuple[dict, dict[str, bytes]]:
    """(meta["attributes"], attribute payloads) of attribute codec version 4 (spec 10.13): the low preset's
    codec at lambda 10 (pinned: the vectors do not follow the preset's rate) with precision classes of step
    multipliers 2^exponents[0] .. 2^exponents[1], each band of SH kept where its change of the views is at
    least its coded step; with a ``codebook`` of that many entries, version 5 (spec 10.16)."""
    from dataclasses import replace

    from gspc.encoder.coding import encode_attributes
    from gspc.encoder.precision_plan import PrecisionParams
    from gspc.presets import QUALITY

    precision = PrecisionParams(exponents=exponents, bias=1.0, sh_keep=1.0)
    params = replace(QUALITY["low"].attributes.with_lambda(10.0), precision=precision, sh_codebook=codebook)
    sig = synthetic_significance(scene.num_gaussians, scene.sh_degree, seed)
    enc = encode_attributes(scene, params, significance=sig)
    assert enc.section.version == (5 if codebook else 4)
    return enc.section.to_dict(), enc.chunks


def scene_meta(attributes: dict, side_info: dict | None = None) -> dict:
    """meta as gspc encode writes it (spec 10.8)."""
    return {
        "encoder": "gspc make_vectors",
        "scene": {
            "num_gaussians": attributes["n"],
            "sh_degree": attributes["sh_degree"],
            "source_gaussians": attributes["n"],
        },
        "attributes": attributes,
        "side_info": side_info or {"background": BACKGROUND, "restorer": "none"},
    }


def attribute_entries(chunks: dict[str, bytes], **index) -> list[tuple[dict, bytes]]:
    order = ["POSN", "PREC", "OPAC", "SCAL", "ROTN", "SHDC", "SHRS"]
    return [(entry(t, chunks[t], index=index.get(t, 0)), chunks[t]) for t in order if t in chunks]


def camera(i: int, w: int, h: int) -> dict:
    from gspc.cameras import Camera

    angle = 0.4 * i
    rot = np.array([[np.cos(angle), 0, -np.sin(angle)], [0, 1, 0], [np.sin(angle), 0, np.cos(angle)]])
    w2c = np.eye(4)
    w2c[:3, :3] = rot
    w2c[:3, 3] = [0.0, 0.0, 3.0]
    K = np.array([[1.2 * w, 0, w / 2], [0, 1.2 * w, h / 2], [0, 0, 1]])
    return Camera(w2c, K, w, h, f"v{i}").to_dict()


def residual_image(h: int, w: int, seed: int, codec: str) -> tuple[bytes, float]:
    """A smooth signed residual quantised as 10.7 says and coded losslessly, so every conforming image
    decoder returns the same samples: (image bytes, gain)."""
    import imagecodecs

    g = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.stack([np.sin(xx / 3.0 + c) * np.cos(yy / 4.0) * 0.05 for c in range(3)], -1)
    r = r + g.normal(0, 0.005, r.shape)
    gain = float(np.float32(127 / np.abs(r).max()))
    q = np.clip(np.rint(r * gain + 128), 0, 255).astype(np.uint8)
    if codec == "jxl":
        return imagecodecs.jpegxl_encode(q, lossless=True, effort=3), gain
    return imagecodecs.webp_encode(q, lossless=True), gain


def side_chunk(scale: int = 2) -> bytes:
    """SIDE (10.9): two 24x20 views with one shared camera size; view 1 carries a JPEG XL residual."""
    from gspc.format.side_chunk import pack_side
    from gspc.format.view_records import ViewRecord

    w, h = 24, 20
    views = [{"camera": camera(i, w, h)} for i in range(2)]
    cams = [v["camera"] for v in views]
    for c in cams[1:]:
        c["intrinsics"] = cams[0]["intrinsics"]
    image, gain = residual_image(-(-h // scale), -(-w // scale), 7, "jxl")
    views[1]["residual"] = {
        "codec": "jxl",
        "shape": [-(-h // scale), -(-w // scale)],
        "bits": 8,
        "gain": gain,
        "offset": 128,
        "scale": scale,
        "full_shape": [h, w],
    }
    return pack_side([ViewRecord.from_dict(v) for v in views], {1: image})


def digest(a: np.ndarray) -> dict:
    a = np.ascontiguousarray(a, dtype="<f4")
    first = a.reshape(a.shape[0], -1)[0] if a.size else a.reshape(-1)
    return {
        "shape": list(a.shape),
        "sha256": hashlib.sha256(a.tobytes()).hexdigest(),
        "first": [float(x) for x in first],
    }


def reference_decode(data: bytes, residuals: bool = True) -> tuple[dict[str, np.ndarray], list[dict]]:
    """gspc's decoder up to the decoded attributes and residuals (what gspc decode does before rendering);
    ``residuals`` False: as a decoder that does not use them (spec 10.7), the images' headers only."""
    from gspc.codec.attributes import decode_attributes
    from gspc.codec.residuals import decode_residual
    from gspc.errors import CodecError
    from gspc.format import container
    from gspc.format.attribute_section import AttributeSection, attribute_chunks
    from gspc.format.side_chunk import legacy_views, read_side_views
    from gspc.format.tiles import refuse_untiled_sides

    def listed(side, **extra) -> list[dict]:
        out = []
        for k, v in enumerate(side.views):
            view = {"width": v.camera.width, "height": v.camera.height, **extra}
            if k in side.images and residuals:
                view["residual"] = decode_residual(side.images[k], v.residual)
            out.append(view)
        return out

    c = container.unpack(data)
    if c.find("TIDX", 0) is not None:  # a tiled file (spec 10.14): gspc's whole decode of its tiles
        from gspc.format.file import read_file
        from gspc.pipeline import DecodeOptions, decode_bytes

        file = read_file(data)  # the tiles' own side information (10.15) read and checked
        scene = decode_bytes(data, DecodeOptions(refine=False))[0]
        views = listed(file.side)  # the whole scene's, then each tile's own in tile order
        for k, side in enumerate(file.tile_sides):
            views += listed(side, tile=k) if side is not None else []
        return {name: getattr(scene, name).numpy() for name in ATTRS}, views
    refuse_untiled_sides(c.chunks)
    if not isinstance(c.header.get("attributes"), dict) or not isinstance(c.header.get("side_info"), dict):
        raise CodecError("meta lacks attributes or side_info")
    side = read_side_views(legacy_views(c.header["side_info"].get("views", [])), c.chunks, len(data))
    scene = decode_attributes(attribute_chunks(c.chunks), AttributeSection.from_dict(c.header["attributes"]))
    return {name: getattr(scene, name).numpy() for name in ATTRS}, listed(side)


def codec_expectation(data: bytes, residuals: bool = True) -> dict:
    """What MANIFEST.json states of a file that decodes; ``residuals`` False for one whose residual images a
    decoder that uses them refuses ("residuals": "refused"), listed as a decoder that does not decodes it."""
    attrs, views = reference_decode(data, residuals)
    out = {"expect": "ok", "attributes": {k: digest(v) for k, v in attrs.items()}, "views": []}
    if not residuals:
        out["residuals"] = "refused"
    for v in views:
        rec = {"width": v["width"], "height": v["height"]}
        if "tile" in v:  # a tile's own view (spec 10.15)
            rec["tile"] = v["tile"]
        if "residual" in v:
            rec["residual"] = digest(v["residual"])
        out["views"].append(rec)
    return out


def ecm_parts(payload: bytes) -> tuple[int, int, list, bytes]:
    import zstandard

    m, c, packed, words = msgpack.unpackb(payload)
    return m, c, msgpack.unpackb(zstandard.ZstdDecompressor().decompress(packed)), words


def ecm(m: int, c: int, models, words: bytes, raw_models: bytes | None = None) -> bytes:
    import zstandard

    packed = (
        raw_models
        if raw_models is not None
        else zstandard.ZstdCompressor(level=19).compress(msgpack.packb(models))
    )
    return msgpack.packb([m, c, packed, words], use_bin_type=True)


def with_model(payload: bytes, column: int, bucket: int, spec: list | None = None, mode: int | None = None):
    """The ECM with one model spec or one column's mode replaced; the words are kept."""
    m, c, models, words = ecm_parts(payload)
    if spec is not None:
        models[column][1][bucket] = spec
    if mode is not None:
        models[column][0] = mode
    return ecm(m, c, models, words)


def codec_vectors() -> list[Vector]:
    vs: list[Vector] = []

    def ok(name: str, desc: str, meta: dict, chunks, minor: int = 1, residuals: bool = True) -> Vector:
        v = valid(name, desc, meta, chunks, minor=minor)
        v.codec = codec_expectation(v.data, residuals)
        vs.append(v)
        return v

    a0, c0 = encode_scene(tiny_scene(40, 0, 1))
    ok(
        "codec_sh0",
        "40 Gaussians, SH degree 0: POSN, OPAC, SCAL, ROTN, SHDC",
        scene_meta(a0),
        attribute_entries(c0),
    )
    a3, c3 = encode_scene(tiny_scene(100, 3, 2))
    ok(
        "codec_sh3",
        "100 Gaussians, SH degree 3, about half with SH rest (SHRS flags and values)",
        scene_meta(a3),
        attribute_entries(c3),
    )
    a1, c1 = encode_scene(tiny_scene(30, 1, 3, rest_fraction=0.0))
    ok(
        "codec_sh1_no_rest",
        "30 Gaussians, SH degree 1, none with SH rest: SHRS values is the empty ECM",
        scene_meta(a1),
        attribute_entries(c1),
    )
    a2, c2 = encode_scene(tiny_scene(50, 1, 4))
    side = side_chunk()
    ok(
        "codec_side_jxl",
        "50 Gaussians, SH degree 1, SIDE with two 24x20 views, one with a lossless JPEG XL "
        "residual at half resolution",
        scene_meta(a2),
        [*attribute_entries(c2), (entry("SIDE", side), side)],
    )
    a5, c5 = encode_scene(unbounded_scene(60, 12, 5, 0.0))
    ok(
        "codec_contracted",
        "72 Gaussians, SH degree 1, 12 of them 20-40 units away (the rest within 2): attribute codec "
        "version 2, positions on the contracted grid",
        scene_meta(a5),
        attribute_entries(c5),
        minor=2,
    )
    a6, c6 = encode_scene(unbounded_scene(120, 50, 6, 0.5))
    ok(
        "codec_far_set",
        f"170 Gaussians, SH degree 1, 50 large ones 20-40 units away: attribute codec version 3, a far set "
        f"of {a6['position']['far_count']} on a grid {a6['position']['far_shift']} bits coarser",
        scene_meta(a6),
        attribute_entries(c6),
        minor=3,
    )
    image, gain = residual_image(20, 24, 8, "webp")
    views10 = [
        {
            "camera": camera(0, 24, 20),
            "residual": {"codec": "webp", "shape": [20, 24], "bits": 8, "gain": gain, "offset": 128},
        },
        {"camera": camera(1, 24, 20)},
    ]
    meta10 = scene_meta(a0, {"views": views10, "background": BACKGROUND, "restorer": "none"})
    ok(
        "codec_resi_1_0",
        "format 1.0 side information: views in meta, one RESI chunk with a lossless WebP "
        "residual at full resolution",
        meta10,
        [*attribute_entries(c0), (entry("RESI", image), image)],
        minor=0,
    )

    def bad_codec(name: str, desc: str, meta: dict, chunks, *contains: str, minor: int = 1) -> None:
        v = valid(name, desc, meta, chunks, minor=minor)
        v.codec = {"expect": "error", "error": "CodecError", "message_contains": list(contains)}
        vs.append(v)

    def broken(name: str, desc: str, *contains: str, meta=None, **payloads) -> None:
        chunks = {**c0, **payloads}
        bad_codec(name, desc, meta or scene_meta(a0), attribute_entries(chunks), *contains)

    n0 = a0["n"]
    broken(
        "codec_invalid_mode_column0",
        "OPAC column 0 with prediction mode 2",
        "prediction mode",
        OPAC=with_model(c0["OPAC"], 0, 0, mode=2),
    )
    broken(
        "codec_invalid_mode_4",
        "SCAL column 1 with prediction mode 4",
        "prediction mode",
        SCAL=with_model(c0["SCAL"], 1, 0, mode=4),
    )
    broken(
        "codec_invalid_negative_u",
        "a geometric model with ratio index u = -1 (no index from the end)",
        "ratio",
        OPAC=with_model(c0["OPAC"], 0, 0, [2, 0, 9, 4, -1, 3]),
    )
    broken(
        "codec_invalid_big_u",
        "a geometric model with ratio index u = 131",
        "ratio",
        OPAC=with_model(c0["OPAC"], 0, 0, [2, 0, 9, 4, 131, 3]),
    )
    broken(
        "codec_invalid_far_centre",
        "a geometric model centred at 2^40 over the window 0..9",
        "centre",
        OPAC=with_model(c0["OPAC"], 0, 0, [2, 0, 9, 2**40, 5, 3]),
    )
    broken(
        "codec_invalid_model_kind",
        "a model of kind 7",
        "kind",
        OPAC=with_model(c0["OPAC"], 0, 0, [7, 0, 9, 4, 5, 3]),
    )
    broken(
        "codec_invalid_kind3_count",
        "an explicit model over 0..3 with 2 weights",
        "weights",
        OPAC=with_model(c0["OPAC"], 0, 0, [3, 0, 3, 1, 2]),
    )
    broken(
        "codec_invalid_spec_integer",
        "a constant model whose value is 2^63",
        "2^48",
        OPAC=with_model(c0["OPAC"], 0, 0, [1, 2**63]),
    )
    broken(
        "codec_invalid_window",
        "an explicit model over 1 symbol",
        "window",
        OPAC=with_model(c0["OPAC"], 0, 0, [3, 5, 5, 1]),
    )
    m, c, models, words = ecm_parts(c0["OPAC"])
    import zstandard

    frame = zstandard.ZstdCompressor(level=19).compress(msgpack.packb(models))
    broken(
        "codec_invalid_zstd_trailing",
        "one zero byte after the models' zstd frame",
        "unused data",
        OPAC=ecm(m, c, models, words, frame + b"\x00"),
    )
    broken(
        "codec_invalid_words_length",
        "range coder words one byte longer than whole words",
        "multiple of 4",
        OPAC=ecm(m, c, models, words + b"\x00"),
    )
    broken(
        "codec_invalid_shape",
        f"OPAC matrix of {n0 + 1} rows for {n0} Gaussians",
        "expected",
        OPAC=ecm(n0 + 1, 1, models, words),
    )
    const = [[1, [[1, 2**48]] * 15]]
    broken(
        "codec_invalid_value_range",
        "OPAC values that grow past 2^48 (constant residual 2^48, mode 1)",
        "2^48",
        OPAC=ecm(n0, 1, const, b""),
    )
    invalid_stream = [[0, [[3, 0, 1, 1, 1]] * 15]]
    broken(
        "codec_invalid_range_quantile",
        "range coder words ff ff ff ff ff ff ff ff: quantile 2^24 at the first symbol",
        "corrupt",
        OPAC=ecm(n0, 1, invalid_stream, b"\xff" * 8),
    )
    # POSN: gaps 2^(3 bits - 1) each: the second code reaches 2^(3 bits).
    from gspc.codec.entropy import encode_matrix, pack_bits

    bits = a0["position"]["bits"]
    lengths = np.full(n0, 3 * bits, np.int64)
    classes = encode_matrix(lengths[:, None])
    raw = pack_bits(np.full(n0, 1 << (3 * bits - 1), np.uint64), lengths - 1)
    broken(
        "codec_invalid_morton_overflow",
        f"position codes past 3 x {bits} bits",
        "past",
        POSN=msgpack.packb([classes, raw], use_bin_type=True),
    )
    classes, raw = msgpack.unpackb(c0["POSN"])
    broken(
        "codec_invalid_raw_extra_byte",
        "one byte more raw bits than the classes need",
        "raw-bit",
        POSN=msgpack.packb([classes, raw + b"\x00"], use_bin_type=True),
    )
    flags, values = msgpack.unpackb(c1["SHRS"])
    assert msgpack.unpackb(values)[0] == 0, "codec_sh1_no_rest must flag no Gaussian"
    empty_words = msgpack.packb([0, msgpack.unpackb(values)[1], b"", b"\x00\x00\x00\x00"], use_bin_type=True)
    bad_codec(
        "codec_invalid_empty_matrix_words",
        "SHRS values: an ECM of 0 rows with a range coder word",
        scene_meta(a1),
        attribute_entries({**c1, "SHRS": msgpack.packb([flags, empty_words], use_bin_type=True)}),
        "0 rows",
    )
    bad_codec(
        "codec_invalid_chunk_index",
        "OPAC with index 1",
        scene_meta(a0),
        attribute_entries(c0, OPAC=1),
        "index 1",
    )
    bad_codec(
        "codec_invalid_shrs_in_sh0",
        "an SHRS chunk in a file of SH degree 0",
        scene_meta(a0),
        attribute_entries({**c0, "SHRS": c3["SHRS"]}),
        "degree 0",
    )
    bad_codec(
        "codec_invalid_far_shift",
        "a far set coarser than its grid: far_shift equal to position.bits",
        scene_meta(dict(a6, position=dict(a6["position"], far_shift=a6["position"]["bits"]))),
        attribute_entries(c6),
        "far set",
    )

    # 10.1 bounds: finite but huge position fields overflowed in the expansion (issue 26).
    def grid_change(attributes: dict, key: str, axis: int | None, value: float) -> dict:
        grid = dict(attributes["position"])
        if axis is None:
            grid[key] = value
        else:
            grid[key] = [value if a == axis else x for a, x in enumerate(grid[key])]
        return scene_meta(dict(attributes, position=grid))

    bits0, bits5 = a0["position"]["bits"], a5["position"]["bits"]
    for name, desc, attributes, chunks, change in (
        ("grid_lo", "version 1 with position.lo[0] = 1e20 (beyond 2^64)", a0, c0, ("lo", 0, 1e20)),
        (
            "grid_corner",
            "version 1 whose grid's far corner lo + (2^bits - 1) step passes 2^64 on axis 1",
            a0,
            c0,
            ("step", 1, 2.0**65 / (2**bits0 - 1)),
        ),
        ("centre", "version 2 with position.centre[2] = -1e300", a5, c5, ("centre", 2, -1e300)),
        ("radius", "version 2 with position.radius = 1e38 (beyond 2^64)", a5, c5, ("radius", None, 1e38)),
        (
            "contracted_corner",
            "version 2 whose grid's far corner passes 32 in grid space on axis 0",
            a5,
            c5,
            ("step", 0, 64.0 / (2**bits5 - 1)),
        ),
    ):
        bad_codec(
            f"codec_invalid_{name}_bound",
            desc,
            grid_change(attributes, *change),
            attribute_entries(chunks),
            "position",
        )
    bad_codec(
        "codec_invalid_far_payload",
        "attribute codec version 3 with a POSN payload of two bins (the far curve missing)",
        scene_meta(a6),
        attribute_entries({**c6, "POSN": msgpack.packb(msgpack.unpackb(c6["POSN"])[:2], use_bin_type=True)}),
        "4 msgpack bins",
    )
    bad_codec(
        "codec_invalid_float_count",
        "attributes.n written as a float",
        scene_meta(dict(a0, n=float(n0))),
        attribute_entries(c0),
        "not an integer",
    )
    bad_codec(
        "codec_invalid_count_vs_payload",
        "300000 Gaussians declared in a file of about 2 KB",
        scene_meta(dict(a0, n=300000)),
        attribute_entries(c0),
        "payload bytes",
    )
    head = struct.calcsize("<IBBBB") + struct.calcsize("<II16s")
    first_gain = head + struct.calcsize("<48sI")  # view 0 has no image
    gain_at = first_gain + struct.calcsize("<48sI")
    assert struct.unpack_from("<I", side, gain_at - 4)[0] > 0
    for gname, g in [("zero", 0.0), ("nan", float("nan"))]:
        bad_side = side[:gain_at] + struct.pack("<f", g) + side[gain_at + 4 :]
        bad_codec(
            f"codec_invalid_side_gain_{gname}",
            f"SIDE view 1 with gain {g} (refused even with --no-restore)",
            scene_meta(a2),
            [*attribute_entries(c2), (entry("SIDE", bad_side), bad_side)],
            "gain",
        )
    big = side[:8] + struct.pack("<II", 65536, 65536) + side[16:]
    bad_codec(
        "codec_invalid_side_pixels",
        "SIDE views of 65536 x 65536 pixels",
        scene_meta(a2),
        [*attribute_entries(c2), (entry("SIDE", big), big)],
        "pixels",
    )
    bad_codec(
        "codec_invalid_side_index",
        "SIDE with index 1",
        scene_meta(a2),
        [*attribute_entries(c2), (entry("SIDE", side, index=1), side)],
        "index 1",
    )
    limit_vectors(vs, ok, bad_codec, a0, c0)
    step_vectors(ok, bad_codec, a0, c0, a5, c5)
    image_vectors(ok, bad_codec, a2, c2, side, a0, c0, views10, image)
    for key in ("opacity_levels", "rotation_levels"):
        bad_codec(
            f"codec_invalid_{key}_2p48",
            f"attributes.{key} = 2^48 + 1 (the limit of every integer of the codec, spec 10.0)",
            scene_meta(dict(a0, **{key: (1 << 48) + 1})),
            attribute_entries(c0),
            "levels",
        )
    grid = dict(a0["position"], centre=[0.0, 0.0, 0.0])
    bad_codec(
        "codec_invalid_centre_at_version_1",
        "a version-1 position grid with a centre (and no radius)",
        scene_meta(dict(a0, position=grid)),
        attribute_entries(c0),
        "contraction",
    )
    tiny = [dict(views10[0], residual=dict(views10[0]["residual"], gain=1e-50)), views10[1]]
    bad_codec(
        "codec_invalid_gain_rounds_to_zero",
        "a 1.0-layout residual gain of 1e-50, positive as binary64 but 0 as binary32",
        scene_meta(a0, {"views": tiny, "background": BACKGROUND, "restorer": "none"}),
        [*attribute_entries(c0), (entry("RESI", image), image)],
        "gain",
    )
    precision_vectors(ok, bad_codec, a0, c0)
    codebook_vectors(ok, bad_codec)
    tile_vectors(ok, bad_codec)
    return vs


def step_vectors(ok, bad_codec, a0: dict, c0: dict, a5: dict, c5: dict) -> None:
    """10.0, 10.1 (1.4, revised): quantiser steps at and past 2^64, and position grids that span under
    binary32's resolution at their corners (each decoded every value infinite, or every Gaussian onto one
    point)."""
    ok(
        "codec_step_at_bound",
        "scale_step = 2^64, the largest step 10.0 allows: every decoded log-scale a finite binary32",
        scene_meta(dict(a0, scale_step=2.0**64)),
        attribute_entries(c0),
    )
    bad_codec(
        "codec_invalid_step_bound",
        "scale_step = 3.4e38 (finite, but its decoded values overflow binary32)",
        scene_meta(dict(a0, scale_step=3.4e38)),
        attribute_entries(c0),
        "scale_step",
    )
    a7, c7 = encode_classed(tiny_scene(120, 3, 9), (-1, 2), 9)
    classes = [dict(a7["classes"][0], dc_step=1e300), *a7["classes"][1:]]
    bad_codec(
        "codec_invalid_class_step_bound",
        "attribute codec version 4 whose classes[0].dc_step is 1e300",
        scene_meta(dict(a7, classes=classes)),
        attribute_entries(c7),
        "classes[0].dc_step",
        minor=4,
    )
    grid = dict(a0["position"], lo=[2.0**64, *a0["position"]["lo"][1:]])
    bad_codec(
        "codec_invalid_grid_resolution",
        "version 1 with position.lo[0] = 2^64 (within the bound of 10.1, and its corner rounds to 2^64): "
        "the grid spans under binary32's resolution there, every Gaussian would decode onto one x",
        scene_meta(dict(a0, position=grid)),
        attribute_entries(c0),
        "on axis 0",
    )
    grid = dict(a5["position"], centre=[2.0**40, *a5["position"]["centre"][1:]])
    bad_codec(
        "codec_invalid_centre_resolution",
        "version 2 with position.centre[0] = 2^40: the grid spans under binary32's resolution there",
        scene_meta(dict(a5, position=grid)),
        attribute_entries(c5),
        "on axis 0",
        minor=2,
    )


def image_vectors(
    ok, bad_codec, a2: dict, c2: dict, side: bytes, a0: dict, c0: dict, views10: list, webp: bytes
) -> None:
    """10.7 (1.4, revised): residual images whose signature or declared size is wrong (refused by every
    decoder) and images cut short after a valid header (refused by a decoder that decodes them only)."""
    from gspc.format.side_chunk import pack_side, unpack_side

    unpacked = unpack_side(side)
    ((k, image),) = unpacked.images.items()

    def with_image(img: bytes) -> list:
        payload = pack_side(unpacked.views, {k: img})
        return [*attribute_entries(c2), (entry("SIDE", payload), payload)]

    ok(
        "codec_residual_damaged",
        f"SIDE view 1's JPEG XL residual cut to {len(image) // 2} of its {len(image)} bytes after a valid "
        "size header: decodes without the residuals; a decoder that decodes them refuses it",
        scene_meta(a2),
        with_image(image[: len(image) // 2]),
        residuals=False,
    )
    import imagecodecs

    tiny = imagecodecs.jpegxl_encode(np.full((1, 1, 3), 128, np.uint8), lossless=True, effort=3)
    bad_codec(
        "codec_invalid_residual_size",
        "SIDE view 1's residual a JPEG XL image that declares 1x1 pixels (its view's residual is 12x10)",
        scene_meta(a2),
        with_image(tiny),
        "declares 1x1",
    )
    bad_codec(
        "codec_invalid_residual_signature",
        "SIDE view 1's residual a WebP image where the chunk names JPEG XL",
        scene_meta(a2),
        with_image(webp),
        "signature",
    )
    meta10 = scene_meta(a0, {"views": views10, "background": BACKGROUND, "restorer": "none"})
    cut = webp[: len(webp) - 8]
    ok(
        "codec_residual_damaged_webp",
        f"format 1.0 side information: the RESI chunk's lossless WebP cut to {len(cut)} of its {len(webp)} "
        "bytes: decodes without the residuals; a decoder that decodes them refuses it",
        meta10,
        [*attribute_entries(c0), (entry("RESI", cut), cut)],
        minor=0,
        residuals=False,
    )


def refuser(bad_codec, attributes: dict, chunks: dict[str, bytes], minor: int):
    """``refused(name, desc, *contains, meta=None, **payloads)``: a refused vector of these attribute chunks
    with ``payloads`` in place of theirs (None: the chunk left out), or another ``meta``."""

    def refused(name: str, desc: str, *contains: str, meta=None, **payloads) -> None:
        changed = {k: v for k, v in {**chunks, **payloads}.items() if v is not None}
        meta = meta or scene_meta(attributes)
        bad_codec(name, desc, meta, attribute_entries(changed), *contains, minor=minor)

    return refused


def precision_vectors(ok, bad_codec, a0: dict, c0: dict) -> None:
    """Attribute codec version 4 (spec 10.13): decoded files on each kind of grid, and one refused file for
    each of its (v) decisions in 10.11."""
    from gspc.codec.entropy import encode_matrix

    a7, c7 = encode_classed(tiny_scene(120, 3, 9), (-1, 2), 9)
    ok(
        "codec_precision_sh3",
        f"120 Gaussians, SH degree 3: attribute codec version 4, {len(a7['classes']) + 1} precision classes "
        "and per-Gaussian SH degrees 0..3 (PREC, each attribute chunk an array of bins) on a plain grid",
        scene_meta(a7),
        attribute_entries(c7),
        minor=4,
    )
    a8, c8 = encode_classed(unbounded_scene(120, 50, 10, 0.5, degree=0), (-1, 1), 10)
    assert "far_count" in a8["position"], "codec_precision_far_set must code a far set"
    ok(
        "codec_precision_far_set",
        f"170 Gaussians, SH degree 0: attribute codec version 4, {len(a8['classes']) + 1} precision classes "
        f"on a contracted grid with a far set of {a8['position']['far_count']} (PREC of one column, no SHRS)",
        scene_meta(a8),
        attribute_entries(c8),
        minor=4,
    )
    a9, c9 = encode_classed(tiny_scene(60, 1, 11), (0, 0), 11)
    assert a9["classes"] == [], "codec_precision_one_class must have class 0 only"
    ok(
        "codec_precision_one_class",
        "60 Gaussians, SH degree 1: attribute codec version 4 with one class (an empty classes array): "
        "each attribute chunk an array of one bin, SHRS of one band",
        scene_meta(a9),
        attribute_entries(c9),
        minor=4,
    )

    refused = refuser(bad_codec, a7, c7, minor=4)

    def prec(column: int, row: int, value: int) -> bytes:
        """c7's PREC with one entry changed."""
        from gspc.codec.entropy import decode_matrix

        m = decode_matrix(c7["PREC"], (a7["n"], 2))
        m[row, column] = value
        return encode_matrix(m)

    count = len(a7["classes"]) + 1
    refused(
        "codec_invalid_precision_class",
        f"PREC names class {count} of {count} classes (0 .. {count - 1})",
        "precision class",
        PREC=prec(0, 5, count),
    )
    refused(
        "codec_invalid_precision_sh_degree",
        "PREC names SH degree 4 in a file of SH degree 3",
        "SH degree",
        PREC=prec(1, 5, 4),
    )
    prec0 = encode_matrix(np.zeros((a0["n"], 1), np.int64))
    bad_codec(
        "codec_invalid_prec_below_version_4",
        "a PREC chunk (every Gaussian class 0) in a file of attribute codec version 1",
        scene_meta(a0),
        attribute_entries({**c0, "PREC": prec0}),
        "PREC",
    )
    refused("codec_invalid_prec_missing", "attribute codec version 4 without a PREC chunk", "PREC", PREC=None)
    maps = [a7["classes"][0]] * 16
    refused(
        "codec_invalid_class_maps",
        "attribute codec version 4 with 16 classes maps (at most 15)",
        "at most 15",
        meta=scene_meta(dict(a7, classes=maps)),
    )
    lacking = [{k: v for k, v in a7["classes"][0].items() if k != "dc_step"}, *a7["classes"][1:]]
    refused(
        "codec_invalid_class_map_key",
        "attribute codec version 4 whose classes[0] lacks dc_step",
        "dc_step",
        meta=scene_meta(dict(a7, classes=lacking)),
    )
    # 10.0: the ECMs of one chunk share one table bound; two of OPAC's get an unused wide model (column 0,
    # bucket 14: column 0's intra class is always 0), each within its own ECM's bound.
    bins = msgpack.unpackb(c7["OPAC"])
    others = sum(table_entries(ecm_parts(b)[2]) for b in bins if ecm_parts(b)[0])
    for extra, good in ((0, True), (1, False)):
        half = ((1 << 22) - others + extra) // 2
        widths = (half, (1 << 22) - others + extra - half)
        wide = [with_model(b, 0, 14, [2, 0, w - 1, 0, 0, 0]) for b, w in zip(bins, widths)]
        desc = (
            f"OPAC's {len(bins)} ECMs with tables that sum to 2^22{' + 1' if extra else ''} entries (unused "
            f"models of {widths[0]} and {widths[1]} symbols in classes 0 and 1)"
        )
        chunks = attribute_entries({**c7, "OPAC": msgpack.packb([*wide, *bins[2:]], use_bin_type=True)})
        if good:
            ok("codec_precision_tables_floor", desc, scene_meta(a7), chunks, minor=4)
        else:
            bad_codec("codec_invalid_precision_tables", desc, scene_meta(a7), chunks, "entries", minor=4)
    bins = msgpack.unpackb(c7["SCAL"])
    refused(
        "codec_invalid_precision_bins",
        f"SCAL an array of {count + 1} bins for {count} classes (an empty ECM added)",
        "bins",
        SCAL=msgpack.packb([*bins, msgpack.packb([0, 3, b"", b""], use_bin_type=True)], use_bin_type=True),
    )


def codebook_vectors(ok, bad_codec) -> None:
    """Attribute codec version 5 (spec 10.16, format 1.8): the SH rest by codebook decoded, and one refused
    file for each of its (v) decisions in 10.11."""
    from gspc.codec.entropy import decode_matrix, encode_matrix

    a, c = encode_classed(tiny_scene(150, 2, 12, rest_fraction=0.8), (-1, 1), 12, codebook=24)
    # gspc's encoder gives a Gaussian with an entry every band; every third of them here keeps band 1 only,
    # as a file may (its entry's band 2 is not decoded).
    prec = decode_matrix(c["PREC"], (a["n"], 2))
    prec[np.flatnonzero(prec[:, 1] == 2)[::3], 1] = 1
    c = dict(c, PREC=encode_matrix(prec))
    degrees = prec[:, 1]
    assert a["classes"] and set(degrees.tolist()) == {0, 1, 2}, "codec_codebook must mix degrees 0..2"
    ok(
        "codec_codebook",
        f"150 Gaussians, SH degree 2: attribute codec version 5, the SH rest by a codebook of "
        f"{a['codebook']} entries (SHRS [entries, indices]), {len(a['classes']) + 1} precision classes, SH "
        "degrees 0, 1 and 2",
        scene_meta(a),
        attribute_entries(c),
        minor=8,
    )

    refused = refuser(bad_codec, a, c, minor=8)

    table, index = msgpack.unpackb(c["SHRS"])
    coded = int((degrees >= 1).sum())
    wrong = decode_matrix(index, (coded, 1))
    wrong[coded // 2, 0] = a["codebook"]
    refused(
        "codec_invalid_codebook_index",
        f"an SHRS index of {a['codebook']} for a codebook of {a['codebook']} entries (0 .. E - 1)",
        "codebook index",
        SHRS=msgpack.packb([table, encode_matrix(wrong)], use_bin_type=True),
    )
    refused(
        "codec_invalid_codebook_bins",
        "SHRS at version 5 an array of three bins (an empty ECM added)",
        "bins",
        SHRS=msgpack.packb([table, index, msgpack.packb([0, 1, b"", b""])], use_bin_type=True),
    )
    refused(
        "codec_invalid_codebook_count",
        f"a codebook of {a['n'] + 1} entries for {a['n']} Gaussians (at most n)",
        "codebook",
        meta=scene_meta(dict(a, codebook=a["n"] + 1)),
    )
    refused(
        "codec_invalid_codebook_missing",
        "attribute codec version 5 without its codebook key",
        "codebook",
        meta=scene_meta({k: v for k, v in a.items() if k != "codebook"}),
    )
    a0, c0 = encode_classed(tiny_scene(40, 0, 13), (0, 0), 13)
    bad_codec(
        "codec_invalid_codebook_sh_degree_0",
        "attribute codec version 5 (a codebook of 1 entry) at SH degree 0",
        scene_meta(dict(a0, version=5, codebook=1)),
        attribute_entries(c0),
        "SH degree 0",
        minor=8,
    )


def tile_vectors(ok, bad_codec) -> None:
    """Spatial tiles (format 1.5, spec 10.14): three tiles of SH degree 1 (one on a contracted grid, one of
    attribute codec version 4) decoded whole, and one refused file for each tile rule marked (v) in 10.11."""
    from gspc.codec.attributes import decode_attributes
    from gspc.format.attribute_section import AttributeSection

    sections = [
        encode_scene(tiny_scene(30, 1, 21)),
        encode_scene(unbounded_scene(30, 10, 22, 0.5, degree=1)),
        encode_classed(tiny_scene(40, 1, 23), (-1, 1), 23),
    ]

    def box(a: dict, c: dict[str, bytes]) -> list[float]:
        m = decode_attributes(c, AttributeSection.from_dict(a)).means.numpy()
        return [float(x) for x in (*m.min(0), *m.max(0))]

    tiles = [{"box": box(a, c), "attributes": a} for a, c in sections]

    def tiled(index: list, per_tile: list[dict[str, bytes]] | None = None, order=None, extra_meta=None):
        """(meta, chunks) of a tiled file: the index, then each tile's chunks with its number."""
        meta = {
            "encoder": "gspc make_vectors",
            "scene": {"num_gaussians": sum(t["attributes"]["n"] for t in index), "sh_degree": 1},
            "side_info": {"background": BACKGROUND, "restorer": "none"},
            **(extra_meta or {}),
        }
        payload = msgpack.packb(index, use_bin_type=True)
        chunks = [(entry("TIDX", payload), payload)]
        for k, c in enumerate(per_tile or [c for _, c in sections]):
            chunks += attribute_entries(c, **dict.fromkeys(c, k))
        return meta, order(chunks) if order else chunks

    meta, chunks = tiled(tiles)
    ok(
        "codec_tiles",
        "format 1.5: three tiles of SH degree 1 (a plain grid, a contracted grid, attribute codec version 4 "
        "with precision classes) in a TIDX index, each tile's chunks indexed by its number",
        meta,
        chunks,
        minor=5,
    )
    outside = [dict(tiles[0], box=[*tiles[0]["box"][:3], *tiles[0]["box"][:3]]), *tiles[1:]]
    cases = [
        ("codec_invalid_tile_box", "tile 0's box is its lowest corner", "outside its box", tiled(outside)),
        (
            "codec_invalid_tile_count",
            "tile 0's attributes declare one Gaussian more than its chunks hold",
            "",
            tiled([dict(tiles[0], attributes=dict(tiles[0]["attributes"], n=tiles[0]["attributes"]["n"] + 1)),
                   *tiles[1:]]),
        ),
        ("codec_invalid_tile_one", "a tile index of one tile (a tiled file holds 2 or more)", "2..",
         tiled(tiles[:1], [sections[0][1]])),
        ("codec_invalid_tile_degrees", "tiles of SH degrees 1 and 0", "SH degrees",
         tiled([*tiles[:2], dict(tiles[2], attributes=dict(encode_scene(tiny_scene(40, 0, 24))[0]))])),
        ("codec_invalid_tile_order", "tile 1's chunks before tile 0's", "comes after",
         tiled(tiles, order=lambda chs: [chs[0], *sorted(chs[1:], key=lambda ch: -ch[0]["index"])])),
        ("codec_invalid_tile_index_last", "the tile index after the tiles' chunks", "before the tile index",
         tiled(tiles, order=lambda chs: [*chs[1:], chs[0]])),
        ("codec_invalid_tile_names_none", "an OPAC chunk naming tile 3 of 3", "names no tile",
         tiled(tiles, order=lambda chs: [(dict(e, index=3), p) if e["type"] == "OPAC" and e["index"] == 2
                                         else (e, p) for e, p in chs])),
        ("codec_invalid_tile_attributes_key", "a tiled file whose meta also has an attributes section",
         "attributes section", tiled(tiles, extra_meta={"attributes": sections[0][0]})),
    ]  # fmt: skip
    for name, desc, needle, (m, chs) in cases:
        bad_codec(name, desc, m, chs, *([needle] if needle else []), minor=5)
    tile_side_vectors(ok, bad_codec, sections, tiles, tiled)


def tile_side_chunk() -> bytes:
    """A TSID payload (10.15, the SIDE layout of 10.9): one 16x12 view with a lossless WebP residual at full
    resolution."""
    from gspc.format.side_chunk import pack_side
    from gspc.format.view_records import ViewRecord

    w, h = 16, 12
    image, gain = residual_image(h, w, 9, "webp")
    residual = {"codec": "webp", "shape": [h, w], "bits": 8, "gain": gain, "offset": 128}
    return pack_side([ViewRecord.from_dict({"camera": camera(2, w, h), "residual": residual})], {0: image})


def tile_side_vectors(ok, bad_codec, sections: list, tiles: list, tiled) -> None:
    """Side information per tile (format 1.6, spec 10.15): tile_vectors' three tiles with a TSID on tiles 0
    and 2, decoded with their views, and one refused file for each rule of 10.15; the same with the tiles
    drawn with a tile's views (1.7), and one refused file for each rule of a tile's ``drawn`` list; the same
    with tile 0's side information serving tiles 0 and 1 (a span, 1.9), and one refused file for each rule of
    10.17."""
    from gspc.format.side_chunk import pack_side
    from gspc.format.view_records import ViewRecord
    from gspc.limits import PIXEL_FLOOR, PIXELS_PER_FILE_BYTE

    meta, base = tiled(tiles)

    def tsid(payload: bytes, k: int) -> tuple[dict, bytes]:
        return entry("TSID", payload, index=k, flags=0), payload  # optional (spec section 6)

    def placed(chunks: list, item: tuple, before: int | None = None) -> list:
        """``chunks`` with ``item`` before the first chunk of tile ``before`` (None: at the end)."""
        ours = [i for i, (e, _) in enumerate(chunks) if e["type"] != "TIDX" and e["index"] == before]
        at = ours[0] if ours else len(chunks)
        return [*chunks[:at], item, *chunks[at:]]

    side0, side2 = side_chunk(), tile_side_chunk()
    ok(
        "codec_tile_sides",
        "format 1.6: codec_tiles' three tiles, tile 0 with a TSID of two 24x20 views (a lossless JPEG XL "
        "residual at half resolution on view 1) after its attribute chunks, tile 2 with a TSID of one 16x12 "
        "view (a lossless WebP residual) before its attribute chunks, tile 1 with none",
        meta,
        placed(placed(base, tsid(side0, 0), before=1), tsid(side2, 2), before=2),
        minor=6,
    )

    # One view (no residual) of tile 1 within the file's floor of 2^22 pixels but past the tile's share of
    # it, Q_1 / Q: the TSID's length does not depend on the view's size.
    def one_view(w: int, h: int) -> bytes:
        return pack_side([ViewRecord.from_dict({"camera": camera(1, w, h)})], {})

    q = [sum(len(p) for e, p in base if e["type"] != "TIDX" and e["index"] == k) for k in range(3)]
    q[1] += len(one_view(1, 1))
    share = min(1 << 28, max(PIXEL_FLOOR * q[1] // sum(q), PIXELS_PER_FILE_BYTE * q[1]))
    w = 4096
    h = share // w + 1
    assert share < w * h <= PIXEL_FLOOR and h <= 65536
    big = one_view(w, h)
    cases = [
        ("codec_invalid_tsid_names_none", "a TSID chunk naming tile 3 of 3", "names no tile",
         placed(base, tsid(side0, 3))),
        ("codec_invalid_tsid_order", "tile 0's TSID after tile 2's chunks", "comes after",
         placed(base, tsid(side0, 0))),
        ("codec_invalid_tsid_side", "tile 0's TSID a byte longer than its SIDE layout (10.9) ends",
         "images need", placed(base, tsid(side0 + b"\0", 0), before=1)),
        ("codec_invalid_tsid_pixels",
         f"tile 1's TSID: one view of {w}x{h} = {w * h:,} pixels, within the file's floor of 2^22 but past "
         f"the tile's share of it ({share:,}: {q[1]:,} of the tiles' {sum(q):,} bytes)",
         "pixels", placed(base, tsid(big, 1), before=2)),
    ]  # fmt: skip
    for name, desc, needle, chs in cases:
        bad_codec(name, desc, meta, chs, needle, minor=6)
    a, c = sections[0]
    bad_codec(
        "codec_invalid_tsid_untiled",
        "an untiled file of 30 Gaussians with a TSID chunk (index 0)",
        scene_meta(a),
        [*attribute_entries(c), tsid(side0, 0)],
        "without a tile index",
        minor=6,
    )
    # Format 1.7: tiles drawn with a tile's views (10.14 `drawn`, 10.15).
    with_drawn = [dict(tiles[0], drawn=[1, 2]), tiles[1], dict(tiles[2], drawn=[1])]
    drawn_meta, drawn_base = tiled(with_drawn)
    ok(
        "codec_tile_sides_drawn",
        "format 1.7: codec_tile_sides with tile 0's views showing tiles 1 and 2 beside it and tile 2's "
        "tile 1 (the index's drawn lists); decoded as codec_tile_sides",
        drawn_meta,
        placed(placed(drawn_base, tsid(side0, 0), before=1), tsid(side2, 2), before=2),
        minor=7,
    )
    for name, desc, drawn in [
        ("codec_invalid_drawn_self", "tile 0's drawn list names tile 0", [0]),
        ("codec_invalid_drawn_none", "tile 0's drawn list names tile 3 of 3", [3]),
        ("codec_invalid_drawn_twice", "tile 0's drawn list names tile 1 twice", [1, 1]),
    ]:
        m, chs = tiled([dict(tiles[0], drawn=drawn), *tiles[1:]])
        bad_codec(name, desc, m, placed(chs, tsid(side0, 0), before=1), "drawn", minor=7)

    def sided(chunks: list) -> list:
        """``chunks`` with codec_tile_sides' TSIDs: side0 on tile 0, side2 on tile 2."""
        return placed(placed(chunks, tsid(side0, 0), before=1), tsid(side2, 2), before=2)

    # Format 1.9: tile 0's side information serving tiles 0 and 1 (10.14 `span`, 10.17).
    spanned = [dict(tiles[0], span=2), *tiles[1:]]
    span_meta, span_base = tiled(spanned)
    ok(
        "codec_tile_span",
        "format 1.9: codec_tile_sides with tile 0's TSID serving tiles 0 and 1 (tile 0's span 2; tile 1 has "
        "no TSID); decoded as codec_tile_sides",
        span_meta,
        sided(span_base),
        minor=9,
    )

    cases = [
        ("codec_invalid_span_past_end", "tile 2 of 3 (with a TSID) has span 2, past the last tile",
         [*tiles[:2], dict(tiles[2], span=2)], sided, ("span",)),
        ("codec_invalid_span_no_tsid", "tile 1 (without a TSID) has span 2; only tile 0 has a TSID",
         [tiles[0], dict(tiles[1], span=2), tiles[2]], lambda chs: placed(chs, tsid(side0, 0), before=1),
         ("span", "TSID")),
        ("codec_invalid_span_member_tsid", "tile 0's span 2 and a TSID on tile 1, its member, as on 0 and 2",
         spanned, lambda chs: placed(sided(chs), tsid(side2, 1), before=2), ("span",)),
        ("codec_invalid_span_drawn_member", "tile 0's span 2 with drawn [1], a tile of its own span",
         [dict(tiles[0], span=2, drawn=[1]), *tiles[1:]], sided, ("span", "drawn")),
    ]  # fmt: skip
    for name, desc, index, with_sides, needles in cases:
        m, chs = tiled(index)
        bad_codec(name, desc, m, with_sides(chs), *needles, minor=9)


def all_vectors() -> list[Vector]:
    vs = valid_vectors() + invalid_vectors() + codec_vectors()
    names = [v.name for v in vs]
    assert len(names) == len(set(names)), "vector names must be unique"
    return vs


ONE_VALUE = [[1, 0]] * 15  # a column's 15 specs when every value is 0 (spec 10.0, kind 1)


def constant_chunks(attributes: dict, n: int) -> dict[str, bytes]:
    """Payloads of ``n`` identical Gaussians at SH degree 0: every column one-value, no range-coder words."""
    half = attributes["rotation_levels"] // 2
    return {
        "POSN": msgpack.packb([ecm(n, 1, [[0, ONE_VALUE]], b""), b""], use_bin_type=True),
        "OPAC": ecm(n, 1, [[0, ONE_VALUE]], b""),
        "SCAL": ecm(n, 3, [[0, ONE_VALUE]] * 3, b""),
        "ROTN": ecm(n, 4, [[0, ONE_VALUE], *[[0, [[1, half]] * 15]] * 3], b""),
        "SHDC": ecm(n, 3, [[0, ONE_VALUE]] * 3, b""),
    }


def table_entries(models: list) -> int:
    return sum(s[2] - s[1] + 1 for _, specs in models for s in specs if s[0] >= 2)


def sized_spec(models: list, size: int) -> list:
    """A kind-3 spec for column 0, bucket 14 (no row of column 0 uses it: its intra class is always 0) that
    makes the msgpack of ``models`` exactly ``size`` bytes: weights of 1 take one byte, of 128 two."""

    def packed(count: int, twos: int) -> int:
        spec = [3, 0, count - 1, *([128] * twos), *([1] * (count - twos))]
        return len(msgpack.packb([[models[0][0], [*models[0][1][:14], spec]], *models[1:]]))

    count = 2
    for _ in range(5):  # the array's length prefix grows with it: settle
        count += size - packed(count, 0)
    twos = size - packed(count, 0)
    assert 0 <= twos <= count and packed(count, twos) == size
    return [3, 0, count - 1, *([128] * twos), *([1] * (count - twos))]


def limit_vectors(vs: list, ok, bad_codec, a0: dict, c0: dict) -> None:
    """Files at the size-bounded limits of spec 10.10 (decoded) and one step past each (refused)."""
    floor = 1 << 16
    for n, good in ((floor, True), (floor + 1, False)):
        a = dict(a0, n=n)
        chunks = attribute_entries(constant_chunks(a, n))
        if good:
            ok(
                "codec_count_floor",
                f"{n} identical Gaussians in about 1 KB: the count floor of 10.10",
                scene_meta(a),
                chunks,
            )
        else:
            bad_codec(
                "codec_invalid_count_past_floor",
                f"{n} identical Gaussians in about 1 KB",
                scene_meta(a),
                chunks,
                "payload bytes",
            )
    m, c, models, words = ecm_parts(c0["OPAC"])
    others = table_entries([[models[0][0], models[0][1][:14]], *models[1:]])
    for extra, good in ((0, True), (1, False)):
        wide = [2, 0, (1 << 22) - others + extra - 1, 0, 0, 0]
        opac = ecm(m, c, [[models[0][0], [*models[0][1][:14], wide]], *models[1:]], words)
        chunks = attribute_entries({**c0, "OPAC": opac})
        desc = (
            f"OPAC models whose tables sum to 2^22{' + 1' if extra else ''} entries (an unused model of "
            f"{wide[2] + 1} symbols)"
        )
        if good:
            ok("codec_tables_floor", desc, scene_meta(a0), chunks)
        else:
            bad_codec("codec_invalid_tables_past_floor", desc, scene_meta(a0), chunks, "table entries")
    for size, good in ((floor, True), (floor + 1, False)):
        spec = sized_spec(models, size)
        opac = ecm(m, c, [[models[0][0], [*models[0][1][:14], spec]], *models[1:]], words)
        chunks = attribute_entries({**c0, "OPAC": opac})
        desc = (
            f"OPAC models of {size} bytes from a small zstd frame (an unused explicit model of {spec[2] + 1} "
            "weights)"
        )
        if good:
            ok("codec_models_floor", desc, scene_meta(a0), chunks)
        else:
            bad_codec("codec_invalid_models_past_floor", desc, scene_meta(a0), chunks, "declare")


def manifest(vs: list[Vector]) -> dict:
    return {
        "about": (
            "gspc conformance vectors (spec/gspc-format.md, section 13). expect 'ok': a reader returns "
            "this version, meta (msgpack bin shown as {'$bin': hex}) and these chunks in file order, "
            "unknown optional ones under 'skipped'. expect 'error': a reader refuses the file; 'error' "
            "names the FormatError subclass of the reference reader and 'message_contains' words its "
            "message holds. 'codec' (codec_* files, section 10): expect 'ok': the decoded attributes "
            "(binary32 little-endian arrays in curve order: shape, SHA-256 of the bytes, row 0's values) "
            "and per side-information view its size and decoded residual R (H x W x 3, after upsampling), "
            "the whole scene's views first, then each tile's own (a TSID, spec 10.15) with its tile's number "
            "('tile'); "
            "with 'residuals': 'refused', those of a decoder that does not decode the residual images, while "
            "one that decodes them refuses the file (spec 10.7); "
            "expect 'error': a decoder refuses the payloads (the reference raises CodecError)."
        ),
        "generated_by": "python tools/make_vectors.py",
        "vectors": [v.manifest() for v in vs],
    }


def readme(vs: list[Vector]) -> str:
    lines = [
        "# gspc conformance vectors",
        "",
        "Made by `python tools/make_vectors.py`; checked by `tests/test_conformance.py`. Each file",
        "exercises one feature or one kind of damage; MANIFEST.json holds the exact expected outcome",
        "(decoded meta, chunk hashes, or the error). The format is described in `../gspc-format.md`.",
        "`codec_*` files are real encodes (valid containers): 'decodes' ones list their decoded attributes'",
        "digests in MANIFEST.json, the others must be refused by a decoder (spec section 10.11).",
        "",
        "| file | bytes | expected | what it holds |",
        "|---|---:|---|---|",
    ]
    for v in vs:
        expected = v.error or "ok"
        if v.codec is not None:
            expected = "decodes" if v.codec["expect"] == "ok" else "ok; codec: CodecError"
            if v.codec.get("residuals") == "refused":
                expected = "decodes without residuals; with them CodecError"
        lines.append(f"| `{v.name}.gspc` | {len(v.data)} | {expected} | {v.description} |")
    return "\n".join(lines) + "\n"


def check_with_reader(vs: list[Vector]) -> list[str]:
    """Problems where the reference reader disagrees with a vector's stated outcome."""
    from gspc.format import container

    problems = []
    for v in vs:
        try:
            c = container.unpack(v.data)
        except container.FormatError as e:
            if type(e).__name__ != v.error:
                problems.append(
                    f"{v.name}: expected {v.error or 'ok'}, reader raised {type(e).__name__}: {e}"
                )
            elif missing := [s for s in v.message_contains if s not in str(e)]:
                problems.append(f"{v.name}: message {str(e)!r} lacks {missing}")
            continue
        if v.error:
            problems.append(f"{v.name}: expected {v.error}, reader accepted it")
        elif c.header != v.meta or [(x.type, x.index, x.payload) for x in c.chunks] != [
            (e["type"], e["index"], p) for e, p in v.kept
        ]:
            problems.append(f"{v.name}: reader decoded different content")
        elif v.codec is not None and v.codec.get("residuals") == "refused":
            from gspc.errors import CodecError

            try:
                reference_decode(v.data)
                problems.append(f"{v.name}: the reference decoded residuals a decoder must refuse")
            except CodecError:
                pass
        elif v.codec is not None and v.codec["expect"] == "error":
            from gspc.errors import CodecError

            try:
                reference_decode(v.data)
                problems.append(f"{v.name}: expected CodecError, the reference decoder accepted it")
            except CodecError as e:
                if missing := [s for s in v.codec["message_contains"] if s not in str(e)]:
                    problems.append(f"{v.name}: codec message {str(e)!r} lacks {missing}")
    return problems


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare with spec/vectors/ instead of writing")
    args = ap.parse_args()
    vs = all_vectors()
    if problems := check_with_reader(vs):
        print("\n".join(problems), file=sys.stderr)
        return 1
    files = {v.name + ".gspc": v.data for v in vs}
    files["MANIFEST.json"] = (json.dumps(manifest(vs), indent=1) + "\n").encode()
    files["README.md"] = readme(vs).encode()
    if args.check:
        stale = [n for n, d in files.items() if not (OUT / n).is_file() or (OUT / n).read_bytes() != d]
        extra = sorted(p.name for p in OUT.glob("*.gspc") if p.name not in files)
        for n in stale + extra:
            print(f"differs: spec/vectors/{n}", file=sys.stderr)
        return 1 if stale or extra else 0
    OUT.mkdir(parents=True, exist_ok=True)
    for p in OUT.glob("*.gspc"):
        if p.name not in files:
            p.unlink()
    for n, d in files.items():
        (OUT / n).write_bytes(d)
    print(f"wrote {len(vs)} vectors to {OUT.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
