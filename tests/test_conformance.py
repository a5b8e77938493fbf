"""Each vector in spec/vectors/ gives the outcome MANIFEST.json states; the spec hex dump is valid_minimal.

Codec vectors (section 10) are checked twice: with gspc's decoder and with tests/spec_reader.py, a decoder
written from the spec alone (no gspc import), which must give the same bits.
"""

import hashlib
import json
import re
import struct
import sys
import zlib
from pathlib import Path

import make_vectors as mv
import msgpack
import numpy as np
import pytest
import spec_reader

from gspc.errors import CodecError, FormatError, InputError
from gspc.format import container
from gspc.format.container import Chunk, pack, unpack

ROOT = Path(__file__).resolve().parents[1]
VECTORS = ROOT / "spec" / "vectors"
SPEC = ROOT / "spec" / "gspc-format.md"
MANIFEST = json.loads((VECTORS / "MANIFEST.json").read_text())["vectors"]


def from_json(value):
    if isinstance(value, dict):
        if set(value) == {"$bin"}:
            return bytes.fromhex(value["$bin"])
        return {k: from_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [from_json(v) for v in value]
    return value


def chunk_summary(chunks: list[Chunk]) -> list[dict]:
    return [
        {
            "type": c.type,
            "index": c.index,
            "required": c.required,
            "length": len(c.payload),
            "sha256": hashlib.sha256(c.payload).hexdigest(),
        }
        for c in chunks
    ]


@pytest.mark.parametrize("vector", MANIFEST, ids=[v["file"] for v in MANIFEST])
def test_vector(vector: dict) -> None:
    data = (VECTORS / vector["file"]).read_bytes()
    assert hashlib.sha256(data).hexdigest() == vector["sha256"], (
        "vector file changed since the manifest was made"
    )
    if vector["expect"] == "ok":
        c = unpack(data)
        assert list(c.version) == vector["version"]
        assert c.header == from_json(vector["meta"])
        assert chunk_summary(c.chunks) == vector["chunks"]
        assert chunk_summary(c.skipped) == vector["skipped"]
        return
    with pytest.raises(FormatError) as err:
        unpack(data)
    assert type(err.value).__name__ == vector["error"], str(err.value)
    for words in vector["message_contains"]:
        assert words in str(err.value)


def test_manifest_covers_every_file() -> None:
    assert {v["file"] for v in MANIFEST} == {p.name for p in VECTORS.glob("*.gspc")}
    kinds = {v["error"] for v in MANIFEST if v["expect"] == "error"}
    error_classes = {
        c.__name__ for c in vars(container).values() if isinstance(c, type) and issubclass(c, FormatError)
    }
    assert kinds == error_classes - {"FormatError"}, "every error class is exercised by a vector"


def test_vectors_are_what_make_vectors_makes() -> None:
    """The stored files are reproducible; a change to the tool that changes them must be deliberate."""
    vs = mv.all_vectors()
    assert {v.name + ".gspc": v.data for v in vs} == {p.name: p.read_bytes() for p in VECTORS.glob("*.gspc")}
    assert mv.manifest(vs)["vectors"] == MANIFEST
    assert mv.check_with_reader(vs) == []


def test_make_vectors_check_mode() -> None:
    """``tools/make_vectors.py --check`` regenerates every vector and finds the stored ones identical."""
    import subprocess

    env = {**__import__("os").environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "make_vectors.py"), "--check"], env=env, capture_output=True
    )
    assert run.returncode == 0, run.stderr.decode()


CODEC = [v for v in MANIFEST if "codec" in v]


def digests(arrays: dict[str, np.ndarray]) -> dict[str, str]:
    return {
        k: hashlib.sha256(np.ascontiguousarray(a, "<f4").tobytes()).hexdigest() for k, a in arrays.items()
    }


