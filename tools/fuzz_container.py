"""Mutation fuzzer for the .gspc container reader; writes its tally to bench/fuzz.md.

    python tools/fuzz_container.py --cases 50000 --seed 0

Takes valid files (the valid conformance vectors and files made by container.pack with random headers and
chunks), applies 1-4 random edits (bit flips, byte writes, inserts, deletes, truncations, splices, extreme
integers over length fields, edits of the decoded msgpack header), and with probability 1/2 repairs the
header and file checksums so that the deeper checks are reached. Every result must be accepted or refused
with a FormatError subclass; anything else is a crash. Peak memory (tracemalloc) and time are recorded.
"""

from __future__ import annotations

import argparse
import random
import struct
import time
import tracemalloc
import zlib
from collections import Counter
from pathlib import Path

import msgpack

from gspc.errors import FormatError
from gspc.format import container

ROOT = Path(__file__).resolve().parents[1]

INTERESTING = [
    0,
    1,
    7,
    8,
    0x7F,
    0x80,
    0xFF,
    0x100,
    0x7FFF,
    0xFFFF,
    0x10000,
    2**24,
    2**24 + 1,
    2**31,
    2**32 - 1,
]
SLACK = 16384  # bytes any read may allocate regardless of size (exception, traceback, small objects)
INTERESTING_64 = INTERESTING + [2**48 - 1, 2**48, 2**63, 2**64 - 1]


def crc(b: bytes) -> int:
    return zlib.crc32(b) & 0xFFFFFFFF


def random_file(rng: random.Random) -> bytes:
    """A valid file from container.pack with a random small header and random chunks."""
    header = {
        "scene": {"count": rng.randrange(1 << 20), "sh_degree": rng.randrange(4)},
        "codec": {"id": rng.choice(["a", "bb", "ccc"]), "q": rng.random()},
        "cameras": [
            {"name": f"v{i}", "K": [rng.random() for _ in range(9)]} for i in range(rng.randrange(4))
        ],
    }
    types = ["POSN", "OPAC", "SCAL", "ROTN", "SHDC", "SHRS"]
    chunks = [
        container.Chunk(t, rng.randbytes(rng.randrange(40))) for t in rng.sample(types, rng.randrange(7))
    ]
    chunks += [
        container.Chunk("RESI", rng.randbytes(rng.randrange(30)), index=i) for i in range(rng.randrange(3))
    ]
    if rng.random() < 0.3:
        chunks.append(container.Chunk("xOPT", rng.randbytes(rng.randrange(20)), required=False))
    rng.shuffle(chunks)
    return container.pack(header, chunks)


def corpus(rng: random.Random, n_random: int = 40) -> list[bytes]:
    files = [p.read_bytes() for p in sorted((ROOT / "spec" / "vectors").glob("valid_*.gspc"))]
    big = [
        container.pack({"big": True}, [container.Chunk("POSN", rng.randbytes(50_000 + i))]) for i in range(2)
    ]
    return files + big + [random_file(rng) for _ in range(n_random)]


def repair(data: bytes) -> bytes:
    """Recompute header_crc (when header_length fits) and the file CRC, as a careless writer would."""
    if len(data) >= 28:
        (h,) = struct.unpack_from("<I", data, 12)
        if 20 + h <= len(data):
            data = data[:16] + struct.pack("<I", crc(data[20 : 20 + h])) + data[20:]
        data = data[:-4] + struct.pack("<I", crc(data[:-4]))
    return data


def edit_header(rng: random.Random, data: bytes) -> bytes:
    """Decode the msgpack header, change one thing in it, and re-frame it around the same payload bytes."""
    if len(data) < 20:
        return data
    (h,) = struct.unpack_from("<I", data, 12)
    try:
        top = msgpack.unpackb(data[20 : 20 + h], strict_map_key=False)
    except Exception:
        return data
    if not isinstance(top, dict):
        return data
    entries = top.get("chunks")
    choice = rng.randrange(8)
    if isinstance(entries, list) and entries and choice < 6 and isinstance(entries[0], dict):
        e = rng.choice(entries)
        key = rng.choice(["type", "flags", "index", "length", "crc"])
        if choice == 0:
            e[key] = rng.choice(INTERESTING_64 + [-1, True, None, 1.5, "x", b"", [], {}])
        elif choice == 1:
            e.pop(key, None)
        elif choice == 2:
            entries.append(dict(e))
        elif choice == 3:
            entries.remove(e)
        elif choice == 4:
            e["type"] = rng.choice(["ZZZZ", "zzzz", "POS", "POSNN", "RE I", "RESI", "é123"])
        else:
            e["length"] = max(0, e.get("length", 0) if isinstance(e.get("length"), int) else 0) + rng.choice(
                [1, 8, 9]
            )
    elif choice == 6:
        top[rng.choice(["chunks", "meta", "other"])] = rng.choice([None, 0, [], {}, "s", [[[]]]])
    else:
        top.pop(rng.choice(["chunks", "meta"]), None)
    try:
        raw = msgpack.packb(top, use_bin_type=True)
    except Exception:
        return data
    rest = data[20 + h :] if 20 + h <= len(data) else b""
    head = data[:12] + struct.pack("<II", len(raw), crc(raw)) + raw
    old_pad = -(20 + h) % 8
    return head + bytes(-len(head) % 8) + rest[old_pad:]


