"""A gspc 1.9 reader written from spec/gspc-format.md alone, as an outside implementer would write one.

It imports numpy, msgpack, zstandard and imagecodecs only, never gspc: the range decoder, the probability
tables, the matrix coder and every payload layout follow the spec's words (section numbers in comments), in
plain Python integers and floats. Tests decode real files with it and with gspc's reference decoder and
require the same bits; where the two disagree, the spec or the reference is wrong.

Slow (one Python call per symbol): meant for the small files of spec/vectors/ and the tests.
"""

from __future__ import annotations

import bisect
import io
import math
import struct
import zlib

import imagecodecs
import msgpack
import numpy as np
import zstandard

MAGIC = b"\x89GSPC\r\n\x1a"
MASK64 = (1 << 64) - 1
PRECISION = 24
INT_LIMIT = 1 << 48  # 10.0: matrix entries and model integers lie in -2^48 .. 2^48
MAX_SYMBOLS = 1 << 22
MAX_GAUSSIANS = 1 << 26
GAUSSIAN_FLOOR = 1 << 16  # 10.10: N <= max(2^16, floor(8 P / 12))
MIN_CODED_BITS = 12
MAX_MODELS_BYTES = 1 << 26  # 10.10: models content <= min(2^26, max(2^16, 32 x frame bytes))
MODELS_FLOOR, MODELS_RATIO = 1 << 16, 32
TABLE_FLOOR, TABLE_PER_BYTE = 1 << 22, 16  # 10.10: table entries <= max(2^22, 16 x ECM bytes)
FILE_TABLE_FLOOR, FILE_MODEL_FLOOR = 1 << 25, 1 << 23  # 10.14: the floors a tiled file's tiles share
MAX_TILES = 8192  # 10.14
MAX_VIEW_PIXELS = 1 << 24
MAX_TOTAL_PIXELS = 1 << 28
PIXEL_FLOOR, PIXELS_PER_BYTE = 1 << 22, 1024  # 10.8: all views <= min(2^28, max(2^22, 1024 x file bytes))
MAX_REFINE = 100_000
MAX_STEP = 2.0**64  # 10.0: quantiser steps
SQRT_HALF = 0.7071067811865476
LN2 = 0.6931471805599453
BOOSTS = [1, 2, 3, 4, 6, 8, 11, 16, 23, 32, 45, 64, 91, 128, 181, 256, 362, 512, 724, 1024, 1448, 2048]


class SpecError(Exception):
    """The file breaks a MUST of the spec (what the reference calls FormatError or CodecError)."""


def need(cond: bool, why: str) -> None:
    if not cond:
        raise SpecError(why)


def is_int(x: object) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


# --------------------------------------------------------------------------------- container (2, 4, 5, 8)


def read_container(data: bytes) -> tuple[tuple[int, int], dict, list[tuple[str, int, bytes]]]:
    """(version, meta, [(type, index, payload)]) for a valid file; assumes sections 4-5 hold (the container
    vectors test those rules) and checks the framing, checksums and padding."""
    need(data[:8] == MAGIC, "magic")
    major, minor, h, hcrc = struct.unpack_from("<HHII", data, 8)
    need(major == 1, "major version")
    header = data[20 : 20 + h]
    need(len(header) == h and zlib.crc32(header) == hcrc, "header checksum")
    top = msgpack.unpackb(header, raw=False)
    pos = (20 + h + 7) // 8 * 8
    need(data[20 + h : pos] == bytes(pos - 20 - h), "header padding")
    chunks = []
    for e in top["chunks"]:
        p = data[pos : pos + e["length"]]
        need(len(p) == e["length"] and zlib.crc32(p) == e["crc"], "chunk checksum")
        end = (pos + e["length"] + 7) // 8 * 8
        need(data[pos + e["length"] : end] == bytes(end - pos - e["length"]), "chunk padding")
        chunks.append((e["type"], e["index"], p))
        pos = end
    need(data[pos : pos + 4] == b"GEND" and len(data) == pos + 8, "trailer")
    need(struct.unpack_from("<I", data, pos + 4)[0] == zlib.crc32(data[: pos + 4]), "file checksum")
    return (major, minor), top["meta"], chunks


# --------------------------------------------------------------------------------- range decoder (10.0)


class RangeDecoder:
    """State: lower, range (64-bit), point (64-bit), the words not read yet."""

    def __init__(self, words: list[int]) -> None:
        self.words = words
        self.next = 0
        self.lower = 0
        self.range = MASK64
        self.point = (self.read() << 32) | self.read()

    def read(self) -> int:
        # Words past the end read as zero; words never read are ignored.
        if self.next >= len(self.words):
            return 0
        self.next += 1
        return self.words[self.next - 1]

    def decode(self, cdf: list[int]) -> int:
        """Index i of the symbol with cdf[i] <= quantile < cdf[i + 1]; cdf[0] = 0, cdf[-1] = 2^24."""
        scale = self.range >> PRECISION
        quantile = ((self.point - self.lower) & MASK64) // scale
        need(quantile < 1 << PRECISION, "range coder quantile outside the table (invalid stream)")
        i = bisect.bisect_right(cdf, quantile) - 1
        self.lower = (self.lower + scale * cdf[i]) & MASK64
        self.range = scale * (cdf[i + 1] - cdf[i])
        if self.range < 1 << 32:
            self.lower = (self.lower << 32) & MASK64
            self.range <<= 32
            self.point = ((self.point << 32) & MASK64) | self.read()
        return i


# --------------------------------------------------------------------------------- model tables (10.0)


def theta_numerators() -> list[int]:
    m = [1 << 20]
    while m[-1] > 8:
        m.append((m[-1] * 60097) >> 16)
    return m


THETA_M = theta_numerators()


def check_spec(spec: object) -> list[int]:
    need(isinstance(spec, list) and len(spec) >= 1 and all(is_int(v) for v in spec), "model spec")
    need(all(-INT_LIMIT <= v <= INT_LIMIT for v in spec), "model spec integer out of range")
    kind = spec[0]
    need(kind in (0, 1, 2, 3), "model kind")
    if kind == 0:
        need(len(spec) == 1, "kind 0 length")
    elif kind == 1:
        need(len(spec) == 2, "kind 1 length")
    else:
        need(len(spec) >= 3, "model window")
        lo, hi = spec[1], spec[2]
        need(2 <= hi - lo + 1 <= MAX_SYMBOLS, "model window size")
        if kind == 2:
            need(len(spec) == 6, "kind 2 length")
            c, u, b = spec[3:]
            need(lo <= c <= hi, "kind 2 centre outside the window")
            need(0 <= u < len(THETA_M) and 0 <= b < len(BOOSTS), "kind 2 ratio or boost index")
        else:
            need(len(spec) == 3 + hi - lo + 1, "kind 3 weight count")
            need(all(0 <= w < 1 << 39 for w in spec[3:]) and sum(spec[3:]) > 0, "kind 3 weights")
    return spec