def check_decoded(vector: dict, attrs: dict, views: list[dict]) -> None:
    want = vector["codec"]
    assert digests(attrs) == {k: d["sha256"] for k, d in want["attributes"].items()}
    for k, d in want["attributes"].items():
        assert list(attrs[k].shape) == d["shape"]
        assert attrs[k].reshape(attrs[k].shape[0], -1)[0].tolist() == d["first"]
    assert len(views) == len(want["views"])
    for got, exp in zip(views, want["views"]):
        assert (got["width"], got["height"]) == (exp["width"], exp["height"])
        assert ("residual" in got) == ("residual" in exp)
        if "residual" in exp:
            assert list(got["residual"].shape) == exp["residual"]["shape"]
            assert digests({"r": got["residual"]})["r"] == exp["residual"]["sha256"]


def test_codec_vectors_cover_each_chunk_type() -> None:
    ok = [v for v in CODEC if v["codec"]["expect"] == "ok"]
    types = {c["type"] for v in ok for c in v["chunks"]}
    assert types == set(container.KNOWN_TYPES)
    ok = [v for v in ok if "attributes" in v["meta"]]  # one section each: not a tiled file (spec 10.14)
    assert {v["meta"]["attributes"]["sh_degree"] for v in ok} >= {0, 3}
    # Every attribute codec version decodes (spec 10.0), version 4 on each kind of position grid (10.13).
    assert {v["meta"]["attributes"]["version"] for v in ok} == {1, 2, 3, 4, 5}
    grids = {
        tuple(sorted(v["meta"]["attributes"]["position"]))
        for v in ok
        if v["meta"]["attributes"]["version"] == 4
    }
    assert len(grids) >= 2
    assert len([v for v in CODEC if v["codec"]["expect"] == "error"]) >= 20


@pytest.mark.parametrize("vector", CODEC, ids=[v["file"] for v in CODEC])
def test_codec_vector_reference(vector: dict) -> None:
    data = (VECTORS / vector["file"]).read_bytes()
    if vector["codec"].get("residuals") == "refused":  # spec 10.7: decodes unless its residuals are used
        check_decoded(vector, *mv.reference_decode(data, residuals=False))
        with pytest.raises(CodecError, match="residual"):
            mv.reference_decode(data)
        return
    if vector["codec"]["expect"] == "ok":
        check_decoded(vector, *mv.reference_decode(data))
        return
    with pytest.raises(CodecError) as err:
        mv.reference_decode(data)
    for words in vector["codec"]["message_contains"]:
        assert words in str(err.value)


@pytest.mark.parametrize("vector", CODEC, ids=[v["file"] for v in CODEC])
def test_codec_vector_spec_reader(vector: dict) -> None:
    data = (VECTORS / vector["file"]).read_bytes()
    if vector["codec"].get("residuals") == "refused":
        check_decoded(vector, *spec_reader.read_scene(data, residuals=False))
        with pytest.raises(spec_reader.SpecError):
            spec_reader.read_scene(data)
        return
    if vector["codec"]["expect"] == "ok":
        check_decoded(vector, *spec_reader.read_scene(data))
        return
    with pytest.raises(spec_reader.SpecError):
        spec_reader.read_scene(data)
    # A file refused for its attributes or views is refused by a decoder that does not use the residual
    # images too (spec 10.7 and 10.10: only the images' pixels are left to decoders that decode them).
    with pytest.raises(spec_reader.SpecError):
        spec_reader.read_scene(data, residuals=False)


def spec_hexdump() -> bytes:
    block = re.search(r"```hexdump\n(.*?)```", SPEC.read_text(), re.S).group(1)
    out = b""
    for line in block.strip().splitlines():
        hexpart = line[10:].split("|")[0]
        out += bytes.fromhex(hexpart.replace(" ", ""))
    return out


def test_spec_hexdump_is_the_minimal_file() -> None:
    dump = spec_hexdump()
    assert dump == (VECTORS / "valid_minimal.gspc").read_bytes()
    # The example is a 1.0 file; this writer differs only in the minor version and so in the file CRC.
    ours = pack({}, [])
    assert ours[:10] == dump[:10] and ours[12:44] == dump[12:44] and ours[10:12] == b"\x04\x00"
    assert len(dump) == 48