def mutate(rng: random.Random, data: bytes, pool: list[bytes]) -> bytes:
    b = bytearray(data)
    kind = rng.randrange(10)
    n = len(b)
    if kind == 0 and n:
        i = rng.randrange(n)
        b[i] ^= 1 << rng.randrange(8)
    elif kind == 1 and n:
        b[rng.randrange(n)] = rng.randrange(256)
    elif kind == 2:
        i = rng.randrange(n + 1)
        b[i:i] = rng.randbytes(rng.randrange(1, 17))
    elif kind == 3 and n:
        i = rng.randrange(n)
        del b[i : i + rng.randrange(1, 17)]
    elif kind == 4:
        del b[rng.randrange(n + 1) :]
    elif kind == 5:
        b += rng.randbytes(rng.randrange(1, 17))
    elif kind == 6 and n >= 4:
        i = rng.choice([12, 16, rng.randrange(n - 3)]) if n >= 20 else rng.randrange(n - 3)
        b[i : i + 4] = struct.pack("<I", rng.choice(INTERESTING))
    elif kind == 7:
        other = rng.choice(pool)
        i, j = rng.randrange(n + 1), rng.randrange(len(other) + 1)
        b = b[:i] + other[j:]
    elif kind == 8 and n:
        i = rng.randrange(n)
        b[i:i] = b[i : i + rng.randrange(1, 33)]
    else:
        return edit_header(rng, bytes(b))
    return bytes(b)


def run_case(data: bytes) -> tuple[str, int, float, str]:
    """(outcome, peak bytes allocated by the read, seconds, message); outcome: ok, error class or CRASH."""
    tracemalloc.reset_peak()
    before = tracemalloc.get_traced_memory()[0]
    t0 = time.perf_counter()
    try:
        container.unpack(data)
        outcome, msg = "ok", ""
    except FormatError as e:
        outcome, msg = type(e).__name__, str(e)
        if type(e) is FormatError or not msg:
            outcome = "CRASH"
    except Exception as e:  # the whole point: anything else is a bug
        outcome, msg = "CRASH", f"{type(e).__name__}: {e}"
    dt = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1] - before
    return outcome, peak, dt, msg


def adversarial(count: int = 100_000) -> list[tuple[str, int, int]]:
    """(description, file size, peak bytes) for headers built to maximise Python objects per byte."""
    out = []
    for desc, item in [("empty maps", {}), ("empty arrays", []), ("small ints", 0), ("1-char strings", "a")]:
        data = container.pack({"a": [item] * count}, [])
        tracemalloc.start()
        container.unpack(data)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        out.append((f"{count} {desc}", len(data), peak))
    return out


def fuzz(cases: int, seed: int) -> dict:
    rng = random.Random(seed)
    pool = corpus(rng)
    tally: Counter[str] = Counter()
    crashes: list[str] = []
    worst_ratio, worst_peak, worst_time, max_size = 0.0, 0, 0.0, 0
    tracemalloc.start()
    for _ in range(cases):
        data = rng.choice(pool)
        for _ in range(rng.randrange(1, 5)):
            data = mutate(rng, data, pool)
        if rng.random() < 0.5:
            data = repair(data)
        outcome, peak, dt, msg = run_case(data)
        tally[outcome] += 1
        if outcome == "CRASH" and len(crashes) < 10:
            crashes.append(f"{msg} (file {data[:64].hex()}...)")
        worst_peak = max(worst_peak, peak)
        worst_ratio = max(worst_ratio, max(0, peak - SLACK) / max(len(data), 1))
        worst_time = max(worst_time, dt)
        max_size = max(max_size, len(data))
    tracemalloc.stop()
    return {
        "cases": cases,
        "seed": seed,
        "corpus": len(pool),
        "tally": tally,
        "crashes": crashes,
        "worst_peak": worst_peak,
        "worst_ratio": worst_ratio,
        "worst_time": worst_time,
        "max_size": max_size,
    }


def report(r: dict, command: str, seconds: float) -> str:
    lines = [
        "# Container fuzzing",
        "",
        f"Command: `{command}` ({seconds:.1f} s on one core).",
        "",
        f"{r['cases']} mutated files from a corpus of {r['corpus']} valid ones (the valid vectors and random "
        "files from `container.pack`); 1-4 edits each, checksums repaired for about half. Every file must be "
        "accepted or refused with a `FormatError` subclass and a message; anything else counts as a crash.",
        "",
        "| outcome | cases |",
        "|---|---:|",
    ]
    lines += [f"| {k} | {v} |" for k, v in sorted(r["tally"].items(), key=lambda kv: -kv[1])]
    lines += [
        "",
        "| bound | worst case |",
        "|---|---:|",
        f"| crashes (other exceptions, bare FormatError, empty message) | {r['tally'].get('CRASH', 0)} |",
        f"| peak memory allocated while reading one file (tracemalloc) | {r['worst_peak']} bytes |",
        f"| k in: peak memory <= 16 KiB + k * file size | {r['worst_ratio']:.2f} |",
        f"| time to read one file | {r['worst_time'] * 1e3:.2f} ms |",
        f"| largest file | {r['max_size']} bytes |",
    ]
    lines += [
        "",
        "Worst cases for memory, made on purpose: headers of many tiny msgpack values, each of which",
        "becomes a Python object far larger than its one or two bytes. Memory stays proportional to the",
        "file size.",
        "",
        "| header holds | file bytes | peak bytes | peak / file size |",
        "|---|---:|---:|---:|",
    ]
    lines += [f"| {d} | {n} | {p} | {p / n:.1f} |" for d, n, p in adversarial()]
    if r["crashes"]:
        lines += ["", "Crashes:", ""] + [f"- {c}" for c in r["crashes"]]
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=50000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "fuzz.md")
    args = ap.parse_args()
    t0 = time.perf_counter()
    r = fuzz(args.cases, args.seed)
    text = report(
        r, f"python tools/fuzz_container.py --cases {args.cases} --seed {args.seed}", time.perf_counter() - t0
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(text)
    return 1 if r["tally"].get("CRASH") else 0


if __name__ == "__main__":
    raise SystemExit(main())