def weights(spec: list[int]) -> list[int]:
    kind, lo, hi = spec[0], spec[1], spec[2]
    if kind == 3:
        return spec[3:]
    c, u, b = spec[3], spec[4], spec[5]
    theta = 1.0 - THETA_M[u] / float(1 << 20)
    p = [1.0]
    for _ in range(max(c - lo, hi - c)):
        p.append(p[-1] * theta)
    w = [max(math.floor(p[abs(x - c)] * float(1 << 30)), 1) for x in range(lo, hi + 1)]
    w[c - lo] = max((w[c - lo] * BOOSTS[b]) >> 3, 1)
    return w


def cdf_of(spec: list[int]) -> list[int]:
    w = weights(spec)
    s, total = len(w), sum(w)
    f = [1 + wx * ((1 << PRECISION) - s) // total for wx in w]
    f[w.index(max(w))] += (1 << PRECISION) - sum(f)
    cdf = [0]
    for x in f:
        cdf.append(cdf[-1] + x)
    return cdf


# --------------------------------------------------------------------------------- ECM (10.0)


def bitlen(x: int) -> int:
    return x.bit_length()


def levels(m: int) -> list[list[tuple[int, int, int]]]:
    """Rows of each level as (row, a, b); level 0 has no neighbours (a = b = -1)."""
    out = [[(r, -1, -1) for r in range(0, m, 64)]]
    h = 32
    while h >= 1:
        out.append([(r, r - h, r + h if r + h < m else r - h) for r in range(h, m, 2 * h)])
        h //= 2
    return out


class Budget:
    """10.14: what one tile of a tiled file may still spend: table entries and decompressed model bytes."""

    def __init__(self, tile_bytes: int, file_bytes: int) -> None:
        self.entries = max(FILE_TABLE_FLOOR * tile_bytes // max(file_bytes, 1), TABLE_PER_BYTE * tile_bytes)
        self.model_bytes = max(FILE_MODEL_FLOOR * tile_bytes // max(file_bytes, 1), MODELS_RATIO * tile_bytes)


def read_ecm(
    payload: bytes, m_expected: int | None, c_expected: int | None, budget: Budget | None = None
) -> tuple:
    """10.0: (m, c, models, words, table entries) of an ECM, every rule checked that needs no symbol decoded
    (an empty ECM: no models); ``None`` leaves a dimension unchecked. ``budget`` (a tile's, 10.14) is spent by
    this ECM's models."""
    try:
        ecm = msgpack.unpackb(payload, raw=False)
    except Exception as e:
        raise SpecError(f"ECM is not one msgpack value ({type(e).__name__})") from None
    need(isinstance(ecm, list) and len(ecm) == 4, "ECM array")
    m, c, models, words = ecm
    need(is_int(m) and is_int(c) and isinstance(models, bytes) and isinstance(words, bytes), "ECM types")
    need(m_expected in (None, m) and c_expected in (None, c), f"ECM shape {m}x{c}")
    need(m >= 0 and c >= 0, "ECM shape")
    if m == 0:
        need(models == b"" and words == b"", "an empty ECM has empty models and words")
        return m, c, [], words, 0
    need(len(words) % 4 == 0, "words length")
    limit = min(MAX_MODELS_BYTES, max(MODELS_FLOOR, MODELS_RATIO * len(models)))
    try:
        need(zstandard.frame_content_size(models) <= limit, "models declare more bytes than allowed")
        # At most limit + 1 bytes are ever inflated, with or without a declared size.
        reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(models), read_across_frames=False)
        need(len(reader.read(limit + 1)) <= limit, "models inflate past the limit")
        d = zstandard.ZstdDecompressor().decompressobj()
        raw = d.decompress(models)
    except zstandard.ZstdError:
        raise SpecError("models are not a zstd frame") from None
    need(d.eof and not d.unused_data, "models must be exactly one complete zstd frame")
    if budget is not None:
        need(len(raw) <= budget.model_bytes, "the tile's models decompress past its budget (10.14)")
        budget.model_bytes -= len(raw)
    try:
        header = msgpack.unpackb(raw, raw=False)
    except Exception as e:
        raise SpecError(f"models are not one msgpack value ({type(e).__name__})") from None
    need(isinstance(header, list) and len(header) == c, "models array length")
    # 10.10: every column's specs checked, and their tables counted, before any table is built.
    entries = 0
    for j in range(c):
        need(isinstance(header[j], list) and len(header[j]) == 2, "column entry")
        mode, specs = header[j]
        need(is_int(mode) and 0 <= mode <= (3 if j else 1), "column mode")
        need(isinstance(specs, list) and len(specs) == 15, "15 model specs")
        entries += sum(s[2] - s[1] + 1 for s in map(check_spec, specs) if s[0] >= 2)
    need(entries <= max(TABLE_FLOOR, TABLE_PER_BYTE * len(payload)), "model tables too large for the ECM")
    if budget is not None:
        need(entries <= budget.entries, "the tile's model tables pass its budget (10.14)")
        budget.entries -= entries
    return m, c, header, words, entries


def decode_ecm(
    payload: bytes, m_expected: int, c_expected: int, budget: Budget | None = None
) -> list[list[int]]:
    """The matrix as a list of columns."""
    m, c, header, words, _ = read_ecm(payload, m_expected, c_expected, budget)
    if m == 0:
        return [[] for _ in range(c)]
    rc = RangeDecoder(list(struct.unpack(f"<{len(words) // 4}I", words)))
    lv = levels(m)
    cols: list[list[int]] = []
    prev_q, prev_nb, prev_e = [0] * m, [0] * m, [0] * m
    for j in range(c):
        mode, specs = header[j]
        cdfs: dict[int, list[int]] = {}
        q, nbs, es = [0] * m, [0] * m, [0] * m
        for k, level in enumerate(lv):
            ctx = []
            for r, a, b in level:
                if k == 0:
                    nb, s = 0, 4
                else:
                    nb, s = (q[a] + q[b]) >> 1, min(bitlen(abs(q[a] - q[b])), 3)
                t = min(bitlen(abs(prev_e[r])), 2)
                ctx.append((3 * s + t, r, nb))
            for bucket in range(15):
                for bk, r, nb in ctx:
                    if bk != bucket:
                        continue
                    spec = specs[bucket]
                    need(spec[0] != 0, "symbol from an empty model")
                    if spec[0] == 1:
                        e = spec[1]
                    else:
                        if bucket not in cdfs:
                            cdfs[bucket] = cdf_of(spec)
                        e = spec[1] + rc.decode(cdfs[bucket])
                    pred = [0, nb, prev_q[r], nb + prev_q[r] - prev_nb[r]][mode]
                    q[r], nbs[r], es[r] = e + pred, nb, e
                    need(abs(q[r]) <= INT_LIMIT, "decoded value out of range")
        cols.append(q)
        prev_q, prev_nb, prev_e = q, nbs, es
    return cols


# --------------------------------------------------------------------------------- attributes (10.1-10.6)


def det_log(x: float) -> float:
    m, e = math.frexp(x)
    if m < SQRT_HALF:
        m, e = 2.0 * m, e - 1
    t = (m - 1.0) / (m + 1.0)
    t2 = t * t
    s = 0.0
    for k in range(27, 0, -2):
        s = s * t2 + 1.0 / k
    return 2.0 * t * s + e * LN2


def unpack_bin_pair(payload: bytes, what: str) -> tuple[bytes, bytes]:
    try:
        pair = msgpack.unpackb(payload, raw=False)
    except Exception:
        raise SpecError(f"{what} is not one msgpack value") from None
    need(isinstance(pair, list) and len(pair) == 2 and all(isinstance(x, bytes) for x in pair), what)
    return pair[0], pair[1]


def curve_voxels(classes: bytes, raw: bytes, n: int, bits: int, budget: Budget | None) -> list[list[int]]:
    """10.1: the voxels (x, y, z) of one curve of ``n`` codes of ``bits`` bits per axis."""
    lengths = decode_ecm(classes, n, 1, budget)[0]
    need(all(0 <= x <= 3 * bits for x in lengths), "position class")
    total = sum(max(x - 1, 0) for x in lengths)
    need(len(raw) == (total + 7) // 8, "raw bits length")
    bitstr = int.from_bytes(raw, "big") if raw else 0
    pad = 8 * len(raw) - total
    need(bitstr & ((1 << pad) - 1) == 0, "raw padding bits")
    bitstr >>= pad
    used, code, out = 0, 0, []
    for x in lengths:
        if x:
            low = (bitstr >> (total - used - (x - 1))) & ((1 << (x - 1)) - 1)
            used += x - 1
            code += (1 << (x - 1)) + low
        need(code < 1 << (3 * bits), "Morton code past 3 x bits")
        out.append([sum(((code >> (3 * b + ax)) & 1) << b for b in range(bits)) for ax in range(3)])
    return out


def finite_float(x: object) -> bool:
    return isinstance(x, float) and math.isfinite(x)


def decode_attributes(
    meta: dict, chunks: dict[str, bytes], budget: Budget | None = None
) -> dict[str, np.ndarray]:
    """float32 arrays: means (n,3), quats (n,4), log_scales (n,3), opacities (n,), sh_dc (n,3), sh_rest
    (n,K,3). ``budget``: a tile's (10.14)."""
    try:
        return _decode_attributes(meta, chunks, budget)
    except (KeyError, TypeError, ValueError, AttributeError) as e:  # 10.0: a missing key or another type
        raise SpecError(f"attribute codec parameters malformed ({type(e).__name__})") from None


QUANTISER_KEYS = ("opacity_levels", "scale_step", "rotation_levels", "dc_step", "sh_steps")
MAX_CLASS_MAPS = 15  # 10.0: classes holds 0 to 15 maps (10.10: at most 16 precision classes)


def class_steps(q: dict, k: int) -> dict:
    """10.0: the five quantiser keys of the section (class 0) or of one ``classes`` map, checked."""
    need(isinstance(q, dict) and all(key in q for key in QUANTISER_KEYS), "class map lacks a quantiser key")
    L, M = q["opacity_levels"], q["rotation_levels"]
    need(is_int(L) and 1 <= L <= INT_LIMIT and is_int(M) and 1 <= M <= INT_LIMIT, "levels")
    sh = q["sh_steps"]
    need(isinstance(sh, list) and len(sh) == k, "sh_steps length")
    steps = [q["scale_step"], q["dc_step"], *sh]
    # 10.0: every step finite, > 0 and at most 2^64 (then 2^48 x step is a finite binary32)
    need(all(finite_float(s) and 0 < s <= MAX_STEP for s in steps), "steps")
    return {key: q[key] for key in QUANTISER_KEYS}


def unpack_bins(payload: bytes, count: int, what: str, budget: Budget | None = None) -> list[bytes]:
    """10.13: a msgpack array of exactly ``count`` bins."""
    try:
        parts = msgpack.unpackb(payload, raw=False)
    except Exception:
        raise SpecError(f"{what} is not one msgpack value") from None
    need(isinstance(parts, list) and len(parts) == count, f"{what}: {count} bins")
    need(all(isinstance(x, bytes) for x in parts), f"{what}: bins")
    # 10.0: the ECMs of the chunk share one table bound, checked before any of their tables is built.
    entries = sum(read_ecm(x, None, None, budget)[4] for x in parts)  # each ECM spends once, here
    need(entries <= max(TABLE_FLOOR, TABLE_PER_BYTE * len(payload)), f"{what}: model tables past the chunk's")
    return parts


def _decode_attributes(meta: dict, chunks: dict[str, bytes], budget: Budget | None) -> dict[str, np.ndarray]:
    a = meta["attributes"]
    version = a["version"]
    need(is_int(version) and version in (1, 2, 3, 4, 5), "codec version")
    n, deg = a["n"], a["sh_degree"]
    need(is_int(n) and 1 <= n <= MAX_GAUSSIANS, "Gaussian count")
    need(is_int(deg) and 0 <= deg <= 3, "SH degree")
    k = (deg + 1) ** 2 - 1
    payload = sum(len(p) for p in chunks.values())  # the attribute chunks' payloads, 10.10
    need(n <= max(GAUSSIAN_FLOOR, 8 * payload // MIN_CODED_BITS), "Gaussian count vs payload")
    grid = a["position"]
    need(isinstance(grid, dict), "position map")
    # 10.0: at versions 4 and 5 the position keys say which grid it is, and that version's rules apply.
    gv = version
    if version >= 4:
        has_far = "far_count" in grid or "far_shift" in grid
        gv = 3 if has_far else 2 if "centre" in grid or "radius" in grid else 1
    bits, lo, step = grid["bits"], grid["lo"], grid["step"]
    need(is_int(bits) and 1 <= bits <= (17 if gv == 1 else 21), "position bits")
    contracted = gv >= 2
    need(contracted == ("radius" in grid) and contracted == ("centre" in grid), "contraction keys")
    need((gv == 3) == ("far_count" in grid) == ("far_shift" in grid), "far set keys")
    far, shift = (grid["far_count"], grid["far_shift"]) if gv == 3 else (0, 0)
    need(is_int(far) and is_int(shift), "far set integers")
    if gv == 3:
        need(1 <= far <= n - 1 and 1 <= shift <= bits - 1, "far set range")
    if contracted:
        centre, radius = grid["centre"], grid["radius"]
        need(len(centre) == 3 and all(map(finite_float, [*centre, radius])) and radius > 0, "centre, radius")
    need(len(lo) == 3 and len(step) == 3 and all(map(finite_float, lo + step)), "grid floats")
    need(all(s > 0 for s in step), "grid step")
    # 10.1 bounds: the grid's far corner T = lo + (2^bits - 1) step, and the region of interest.
    bound = 32.0 if contracted else 2.0**64
    corner = [lo[ax] + float(2**bits - 1) * step[ax] for ax in range(3)]
    need(all(abs(x) <= bound for x in lo + corner), "position grid bounds")
    if contracted:
        need(all(abs(c) <= 2.0**64 for c in centre) and radius <= 2.0**64, "centre, radius bounds")
    # 10.1 resolution: each axis's grid spans at least 2^-24 of its corners (and, contracted, of its centre)
    for ax in range(3):
        span = float(2**bits - 1) * step[ax]
        need(span >= 2.0**-24 * max(abs(lo[ax]), abs(corner[ax])), "position grid under binary32's grain")
        if contracted:
            need(radius * span >= 2.0**-24 * abs(centre[ax]), "position grid under binary32's grain")
    # 10.0, 10.13: class 0 is the section's own quantisers; at version 4 each classes map is one more.
    classes = [class_steps(a, k)]
    if version >= 4:
        maps = a["classes"]
        need(isinstance(maps, list) and len(maps) <= MAX_CLASS_MAPS, "classes: an array of at most 15 maps")
        classes += [class_steps(m, k) for m in maps]
    wanted = {"POSN", "OPAC", "SCAL", "ROTN", "SHDC"} | ({"SHRS"} if deg else set())
    need(set(chunks) == wanted | ({"PREC"} if version >= 4 else set()), "chunks")
    entries = 0
    if version == 5:  # 10.16: the SH rest by codebook, never at SH degree 0
        entries = a["codebook"]
        need(deg > 0, "a codebook at SH degree 0")
        need(is_int(entries) and 1 <= entries <= min(2**16, n), "codebook entries")

    # 10.1 positions: one curve, or the near curve and the far set's (version 3)
    try:
        parts = msgpack.unpackb(chunks["POSN"], raw=False)
    except Exception:
        raise SpecError("POSN is not one msgpack value") from None
    need(isinstance(parts, list) and len(parts) == (4 if gv == 3 else 2), "POSN array length")
    need(all(isinstance(x, bytes) for x in parts), "POSN bins")
    voxels = curve_voxels(parts[0], parts[1], n - far, bits, budget)
    if gv == 3:
        far_voxels = curve_voxels(parts[2], parts[3], far, bits - shift, budget)
        voxels += [[w << shift for w in v] for v in far_voxels]
    means = np.zeros((n, 3), np.float32)
    for i, v in enumerate(voxels):
        y = [lo[ax] + v[ax] * step[ax] for ax in range(3)]
        if not contracted:
            means[i] = np.array(y, np.float32)
            continue
        # 10.1 contracted grid, in the spec's operation order (binary64, then one cast to binary32).
        rho = math.sqrt((y[0] * y[0] + y[1] * y[1]) + y[2] * y[2])
        if rho > 1:
            e = math.floor(rho - 1)
            r = math.ldexp(1 + ((rho - 1) - e), e)
            sc = r / rho
            y = [c * sc for c in y]
        means[i] = np.array([centre[ax] + radius * y[ax] for ax in range(3)], np.float32)

    out = {
        "means": means,
        "quats": np.zeros((n, 4), np.float32),
        "log_scales": np.zeros((n, 3), np.float32),
        "opacities": np.zeros(n, np.float32),
        "sh_dc": np.zeros((n, 3), np.float32),
        "sh_rest": np.zeros((n, k, 3), np.float32),
    }
    if version < 4:
        matrices = {t: chunks[t] for t in ("OPAC", "SCAL", "ROTN", "SHDC")}
        decode_values(out, classes[0], list(range(n)), matrices, budget)
        if deg:  # 10.6 SH rest: flags, then the flagged Gaussians' K coefficients
            fl, vals = unpack_bin_pair(chunks["SHRS"], "SHRS")
            flags = decode_ecm(fl, n, 1, budget)[0]
            need(all(f in (0, 1) for f in flags), "SH rest flag")
            rows = [i for i, f in enumerate(flags) if f]
            decode_band(out["sh_rest"], classes[0], rows, decode_ecm(vals, len(rows), 3 * k, budget), 0, k)
        return out

    # 10.13: each Gaussian's class and SH degree, then each class's rows from bins of their own.
    c = len(classes)
    prec = decode_ecm(chunks["PREC"], n, 1 if deg == 0 else 2, budget)
    cls = prec[0]
    degrees = prec[1] if deg else [0] * n
    need(all(0 <= x < c for x in cls), "PREC class outside 0 .. C - 1")
    need(all(0 <= d <= deg for d in degrees), "PREC SH degree outside 0 .. sh_degree")
    bins = {t: unpack_bins(chunks[t], c, t, budget) for t in ("OPAC", "SCAL", "ROTN", "SHDC")}
    bands = 0 if version == 5 else deg
    rest_bins = unpack_bins(chunks["SHRS"], c * bands, "SHRS", budget) if bands else []
    for kk in range(c):
        rows = [i for i in range(n) if cls[i] == kk]
        decode_values(out, classes[kk], rows, {t: b[kk] for t, b in bins.items()})
        for b in range(1, bands + 1):
            band_rows = [i for i in rows if degrees[i] >= b]
            cols = decode_ecm(rest_bins[kk * deg + b - 1], len(band_rows), 3 * (2 * b + 1))
            decode_band(out["sh_rest"], classes[kk], band_rows, cols, b * b - 1, 2 * b + 1)
    if version == 5:
        # 10.16: entries at class 0's steps, then each Gaussian of degree >= 1 its entry up to its degree.
        table_bin, index_bin = unpack_bins(chunks["SHRS"], 2, "SHRS", budget)
        table = decode_ecm(table_bin, entries, 3 * k)
        coded = [i for i in range(n) if degrees[i] >= 1]
        index = decode_ecm(index_bin, len(coded), 1)[0]
        need(all(0 <= e < entries for e in index), "codebook index outside 0 .. E - 1")
        for i, e in zip(coded, index):
            cols = [[col[e]] for col in table[: 3 * ((degrees[i] + 1) ** 2 - 1)]]
            decode_band(out["sh_rest"], classes[0], [i], cols, 0, (degrees[i] + 1) ** 2 - 1)
    return out


def decode_values(
    out: dict, q: dict, rows: list[int], matrices: dict[str, bytes], budget: Budget | None = None
) -> None:
    """10.2 to 10.5 for the Gaussians ``rows`` (in decoded order), each matrix of len(rows) rows, with the
    quantisers ``q`` of their class; ``budget``: spent by matrices not already counted as bins (10.14)."""
    m = len(rows)
    L, M = q["opacity_levels"], q["rotation_levels"]
    # 10.2 opacity
    for i, v in zip(rows, decode_ecm(matrices["OPAC"], m, 1, budget)[0]):
        x = min(max(v / float(L), 0.25 / L), 1.0 - 0.25 / L)
        out["opacities"][i] = np.float32(det_log(x) - det_log(1.0 - x))
    # 10.3, 10.5
    for name, chunk, s in (("log_scales", "SCAL", q["scale_step"]), ("sh_dc", "SHDC", q["dc_step"])):
        cols = decode_ecm(matrices[chunk], m, 3, budget)
        for r, i in enumerate(rows):
            out[name][i] = [np.float32(cols[ch][r] * s) for ch in range(3)]
    # 10.4 rotations
    rot = decode_ecm(matrices["ROTN"], m, 4, budget)
    rstep = 2.0 * SQRT_HALF / M
    for r_i, i in enumerate(rows):
        j = rot[0][r_i]
        need(0 <= j <= 3 and all(0 <= rot[c][r_i] <= M for c in (1, 2, 3)), "rotation symbol")
        r = [rot[c][r_i] * rstep - SQRT_HALF for c in (1, 2, 3)]
        largest = math.sqrt(max(1.0 - ((r[0] * r[0] + r[1] * r[1]) + r[2] * r[2]), 0.0))
        others = [x for x in range(4) if x != j]
        out["quats"][i, j] = np.float32(largest)
        for x, v in zip(others, r):
            out["quats"][i, x] = np.float32(v)


def decode_band(
    rest: np.ndarray, q: dict, rows: list[int], cols: list[list[int]], first: int, count: int
) -> None:
    """10.6, 10.13: coefficients first .. first + count - 1 of the Gaussians ``rows``; column 3 j + ch is
    coefficient first + j, colour channel ch, decoded float32(q * sh_steps[first + j])."""
    steps = q["sh_steps"]
    for r_i, i in enumerate(rows):
        for j in range(count):
            for ch in range(3):
                rest[i, first + j, ch] = np.float32(cols[3 * j + ch][r_i] * steps[first + j])


# --------------------------------------------------------------------------------- side information


def parse_side(payload: bytes) -> list[dict]:
    """10.9: one dict per view: width, height, intrinsics, pose (binary32 tuples), and with a residual
    codec, bits, scale, gain, image."""
    p = 0

    def take(fmt: str) -> tuple:
        nonlocal p
        size = struct.calcsize(fmt)
        need(p + size <= len(payload), "SIDE truncated")
        out = struct.unpack_from(fmt, payload, p)
        p += size
        return out

    count, flags, codec, bits, s = take("<IBBBB")
    need(1 <= count <= 1 << 20 and flags in (0, 1) and codec in (0, 1, 2), "SIDE head")
    need(bits in (8, 16) and 1 <= s <= 16, "SIDE head")
    shared = None if flags else take("<II4f")
    views = []
    for _ in range(count):
        w, h, *intr = take("<II4f") if flags else shared
        pose = take("<12f")
        (length,) = take("<I")
        check_camera(w, h, intr, pose)
        view = {"width": w, "height": h, "intrinsics": tuple(intr), "pose": pose, "length": length}
        if length:
            (gain,) = take("<f")
            need(math.isfinite(gain) and gain > 0, "gain")
            view.update(codec=codec, bits=bits, scale=s, gain=gain)
        views.append(view)
    need(sum(v["width"] * v["height"] <= MAX_VIEW_PIXELS for v in views) == len(views), "view pixels")
    need(sum(v["width"] * v["height"] for v in views) <= MAX_TOTAL_PIXELS, "total pixels")
    need(p + sum(v["length"] for v in views) == len(payload), "SIDE length")
    for v in views:
        v["image"] = payload[p : p + v["length"]]
        p += v["length"]
    return views


JXL_CONTAINER = bytes.fromhex("0000000c4a584c200d0a870a")
JXL_RATIOS = {1: (1, 1), 2: (12, 10), 3: (4, 3), 4: (3, 2), 5: (16, 9), 6: (5, 4), 7: (2, 1)}


def boxes(data: bytes, start: int, end: int):
    """10.7: ISOBMFF boxes (type, payload start, payload end) from ``start`` to ``end``; the walk stops at a
    box whose size is below its header or runs past ``end``."""
    pos = start
    while pos + 8 <= end:
        size, kind = struct.unpack_from(">I4s", data, pos)
        head = 8
        if size == 1:
            if pos + 16 > end:
                return
            (size,) = struct.unpack_from(">Q", data, pos + 8)
            head = 16
        if size == 0:
            size = end - pos
        if size < head or pos + size > end:
            return
        yield kind, pos + head, pos + size
        pos += size


def jxl_size(data: bytes) -> tuple[int, int]:
    """10.7: (width, height) from a JPEG XL codestream's SizeHeader, bits read least significant first."""
    code = data
    if data[:12] == JXL_CONTAINER:
        found = [(k, a, b) for k, a, b in boxes(data, 0, len(data)) if k in (b"jxlc", b"jxlp")]
        need(bool(found), "JPEG XL container without a codestream box")
        kind, a, b = found[0]
        code = data[a + (4 if kind == b"jxlp" else 0) : b]
    need(code[:2] == b"\xff\x0a", "JPEG XL signature")
    pos = 16  # bits, after FF 0A

    def bits(n: int) -> int:
        nonlocal pos
        need(pos + n <= 8 * len(code), "JPEG XL codestream ends inside its SizeHeader")
        v = sum(((code[(pos + i) >> 3] >> ((pos + i) & 7)) & 1) << i for i in range(n))
        pos += n
        return v

    def u32() -> int:
        return bits((9, 13, 18, 30)[bits(2)]) + 1

    div8 = bits(1)
    height = (bits(5) + 1) * 8 if div8 else u32()
    ratio = bits(3)
    if ratio:
        num, den = JXL_RATIOS[ratio]
        return height * num // den, height
    return ((bits(5) + 1) * 8 if div8 else u32()), height


def webp_size(data: bytes) -> tuple[int, int]:
    """10.7: (width, height) from a WebP's first chunk: VP8, VP8L or VP8X."""
    need(len(data) >= 30 and data[:4] == b"RIFF" and data[8:12] == b"WEBP", "WebP signature")
    kind = data[12:16]
    if kind == b"VP8 " and data[23:26] == b"\x9d\x01\x2a":
        w, h = struct.unpack_from("<HH", data, 26)
        return w & 0x3FFF, h & 0x3FFF
    if kind == b"VP8L" and data[20] == 0x2F:
        (v,) = struct.unpack_from("<I", data, 21)
        return (v & 0x3FFF) + 1, ((v >> 14) & 0x3FFF) + 1
    need(kind == b"VP8X", "WebP first chunk")
    return int.from_bytes(data[24:27], "little") + 1, int.from_bytes(data[27:30], "little") + 1


def avif_size(data: bytes) -> tuple[int, int]:
    """10.7: the largest width and the largest height of the ispe boxes in meta / iprp / ipco."""
    sizes = []
    for k1, a1, b1 in boxes(data, 0, len(data)):
        for k2, a2, b2 in boxes(data, a1 + 4, b1) if k1 == b"meta" else ():
            for k3, a3, b3 in boxes(data, a2, b2) if k2 == b"iprp" else ():
                for k4, a4, b4 in boxes(data, a3, b3) if k3 == b"ipco" else ():
                    if k4 == b"ispe" and b4 - a4 >= 12:
                        sizes.append(struct.unpack_from(">II", data, a4 + 4))
    need(bool(sizes), "AVIF without an image size (ispe)")
    return max(w for w, _ in sizes), max(h for _, h in sizes)


def check_image_header(view: dict) -> None:
    """10.7: the image's signature and declared size, which every decoder checks."""
    s, H, W = view["scale"], view["height"], view["width"]
    declared = [jxl_size, webp_size, avif_size][view["codec"]](view["image"])
    need(declared == (-(-W // s), -(-H // s)), "residual image declares another size")


def decode_residual(view: dict) -> np.ndarray:
    """10.7: R (H, W, 3) float32 at the camera's full size."""
    decode = [imagecodecs.jpegxl_decode, imagecodecs.webp_decode, imagecodecs.avif_decode][view["codec"]]
    try:
        u = decode(view["image"])
    except Exception as e:  # each image library raises its own error for a stream it cannot read
        raise SpecError(f"residual image does not decode ({type(e).__name__})") from None
    if u.ndim == 2:
        u = np.repeat(u[:, :, None], 3, axis=2)
    s, H, W = view["scale"], view["height"], view["width"]
    h, w = -(-H // s), -(-W // s)
    need(u.shape[:2] == (h, w) and u.shape[2] >= 3, "residual image size")
    offset = np.float32(1 << (view["bits"] - 1))
    r = (u[:, :, :3].astype(np.float32) - offset) / np.float32(view["gain"])
    if s == 1:
        return r

    def axis(n_out: int, n_in: int) -> tuple[list[int], list[int], np.ndarray]:
        i0, i1, f = [], [], []
        for y in range(n_out):
            x = min(max((y + 0.5) / s - 0.5, 0.0), n_in - 1.0)
            a = math.floor(x)
            i0.append(a)
            i1.append(min(a + 1, n_in - 1))
            f.append(x - a)
        return i0, i1, np.array(f, np.float32)

    y0, y1, fy = axis(H, h)
    x0, x1, fx = axis(W, w)
    one = np.float32(1)
    top = r[y0][:, x0] * (one - fx)[None, :, None] + r[y0][:, x1] * fx[None, :, None]
    bot = r[y1][:, x0] * (one - fx)[None, :, None] + r[y1][:, x1] * fx[None, :, None]
    return top * (one - fy)[:, None, None] + bot * fy[:, None, None]


def check_camera(width: object, height: object, intrinsics: tuple, pose: tuple) -> None:
    """10.8, 10.9: sizes 1 .. 65536, every value finite, both focal lengths > 0."""
    need(all(is_int(x) and 1 <= x <= 65536 for x in (width, height)), "camera size")
    need(all(math.isfinite(v) for v in (*intrinsics, *pose)), "camera values")
    need(intrinsics[0] > 0 and intrinsics[1] > 0, "focal lengths")


def record_view(r: dict, image: bytes | None) -> dict:
    """10.7, 10.8: one view of the 1.0 layout (a header record and its RESI payload)."""
    cam, res = r["camera"], r.get("residual")
    need(isinstance(cam, dict), "camera map")
    intr, pose = cam["intrinsics"], cam["pose"]
    need(
        isinstance(intr, bytes) and len(intr) == 16 and isinstance(pose, bytes) and len(pose) == 48,
        "camera bins",
    )
    intrinsics, pose = struct.unpack("<4f", intr), struct.unpack("<12f", pose)
    check_camera(cam["width"], cam["height"], intrinsics, pose)
    view = {"width": cam["width"], "height": cam["height"], "length": len(image or b"")}
    view.update(intrinsics=intrinsics, pose=pose)
    if res is not None:
        need(isinstance(res, dict), "residual map")
        # 10.7: the gain as binary32 (what R is divided by) finite and > 0
        need(isinstance(res["gain"], float) and 2.0**-150 < res["gain"] < 2.0**128 - 2.0**103, "gain")
        s = res.get("scale", 1)
        need(is_int(s) and 1 <= s <= 16, "scale")
        need(
            res["codec"] in ("jxl", "webp", "avif") and res["bits"] in (8, 16) and is_int(res["bits"]),
            "codec",
        )
        need(is_int(res["offset"]) and res["offset"] == 1 << (res["bits"] - 1), "offset")
        need(list(res.get("full_shape", res["shape"])) == [cam["height"], cam["width"]], "full shape")
        need(list(res["shape"]) == [-(-cam["height"] // s), -(-cam["width"] // s)], "shape")
        codec = ["jxl", "webp", "avif"].index(res["codec"])
        view.update(codec=codec, bits=res["bits"], scale=s, gain=res["gain"], image=image)
    return view


def finite_number(x: object) -> bool:
    return (is_int(x) or isinstance(x, float)) and math.isfinite(x)


def check_meta(meta: dict, tiled: bool = False) -> None:
    """10.8: the sections of meta a decoder reads, each refused when present and malformed (a tiled file's
    attributes are its tiles', 10.14)."""
    need(tiled or isinstance(meta.get("attributes"), dict), "attributes section")
    side = meta.get("side_info")
    need(isinstance(side, dict), "side_info section")
    need(isinstance(side.get("views", []), list), "side_info.views")
    bg = side.get("background")
    need(
        isinstance(bg, list) and len(bg) == 3 and all(finite_number(v) and 0 <= v <= 1 for v in bg),
        "background",
    )
    restorer = side.get("restorer", "none")
    need(isinstance(restorer, str) and 1 <= len(restorer) <= 200, "restorer")
    iterations = side.get("refine_iterations", 300)
    need(is_int(iterations) and 0 <= iterations <= MAX_REFINE, "refine_iterations")
    if "scene" in meta:
        scene = meta["scene"]
        need(isinstance(scene, dict), "scene section")
        count, degree = scene.get("num_gaussians", 0), scene.get("sh_degree", 0)
        need(is_int(count) and count >= 0 and is_int(degree) and 0 <= degree <= 3, "scene section")


ATTRIBUTE_TYPES = ("POSN", "PREC", "OPAC", "SCAL", "ROTN", "SHDC", "SHRS")
TILE_TYPES = (*ATTRIBUTE_TYPES, "TSID")  # 10.15: a tile's TSID is one of its chunks for 10.14's layout rules


def tile_share(floor: int, per_byte: int, tile_bytes: int, all_bytes: int) -> int:
    """10.15: a tile's share of one file's floor, max(floor(floor x Q_k / Q), per_byte x Q_k)."""
    return max(floor * tile_bytes // max(all_bytes, 1), per_byte * tile_bytes)


def span_leads(tiles: list[dict]) -> list[int]:
    """10.17: each tile's span's first tile (its own number outside any span), of spans read_tiles checked."""
    lead = list(range(len(tiles)))
    for k, t in enumerate(tiles):
        lead[k + 1 : k + t.get("span", 1)] = [k] * (t.get("span", 1) - 1)
    return lead


def tile_sizes(chunks: list[tuple[str, int, bytes]], lead: list[int]) -> list[int]:
    """10.15: Q_k, the bytes of tile k's attribute payloads and of its TSID payload (the layout checked);
    10.17: a span's, its members' bytes in its first tile's Q_k (``lead``: span_leads), 0 for a member."""
    q = [0] * len(lead)
    for t, i, p in chunks:
        if t in TILE_TYPES:
            q[lead[i]] += len(p)
    return q


def read_tiles(
    meta: dict, chunks: list[tuple[str, int, bytes]]
) -> tuple[dict[str, np.ndarray], list[list[dict] | None]]:
    """10.14: a tiled file's attributes, its tiles' Gaussians one after another; 10.15: each tile's own
    side-information views (parse_side's dicts; None: the tile has no TSID), their pixels within the tile's
    share and their images not yet looked at."""
    need("attributes" not in meta, "a tiled file has no attributes section")
    index = [(i, p) for t, i, p in chunks if t == "TIDX"]
    need(len(index) == 1 and index[0][0] == 0, "one TIDX chunk, of index 0")
    payload = index[0][1]
    n = len(payload)

    def refuse_ext(code, data):
        raise SpecError("TIDX holds an extension type")

    try:
        tiles = msgpack.unpackb(
            payload, raw=False, ext_hook=refuse_ext, max_str_len=n, max_bin_len=n, max_array_len=n,
            max_map_len=n, max_ext_len=n,
        )  # fmt: skip
    except SpecError:
        raise
    except Exception:
        raise SpecError("TIDX is not one msgpack value") from None
    need(isinstance(tiles, list) and 2 <= len(tiles) <= MAX_TILES, "TIDX: an array of 2..8192 tiles")
    for t in tiles:
        need(isinstance(t, dict) and "box" in t and isinstance(t.get("attributes"), dict), "tile map")
        box = t["box"]
        need(isinstance(box, list) and len(box) == 6 and all(finite_float(x) for x in box), "tile box")
        need(all(box[a] <= box[a + 3] for a in range(3)), "tile box low above high")
    for k, t in enumerate(tiles):  # 1.7: the tiles drawn with tile k's views, other tiles, each once
        drawn = t.get("drawn", [])
        ok = isinstance(drawn, list) and len(drawn) <= 64 and len(set(map(repr, drawn))) == len(drawn)
        need(ok and all(type(j) is int and 0 <= j < len(tiles) and j != k for j in drawn), "tile's drawn")
    for k, t in enumerate(tiles):  # 1.9: the tiles k .. k + span - 1 that tile k's TSID serves (10.17)
        span = t.get("span", 1)
        need(type(span) is int and 1 <= span <= min(64, len(tiles) - k), "tile's span")
    degrees = {t["attributes"].get("sh_degree") for t in tiles}
    need(len(degrees) == 1, "tiles of different SH degrees")
    # The index first; each attribute chunk (and each TSID, 10.15) names a tile; a tile's chunks after the
    # one before's.
    per_tile: list[dict[str, bytes]] = [{} for _ in tiles]
    sides: dict[int, bytes] = {}
    seen_index, last = False, -1
    for t, i, p in chunks:
        if t == "TIDX":
            seen_index = True
        elif t in TILE_TYPES:
            need(seen_index, f"a {t} chunk before the tile index")
            need(0 <= i < len(tiles), f"a {t} chunk names no tile")
            need(i >= last, f"a tile's {t} chunk comes after a later tile's")
            last = i
            if t == "TSID":
                need(i not in sides, "two TSID chunks of one tile")
                sides[i] = p
            else:
                per_tile[i][t] = p
    # 10.17: a span above 1 only on a tile with a TSID; its members with no TSID, drawn tiles or span of their
    # own; none of its tiles drawn with it.
    for k, t in enumerate(tiles):
        members = range(k + 1, k + t.get("span", 1))
        need(not members or k in sides, f"tile {k}'s span without a TSID chunk")
        for j in members:
            alone = j not in sides and not tiles[j].get("drawn", []) and tiles[j].get("span", 1) == 1
            need(alone, f"tile {j} of tile {k}'s span with a TSID, drawn tiles or a span of its own")
        need(not set(members) & set(t.get("drawn", [])), f"tile {k}'s drawn names a tile of its span")
    total = sum(len(p) for c in per_tile for p in c.values())
    count = sum(t["attributes"].get("n", 0) for t in tiles if is_int(t["attributes"].get("n", 0)))
    need(count <= max(GAUSSIAN_FLOOR, 8 * total // MIN_CODED_BITS), "Gaussians in all past the tiles' bytes")
    # 10.15: each TSID in the SIDE layout (10.9), its views' pixels within the tile's share of the file's
    # floor, Q_k / Q (10.17: its span's), when the chunk is read.
    q = tile_sizes(chunks, span_leads(tiles))
    tile_views: list[list[dict] | None] = []
    for k in range(len(tiles)):
        if k not in sides:
            tile_views.append(None)
            continue
        views = parse_side(sides[k])
        share = min(MAX_TOTAL_PIXELS, tile_share(PIXEL_FLOOR, PIXELS_PER_BYTE, q[k], sum(q)))
        need(sum(v["width"] * v["height"] for v in views) <= share, f"tile {k}'s views pass its pixel share")
        tile_views.append(views)
    parts = []
    for t, c in zip(tiles, per_tile):
        tile_bytes = sum(len(p) for p in c.values())
        a = decode_attributes({"attributes": t["attributes"]}, c, Budget(tile_bytes, total))
        lo, hi = np.array(t["box"][:3], np.float32), np.array(t["box"][3:], np.float32)
        need(bool(((a["means"] >= lo) & (a["means"] <= hi)).all()), "a tile's position outside its box")
        parts.append(a)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, tile_views


def read_scene(data: bytes, residuals: bool = True) -> tuple[dict[str, np.ndarray], list[dict]]:
    """A whole file's codec layer: the attributes, and the side-information views with residual R: the whole
    scene's (SIDE or RESI), then, in a tiled file, each tile's own (TSID, 10.15) in tile order, each of those
    marked with its tile's number (key ``tile``). With ``residuals`` False, a decoder that does not use the
    residual images (10.7): each image's signature and declared size are checked, its pixels are not
    decoded."""
    version, meta, chunks = read_container(data)
    tiled = any(t == "TIDX" for t, _, _ in chunks)
    check_meta(meta, tiled)
    attr = {}
    for t, index, payload in chunks:
        need(t != "TSID" or tiled, "a TSID chunk in a file without a tile index (10.15)")
        if t in ATTRIBUTE_TYPES and not tiled:
            need(index == 0, f"{t} index")
            attr[t] = payload
    tile_views: list[list[dict] | None] = []
    if tiled:
        attributes, tile_views = read_tiles(meta, chunks)
    else:
        attributes = decode_attributes(meta, attr)
    side = [(i, p) for t, i, p in chunks if t == "SIDE"]
    resi = {i: p for t, i, p in chunks if t == "RESI"}
    records = meta["side_info"].get("views", [])
    if side:  # 10.9
        need(side[0][0] == 0, "SIDE index")
        need(not records and not resi, "SIDE and the 1.0 layout")
        views = parse_side(side[0][1])
    else:  # 10.7: views in meta, one RESI chunk per view with a residual record
        views = []
        need(set(resi) == {k for k, r in enumerate(records) if "residual" in r}, "RESI chunks and records")
        for k, r in enumerate(records):
            try:
                views.append(record_view(r, resi.get(k)))
            except (KeyError, TypeError, ValueError, AttributeError) as e:  # a missing key or another type
                raise SpecError(f"1.0 view {k} malformed ({type(e).__name__})") from None
        need(all(v["width"] * v["height"] <= MAX_VIEW_PIXELS for v in views), "view pixels")
        need(sum(v["width"] * v["height"] for v in views) <= MAX_TOTAL_PIXELS, "total pixels")
    # 10.8: all views together within the file's pixel budget, before anything is rendered or decoded.
    budget = min(MAX_TOTAL_PIXELS, max(PIXEL_FLOOR, PIXELS_PER_BYTE * len(data)))
    need(sum(v["width"] * v["height"] for v in views) <= budget, "pixels beyond the file's budget")
    # 10.15: each tile's own views, their pixels already held to the tile's share (read_tiles).
    for k, tv in enumerate(tile_views):
        views += [dict(v, tile=k) for v in tv or ()]
    for v in views:
        if v["length"]:
            check_image_header(v)
    for v in views:
        if v["length"] and residuals:
            v["residual"] = decode_residual(v)
    return attributes, views


# --------------------------------------------------------------------------------- the decoder's work (10.8)

PAIR_FLOOR, PAIRS_PER_BYTE = 1 << 22, 32  # 10.8: P_v <= max(2^22, 32 x size)
WORK_FLOOR, WORK_PER_BYTE = 1 << 26, 4096  # 10.8: F <= max(2^26, 4096 x size)
RESTORED_PIXEL = 8


def view_pairs(attributes: dict[str, np.ndarray], view: dict) -> int:
    """10.8 "The decoder's work": the Gaussian-tile pairs P_v of one view, from the projection of 10.12
    rules 1 and 2 (binary64), over the Gaussians ``attributes`` (a tile's alone for its own views, 10.15)."""
    fx, fy, cx, cy = (float(v) for v in view["intrinsics"])
    w, h = view["width"], view["height"]
    pose = np.array(view["pose"], np.float64).reshape(3, 4)
    rot, t = pose[:, :3], pose[:, 3]
    p = attributes["means"].astype(np.float64) @ rot.T + t
    q = attributes["quats"].astype(np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    qw, qx, qy, qz = q.T
    rq = np.stack(
        [
            np.stack([1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)], -1),
            np.stack([2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)], -1),
            np.stack([2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)], -1),
        ],
        1,
    )
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        m = rq * np.exp(attributes["log_scales"].astype(np.float64))[:, None, :]
        cov = rot @ (m @ m.transpose(0, 2, 1)) @ rot.T
        z = p[:, 2]
        lim_x = (cx / fx + 0.3 * w / (2 * fx), (w - cx) / fx + 0.3 * w / (2 * fx))
        lim_y = (cy / fy + 0.3 * h / (2 * fy), (h - cy) / fy + 0.3 * h / (2 * fy))
        tx = np.clip(p[:, 0] / z, -lim_x[0], lim_x[1])
        ty = np.clip(p[:, 1] / z, -lim_y[0], lim_y[1])
        j = np.zeros((len(z), 2, 3))
        j[:, 0, 0], j[:, 0, 2] = fx / z, -fx * tx / z
        j[:, 1, 1], j[:, 1, 2] = fy / z, -fy * ty / z
        cov2 = j @ cov @ j.transpose(0, 2, 1)
        alpha = 1 / (1 + np.exp(-attributes["opacities"].astype(np.float64)))
        thr = 2 * np.log(255 * alpha)
        hx, hy = np.sqrt(thr * (cov2[:, 0, 0] + 0.3)), np.sqrt(thr * (cov2[:, 1, 1] + 0.3))
        mx, my = fx * p[:, 0] / z + cx, fy * p[:, 1] / z + cy
        drawn = (z > 0.01) & (alpha >= 1 / 255)

        def tiles(centre: np.ndarray, half: np.ndarray, size: int) -> np.ndarray:
            # columns i, 0 <= i < ceil(size / 8), with 8 i + 0.5 <= centre + half, 8 i + 7.5 >= centre - half
            first = np.maximum(np.ceil((centre - half - 7.5) / 8), 0)
            last = np.minimum(np.floor((centre + half - 0.5) / 8), -(-size // 8) - 1)
            return np.where(np.isfinite(last - first), np.maximum(last - first + 1, 0), 0)

        count = tiles(mx, hx, w) * tiles(my, hy, h)
    return int(count[drawn & np.isfinite(count)].sum())


def view_work(
    attributes: dict[str, np.ndarray], views: list[dict], restore: bool, pair_budget: int, what: str
) -> tuple[int, int]:
    """10.8 "The decoder's work" of rendering ``views`` of the Gaussians ``attributes`` (a whole scene, or one
    tile's alone, 10.15): each view's pairs checked against ``pair_budget`` before the next is counted;
    (the first work F, the heaviest view's work max_v w_v)."""
    n = len(attributes["means"])
    work = []
    for k, v in enumerate(views):
        pairs = view_pairs(attributes, v)
        need(pairs <= pair_budget, f"{what}view {k}: Gaussian-tile pairs past the budget")
        work.append(n + pairs + v["width"] * v["height"])
    restored = sum(v["width"] * v["height"] for v in views if v["length"]) if restore else 0
    return sum(work) + RESTORED_PIXEL * restored, max(work, default=1)


def decoder_work(data: bytes, restore: bool = True) -> int | list[int | None]:
    """10.8: check a file's work as a decoder that renders (and, with ``restore``, restores) does, and return
    the refinement iterations its default runs. A tiled file (10.15): each tile's own views checked against
    the tile's share of the file's budgets, counted over the tile's Gaussians alone (10.17: a span's views
    over the span's, with its share), and the iterations of each tile's default refinement returned, tile
    by tile (None: the tile has no TSID, a span's member too); the whole scene's views, where it has any,
    are checked as 10.8 says."""
    attributes, views = read_scene(data, residuals=restore)
    meta, chunks = read_container(data)[1:]
    iterations = meta["side_info"].get("refine_iterations", 300)
    size, n = len(data), len(attributes["means"])
    scene_views = [v for v in views if "tile" not in v]
    first, heaviest = view_work(attributes, scene_views, restore, max(PAIR_FLOOR, PAIRS_PER_BYTE * size), "")
    budget = max(WORK_FLOOR, WORK_PER_BYTE * size)
    need(first <= budget, "first renders and restoration past the work budget")
    runs = min(iterations, max(1000, n), (budget - first) // heaviest)
    index = [p for t, _, p in chunks if t == "TIDX"]
    if not index:
        return runs
    tiles = msgpack.unpackb(index[0], raw=False)
    counts = [t["attributes"]["n"] for t in tiles]
    q = tile_sizes(chunks, span_leads(tiles))
    out: list[int | None] = []
    for k, start in enumerate(np.cumsum([0, *counts[:-1]]).tolist()):
        mine = [v for v in views if v.get("tile") == k]
        if not mine:  # no TSID (a TSID holds at least one view, 10.9)
            out.append(None)
            continue
        n_k = sum(counts[k : k + tiles[k].get("span", 1)])  # 10.17: the span's Gaussians, tile k's first
        tile = {name: a[start : start + n_k] for name, a in attributes.items()}
        pairs = tile_share(PAIR_FLOOR, PAIRS_PER_BYTE, q[k], sum(q))
        first, heaviest = view_work(tile, mine, restore, pairs, f"tile {k}'s ")
        budget = tile_share(WORK_FLOOR, WORK_PER_BYTE, q[k], sum(q))
        need(first <= budget, f"tile {k}'s first renders and restoration past its share of the work budget")
        out.append(min(iterations, max(1000, n_k), (budget - first) // heaviest))
    return out