def test_minimal_file_parses_by_hand_from_the_spec() -> None:
    """Follow spec sections 2 and 12 with struct, zlib and msgpack only."""
    d = spec_hexdump()
    magic, major, minor, h, hcrc = struct.unpack_from("<8sHHII", d, 0)
    assert magic == bytes.fromhex("8947535043 0d0a1a".replace(" ", ""))
    assert (major, minor, h) == (1, 0, 15)
    assert hcrc == zlib.crc32(d[20 : 20 + h]) == 0x646BF91C
    assert msgpack.unpackb(d[20 : 20 + h]) == {"chunks": [], "meta": {}}
    t = (20 + h + 7) // 8 * 8
    assert d[20 + h : t] == bytes(t - 20 - h)
    assert d[t : t + 4] == b"GEND"
    assert struct.unpack_from("<I", d, t + 4)[0] == zlib.crc32(d[: t + 4]) == 0x6BA4C6E1
    assert len(d) == t + 8
    text = SPEC.read_text()
    assert "0x646bf91c" in text and "0x6ba4c6e1" in text and "0xCBF43926" in text
    assert zlib.crc32(b"123456789") == 0xCBF43926


def test_spec_registry_matches_known_types() -> None:
    text = SPEC.read_text()
    registered = set(re.findall(r"^\| `([A-Z0-9]{4})` \|", text, re.M))
    assert registered == set(container.KNOWN_TYPES)
    # Every registered type has its payload specified in a section of its own, and no placeholder remains.
    for t in registered:
        assert re.search(rf"^### 10\.\d+ {t}: ", text, re.M), f"no payload section for {t}"
    assert "to be specified" not in text


# ------------------------------------------------------------------ limits too big to store as vectors


def table_file(n_chunks: int) -> bytes:
    entries = [(mv.entry("RESI", b"", index=i), b"") for i in range(n_chunks)]
    return mv.build({}, entries)


@pytest.mark.slow
def test_chunk_count_limit() -> None:
    assert len(unpack(table_file(container.MAX_CHUNKS)).chunks) == container.MAX_CHUNKS
    with pytest.raises(container.LimitExceeded, match="65536 entries"):
        unpack(table_file(container.MAX_CHUNKS + 1))


def test_header_length_at_limit_is_checked_against_the_file() -> None:
    d = pack({}, [])
    at_limit = d[:12] + struct.pack("<I", container.MAX_HEADER_LENGTH) + d[16:]
    with pytest.raises(container.Truncated):
        unpack(at_limit)
    over = d[:12] + struct.pack("<I", container.MAX_HEADER_LENGTH + 1) + d[16:]
    with pytest.raises(container.LimitExceeded):
        unpack(over)


# ------------------------------------------------------------------ writer and API


def test_roundtrip_and_skipping() -> None:
    header = {"scene": {"count": 3, "bbox": [[0.0, 1.5], [-2.0, 3.0]]}, "blob": b"\x00\xff", "none": None}
    chunks = [
        Chunk("RESI", b"r1", index=1),
        Chunk("POSN", bytes(range(256)) * 3),
        Chunk("OPAC", b"", required=False),
        Chunk("xEXT", b"private", required=False),
    ]
    c = unpack(pack(header, chunks))
    assert c.version == container.VERSION
    assert c.header == header
    assert c.chunks == chunks[:3]
    assert c.skipped == chunks[3:]
    assert c.find("RESI", 1).payload == b"r1" and c.find("RESI", 0) is None
    # A reader that knows xEXT keeps it; one that does not know POSN refuses it.
    assert len(unpack(pack(header, chunks), known_types={"POSN", "RESI", "OPAC", "xEXT"}).chunks) == 4
    with pytest.raises(container.UnknownRequiredChunk, match="POSN#0"):
        unpack(pack(header, chunks), known_types={"RESI"})


