"""Mutated .gspc files are accepted or refused with a named FormatError subclass, in bounded memory.

A few hundred cases here; tools/fuzz_container.py runs tens of thousands and writes bench/fuzz.md.
"""

import struct
import tracemalloc
import zlib
from pathlib import Path

import fuzz_container
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gspc.errors import FormatError
from gspc.format import container

ROOT = Path(__file__).resolve().parents[1]
SLACK = 64 * 1024  # bytes a read may allocate whatever the file size (exception, traceback, small objects)


def seeds() -> list[bytes]:
    files = [p.read_bytes() for p in sorted((ROOT / "spec" / "vectors").glob("valid_*.gspc"))]
    files.append(
        container.pack(
            {"cameras": [{"K": [1.0] * 9, "name": "v0"}], "n": 5},
            [container.Chunk("POSN", bytes(300)), container.Chunk("RESI", b"r" * 13, index=4)],
        )
    )
    return files


SEEDS = seeds()


def read_bounded(data: bytes) -> str:
    """Outcome of unpack(data); asserts any error is a named, explained FormatError and memory is bounded."""
    tracemalloc.start()
    try:
        container.unpack(data)
        outcome = "ok"
    except FormatError as e:
        assert type(e) is not FormatError, "errors name what is wrong: a subclass, never the base class"
        assert str(e), f"{type(e).__name__} without a message"
        outcome = type(e).__name__
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert peak <= SLACK + 4 * len(data), f"read of {len(data)} bytes allocated {peak}"
    return outcome


def repair(data: bytes) -> bytes:
    if len(data) >= 28:
        (h,) = struct.unpack_from("<I", data, 12)
        if 20 + h <= len(data):
            data = data[:16] + struct.pack("<I", zlib.crc32(data[20 : 20 + h])) + data[20:]
        data = data[:-4] + struct.pack("<I", zlib.crc32(data[:-4]))
    return data


edit = st.one_of(
    st.tuples(st.just("flip"), st.floats(0, 1, exclude_max=True), st.integers(0, 7)),
    st.tuples(st.just("set"), st.floats(0, 1, exclude_max=True), st.integers(0, 255)),
    st.tuples(st.just("insert"), st.floats(0, 1), st.binary(min_size=1, max_size=16)),
    st.tuples(st.just("delete"), st.floats(0, 1, exclude_max=True), st.integers(1, 16)),
    st.tuples(st.just("truncate"), st.floats(0, 1, exclude_max=True), st.none()),
    st.tuples(
        st.just("u32"),
        st.sampled_from([12, 16, 20, 24, 28, 32, 40]),
        st.sampled_from([0, 1, 8, 0xFF, 0xFFFF, 2**24, 2**24 + 1, 2**31, 2**32 - 1]),
    ),
)


def apply(data: bytes, edits: list) -> bytes:
    b = bytearray(data)
    for kind, where, value in edits:
        i = int(where * len(b)) if isinstance(where, float) else where
        if kind == "flip" and b:
            b[min(i, len(b) - 1)] ^= 1 << value
        elif kind == "set" and b:
            b[min(i, len(b) - 1)] = value
        elif kind == "insert":
            b[i:i] = value
        elif kind == "delete":
            del b[i : i + value]
        elif kind == "truncate":
            del b[i:]
        elif kind == "u32" and i + 4 <= len(b):
            b[i : i + 4] = struct.pack("<I", value)
    return bytes(b)


@settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(SEEDS), st.lists(edit, min_size=1, max_size=4), st.booleans())
@pytest.mark.slow
def test_mutated_files_fail_cleanly(seed: bytes, edits: list, fix_checksums: bool) -> None:
    data = apply(seed, edits)
    if fix_checksums:
        data = repair(data)
    outcome = read_bounded(data)
    if not fix_checksums and data != seed:
        assert outcome != "ok", "every edit of a file is caught (CRC-32 finds any change of up to 32 bits)"


def test_structure_aware_fuzz_from_the_tool() -> None:
    """The tool's mutations, header edits included, on a few hundred cases with a fixed seed."""
    r = fuzz_container.fuzz(300, seed=7)
    assert r["tally"].get("CRASH", 0) == 0, r["crashes"]
    assert r["worst_ratio"] <= 4, "memory beyond 16 KiB grows at most 4 bytes per file byte"
    assert len(r["tally"]) >= 6, "the mutations reach many different checks"


def test_absurd_lengths_allocate_nothing() -> None:
    """Length fields at their largest cost no memory: they are compared with the file size first."""
    base = container.pack({}, [container.Chunk("POSN", b"abc")])
    for offset in (12, 16):
        for value in (2**24, 2**31, 2**32 - 1):
            read_bounded(base[:offset] + struct.pack("<I", value) + base[offset + 4 :])