def test_layout_is_aligned() -> None:
    data = pack({"a": 1}, [Chunk("RESI", b"x" * n, index=n) for n in range(12)])
    assert len(data) % 8 == 0
    info = container.describe(data)
    assert all(c["offset"] % 8 == 0 for c in info["chunks"])
    assert sum(info["totals"].values()) == info["file_size"] == len(data)


def test_describe(tmp_path: Path) -> None:
    path = tmp_path / "s.gspc"
    container.write(path, {"codec": "x"}, [Chunk("POSN", b"p" * 100), Chunk("RESI", b"r" * 9, index=0)])
    info = container.describe(path)
    assert info["version"] == container.VERSION == (1, 4)
    assert [(c["type"], c["index"], c["size"], c["required"]) for c in info["chunks"]] == [
        ("POSN", 0, 100, True),
        ("RESI", 0, 9, True),
    ]
    assert info["bytes_per_type"] == {"POSN": 104, "RESI": 16}
    assert sum(info["totals"].values()) == info["file_size"]
    assert info["header_size"] > 0 and info["meta_keys"] == ["codec"]
    # describe lists a required chunk this reader does not know instead of refusing the file
    unknown = container.describe((VECTORS / "invalid_unknown_required.gspc").read_bytes())
    assert unknown["chunks"][-1]["type"] == "ZZZZ" and unknown["chunks"][-1]["known"] is False


def test_write_is_atomic(tmp_path: Path) -> None:
    path = tmp_path / "s.gspc"
    container.write(path, {}, [Chunk("POSN", b"1")])
    before = path.read_bytes()
    with pytest.raises(ValueError):
        container.write(path, {"bad": np.float32(1)}, [])  # refused before anything is written
    with pytest.raises(ValueError):
        container.write(path, {}, [Chunk("POSN", b"1"), Chunk("POSN", b"2")])
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["s.gspc"]
    assert container.read(path).chunks == [Chunk("POSN", b"1")]


def test_read_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="cannot read"):
        container.read(tmp_path / "nope.gspc")


def nested(levels: int) -> list:
    out: list = [1]
    for _ in range(levels - 1):
        out = [out]
    return out


@pytest.mark.parametrize(
    "header, chunks, words",
    [
        ({1: "x"}, [], "not a str"),
        ({"a": {"b": np.int64(3)}}, [], "header.meta.a.b"),
        ({"a": 2**64}, [], "64 bits"),
        ({"d": nested(31)}, [], "deeper"),
        ([], [], "dict"),
        ({}, [Chunk("POS", b"")], "4 ASCII"),
        ({}, [Chunk("PO N", b"")], "4 ASCII"),
        ({}, [Chunk("RESI", b"", index=-1)], "index"),
        ({}, [Chunk("RESI", b"", index=2**32)], "index"),
        ({}, [Chunk("POSN", np.zeros(3, np.float32))], "not bytes"),
    ],
)
def test_pack_refuses_what_readers_refuse(header, chunks, words) -> None:
    with pytest.raises(ValueError, match=words):
        pack(header, chunks)


def test_pack_accepts_the_deepest_allowed_header() -> None:
    deep = nested(container.MAX_DEPTH - 2)  # top map (level 1) > meta (2) > 30 lists (3..32)
    assert unpack(pack({"d": deep}, [])).header == {"d": deep}


@pytest.mark.parametrize("name", ["codec_residual_damaged", "codec_residual_damaged_webp"])
def test_a_damaged_residual_decodes_unless_the_decoder_restores(name, tmp_path) -> None:
    """Spec 10.7 (1.4, revised): an image cut short after a valid header is read only by its header when the
    decoder does not restore, and refused, in one line and with no output, when it does."""
    from gspc.pipeline import DecodeOptions, decode

    path = VECTORS / f"{name}.gspc"
    decode(path, tmp_path / "plain.ply", DecodeOptions(restore=False))
    decode(path, tmp_path / "attributes.ply", DecodeOptions(restore=False, refine=False))
    with pytest.raises(CodecError, match="residual"):
        decode(path, tmp_path / "restored.ply", DecodeOptions(iterations=1))
    assert not (tmp_path / "restored.ply").exists()
