"""Exact entropy coding of integer symbol arrays with contexts from already-decoded data.

Everything the range coder sees is derived from integers written in the stream, with IEEE
float64 operations that are correctly rounded on every machine (+, -, *, / and cumulative
products; no exp/log/pow), so encoder and decoder build identical probability tables.

Layers, each usable alone:
- ``bit_length``: vectorised integer bit length.
- Models (``fit_model``, ``model_weights``): a model is a short list of ints, the "spec":
  ``[0]`` empty, ``[1, v]`` constant v (costs no bits), ``[2, lo, hi, c, u, b]`` two-sided geometric
  over the window lo..hi centred at c with ratio ``THETAS[u]`` and the centre weight scaled by
  ``BOOSTS[b] / 8``, ``[3, lo, hi, w_lo, ..., w_hi]`` integer frequency table.
- ``encode_matrix`` / ``decode_matrix``: an (M, C) integer matrix coded channel by channel. Rows
  follow a space-filling curve; row i's spatial context is rows ``i - h`` and ``i + h`` where h is
  the lowest set bit of i (a dyadic hierarchy: rows that are multiples of 64 first, without spatial
  context, then the midpoints at distances 32, 16, ..., 1). Intra context is the previous channel of
  the same row. Per channel the encoder picks the predictor (none, neighbours, previous channel,
  neighbours plus the previous channel's prediction error) that minimises the estimated rate; the
  context bucket (neighbour disagreement x previous channel's residual magnitude) picks the model.
"""

from __future__ import annotations

import math

import constriction
import msgpack
import numpy as np
import zstandard

from gspc.errors import CodecError, ValueRangeError
from gspc.limits import DecodeBudget, max_model_entries, max_model_list_bytes

BASE_STRIDE = 64
_NUM_SPATIAL = 5  # |a-b| bit length 0, 1, 2, >=3, and "no neighbours" (base rows)
_NUM_INTRA = 3  # previous channel's |residual| bit length 0, 1, >=2
NUM_BUCKETS = _NUM_SPATIAL * _NUM_INTRA
NUM_MODES = 4
_EMPIRICAL_MAX_WINDOW = 512
_EMPIRICAL_SCALE = 1023
_WEIGHT_SCALE = float(1 << 30)
PRECISION = 24  # constriction's default range coder: 32-bit words, 64-bit state, 24-bit probabilities
MAX_WINDOW = 1 << 22  # symbols per model (constriction needs fewer than 2^24 - 1)
# Model integers and decoded entries lie in -2^48..2^48 (spec 10.0), so every prediction (at most three
# such terms) fits in int64 and every value converts to float64 exactly: no wrap-around to define.
INT_LIMIT = 1 << 48
# The largest |symbol| encode_matrix takes: mode 0 (no prediction) then codes any column within MAX_WINDOW;
# predicting modes whose residuals would need a wider window are not chosen.
SYMBOL_LIMIT = (MAX_WINDOW >> 1) - 1


def _thetas() -> np.ndarray:
    # 1 - m/2^20 with m shrinking by ~2^(-1/8) per step, in integers: exact and machine-independent.
    m = [1 << 20]
    while m[-1] > 8:
        m.append((m[-1] * 60097) >> 16)
    return np.array([1.0 - mi / float(1 << 20) for mi in m])


THETAS = _thetas()
BOOSTS = np.array(
    [1, 2, 3, 4, 6, 8, 11, 16, 23, 32, 45, 64, 91, 128, 181, 256, 362, 512, 724, 1024, 1448, 2048]
)


def bit_length(x: np.ndarray) -> np.ndarray:
    """Bit length of non-negative int64 integers (0 -> 0, 1 -> 1, 2..3 -> 2, ...), exact up to 2^63 - 1."""
    x = np.asarray(x, dtype=np.int64)
    if x.size and 0 <= int(x.min()) and int(x.max()) < 1 << 53:
        # Every such integer is a float64 exactly, whose binary exponent is its bit length (0 -> 0).
        return np.frexp(x.astype(np.float64))[1].astype(np.int64)
    x = x.copy()
    n = np.zeros(x.shape, np.int64)
    for s in (32, 16, 8, 4, 2, 1):  # binary search on integers: no float rounding near 2^53
        big = x >= (1 << s)
        n += big * s
        x = np.where(big, x >> s, x)
    return n + (x > 0)


# ---------------------------------------------------------------------------------------------
# Models


def model_weights(spec: list[int]) -> np.ndarray:
    """Integer-valued float64 weights over the spec's window (kinds 2 and 3)."""
    kind, lo, hi = spec[0], spec[1], spec[2]
    if kind == 3:
        return np.asarray(spec[3:], dtype=np.float64)
    c, u, b = spec[3], spec[4], spec[5]
    d = np.abs(np.arange(lo, hi + 1, dtype=np.int64) - c)
    powers = np.cumprod(np.concatenate([[1.0], np.full(int(d.max()), THETAS[u])]))
    w = np.maximum(np.floor(powers[d] * _WEIGHT_SCALE), 1.0)
    if lo <= c <= hi:
        w[c - lo] = max(np.floor(w[c - lo] * float(BOOSTS[b]) / 8.0), 1.0)
    return w


def _rate_grid_factors() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """fit_model's per-(theta, boost) constants: log2 of the normaliser z, of the centre boost, of theta (1
    where theta is 0) and where theta is positive; the same float64 operations as computing them per call."""
    th = THETAS[:, None]
    bo = BOOSTS[None, :] / 8.0
    with np.errstate(divide="ignore", invalid="ignore"):
        z = bo + 2.0 * th / (1.0 - th)
        return np.log2(z), np.log2(bo), np.log2(np.where(th > 0, th, 1)), th > 0


_LOG2_Z, _LOG2_BOOST, _LOG2_THETA, _THETA_POSITIVE = _rate_grid_factors()


def fit_model(sym: np.ndarray) -> tuple[list[int], float]:
    """The cheapest model spec for these symbols and its estimated cost in bits (table included)."""
    sym = np.asarray(sym, dtype=np.int64)
    specs, bits = fit_models(sym, np.zeros(sym.size, np.int64), 1)
    return specs[0], bits[0]


def fit_models(sym: np.ndarray, context: np.ndarray, contexts: int) -> tuple[list[list[int]], list[float]]:
    """:func:`fit_model` of the symbols of each context ``0 .. contexts - 1`` (``context`` beside ``sym``,
    each value below ``contexts``): the same specs and costs, the float arithmetic of each context's cost
    unchanged, with one sort for all of them and one compiled pass over the contexts (gspc/codec/fit_cpu.py;
    the encoder fits four predictors x 15 buckets per column). Each context's model: the cheapest of a
    two-sided geometric over its window (the best theta and boost by their rate on the infinite support, then
    costed on the window) and, for windows under 512 symbols, an explicit table of its counts."""
    sym, context = np.asarray(sym, dtype=np.int64), np.asarray(context, dtype=np.int64)
    specs: list[list[int]] = [[0] for _ in range(contexts)]
    bits = [0.0] * contexts
    if sym.size == 0:
        return specs, bits
    count = np.bincount(context, minlength=contexts)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    # Each context's symbols in order: one sort of (context, symbol) packed into one integer where it fits.
    low, span = int(sym.min()), int(sym.max()) - int(sym.min()) + 1
    if span < (1 << 62) // contexts:
        ordered = np.sort(context * span + (sym - low)) % span + low
    else:
        ordered = sym[np.lexsort((sym, context))]
    from gspc.codec import fit_cpu  # numba: imported where an encoder fits models

    kind, head, cost, table_start, tables = fit_cpu.fit_sorted(
        ordered,
        first,
        count,
        _LOG2_Z,
        _LOG2_BOOST.ravel(),
        _LOG2_THETA.ravel(),
        _THETA_POSITIVE.ravel(),
        THETAS,
        BOOSTS,
        _WEIGHT_SCALE,
        _EMPIRICAL_MAX_WINDOW,
        _EMPIRICAL_SCALE,
    )
    for k in np.flatnonzero(kind).tolist():
        a, z, c, u, b = head[k].tolist()
        if kind[k] == 1:
            specs[k] = [1, a]
        elif kind[k] == 2:
            specs[k] = [2, a, z, c, u, b]
        else:
            specs[k] = [3, a, z, *tables[table_start[k] : table_start[k + 1]].tolist()]
        bits[k] = float(cost[k])
    return specs, bits


def _is_int(x: object) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def check_spec(spec: object) -> None:
    """CodecError unless ``spec`` is a model spec of spec 10.0, checked before any table is built: a
    kind-2 centre far outside its window would otherwise make :func:`model_weights` allocate without bound."""
    if not isinstance(spec, list) or not spec or not all(_is_int(v) for v in spec):
        raise CodecError(f"entropy model spec {spec!r:.60} is not a list of integers")
    if not all(-INT_LIMIT <= v <= INT_LIMIT for v in spec):
        raise CodecError("entropy model spec holds an integer outside -2^48..2^48")
    kind = spec[0]
    sizes = {0: 1, 1: 2, 2: 6}
    if kind not in (0, 1, 2, 3) or len(spec) != sizes.get(kind, max(len(spec), 3)):
        raise CodecError(f"entropy model spec of kind {kind} has {len(spec)} integers")
    if kind < 2:
        return
    lo, hi = spec[1], spec[2]
    if not 2 <= hi - lo + 1 <= MAX_WINDOW:
        raise CodecError(f"entropy model window {lo}..{hi} is outside 2..{MAX_WINDOW} symbols")
    if kind == 2:
        c, u, b = spec[3:]
        if not (lo <= c <= hi and 0 <= u < THETAS.size and 0 <= b < BOOSTS.size):
            raise CodecError(f"geometric model centre {c}, ratio {u} or boost {b} out of range")
    elif len(spec) != 3 + hi - lo + 1:
        raise CodecError(f"explicit model over {hi - lo + 1} symbols lists {len(spec) - 3} weights")


def table_entries(spec: list[int]) -> int:
    """Entries of the probability table a checked spec builds: its window for kinds 2 and 3, else none."""
    return spec[2] - spec[1] + 1 if spec[0] >= 2 else 0


def check_models(header: object, nc: int, payload_bytes: int, budget: DecodeBudget | None = None) -> list:
    """CodecError unless ``header`` is the model list of an ``nc``-column matrix (spec 10.0) whose tables
    together stay within gspc/limits.py's bound for a ``payload_bytes``-byte matrix: every spec is checked
    and the tables counted before any table is built."""
    if not isinstance(header, list) or len(header) != nc:
        count = len(header) if isinstance(header, list) else "no"
        raise CodecError(f"entropy models list {count} columns, the matrix has {nc}")
    entries = 0
    for ch, column in enumerate(header):
        if not (isinstance(column, list) and len(column) == 2):
            raise CodecError(f"column {ch}'s models are not a [mode, models] pair")
        mode, specs = column
        # Column 0 has no previous column: modes 2 and 3 would predict from zeros (spec 10.0).
        if not _is_int(mode) or not 0 <= mode < (NUM_MODES if ch > 0 else 2):
            raise CodecError(f"column {ch} has prediction mode {mode!r}")
        if not isinstance(specs, list) or len(specs) != NUM_BUCKETS:
            count = len(specs) if isinstance(specs, list) else "no"
            raise CodecError(f"column {ch} lists {count} models, not {NUM_BUCKETS}")
        for spec in specs:
            check_spec(spec)
            entries += table_entries(spec)
    limit = max_model_entries(payload_bytes)
    if entries > limit:
        raise CodecError(
            f"entropy models build {entries:,} table entries from a {payload_bytes:,}-byte matrix "
            f"(limit {limit:,})"
        )
    if budget is not None and not budget.spend_tables(entries):
        raise CodecError("the file's entropy models build more table entries in all than its bytes allow")
    return header


def fixed_point_table(spec: list[int]) -> np.ndarray:
    """The exact integer frequencies the range coder uses: every symbol >= 1, summing to 2^PRECISION.

    With n symbols, weights w and W = sum(w): ``f = 1 + floor(w * (2^PRECISION - n) / W)``, then the
    shortfall ``2^PRECISION - sum(f)`` (0 <= shortfall < n) goes to the first symbol of largest weight.
    All int64 arithmetic: weights are below 2^39 and the window below 2^24, so nothing overflows.
    """
    w = model_weights(spec).astype(np.int64)
    n = w.size
    if (w < 0).any() or w.max() >= 1 << 39 or w.sum() <= 0:
        raise CodecError("entropy model has weights outside 0..2^39 or none positive")
    if not 2 <= n <= MAX_WINDOW:
        raise CodecError(f"entropy model window of {n} symbols is outside 2..{MAX_WINDOW}")
    free = (1 << PRECISION) - n
    f = 1 + (w * free) // int(w.sum())
    f[int(np.argmax(w))] += (1 << PRECISION) - int(f.sum())
    return f


def _categorical(spec: list[int]):
    # constriction's fast quantiser (ContiguousCategoricalEntropyModel::
    # from_floating_point_probabilities_fast)
    # sets cdf[i] = floor(sum(p[:i]) * (2^24 - n) / sum(p)) + i. Given p = f - 1 (integers, so every sum is
    # exact in float64 and the scale is exactly 1.0), that is cdf[i] = sum(f[:i]): the coder uses f exactly.
    f = fixed_point_table(spec)
    return constriction.stream.model.Categorical((f - 1).astype(np.float64), perfect=False)


def encode_symbols(enc, sym: np.ndarray, spec: list[int], model=None) -> None:
    if spec[0] < 2 or sym.size == 0:
        return
    model = _categorical(spec) if model is None else model
    enc.encode((np.asarray(sym, dtype=np.int64) - spec[1]).astype(np.int32), model)


def decode_symbols(dec, n: int, spec: list[int], model=None) -> np.ndarray:
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if spec[0] == 1:
        return np.full(n, spec[1], dtype=np.int64)
    if spec[0] < 2:
        raise CodecError("entropy stream asks for symbols from an empty model")
    model = _categorical(spec) if model is None else model
    return dec.decode(model, n).astype(np.int64) + spec[1]


# ---------------------------------------------------------------------------------------------
# Context coding of (M, C) matrices


def hierarchy(m: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Coding levels: (rows, left neighbour, right neighbour); the first level has no neighbours."""
    levels = [(np.arange(0, m, BASE_STRIDE), np.zeros(0, np.int64), np.zeros(0, np.int64))]
    h = BASE_STRIDE // 2
    while h >= 1:
        rows = np.arange(h, m, 2 * h)
        right = rows + h
        right = np.where(right < m, right, rows - h)
        levels.append((rows, rows - h, right))
        h //= 2
    return levels


def _prediction(mode: int, nb: np.ndarray, prev_q: np.ndarray, prev_nb: np.ndarray) -> np.ndarray:
    if mode == 0:
        return np.zeros_like(nb)
    if mode == 1:
        return nb
    if mode == 2:
        return prev_q
    return nb + (prev_q - prev_nb)


def _context(q: np.ndarray, rows: np.ndarray, left: np.ndarray, right: np.ndarray):
    """Neighbour prediction (floor mean) and spatial bucket for one level's rows."""
    if left.size == 0:
        return np.zeros(rows.size, np.int64), np.full(rows.size, _NUM_SPATIAL - 1)
    a, b = q[left], q[right]
    return (a + b) >> 1, np.minimum(bit_length(np.abs(a - b)), _NUM_SPATIAL - 2)


def _intra_bucket(prev_res: np.ndarray) -> np.ndarray:
    return np.minimum(bit_length(np.abs(prev_res)), _NUM_INTRA - 1)


def _full_context(q: np.ndarray, levels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Neighbour prediction, spatial bucket and level index for every row (encoder side)."""
    nb = np.zeros(q.size, np.int64)
    sb = np.zeros(q.size, np.int64)
    lv = np.zeros(q.size, np.int64)
    for k, (rows, left, right) in enumerate(levels):
        nb[rows], sb[rows] = _context(q, rows, left, right)
        lv[rows] = k
    return nb, sb, lv


def encode_matrix(q: np.ndarray) -> bytes:
    """Code an (M, C) integer matrix of entries within +-SYMBOL_LIMIT; returns a self-contained payload
    (models + range-coder words). Columns are widened to int64 one at a time (a narrower matrix stays so)."""
    q = np.asarray(q)
    if q.dtype.kind not in "iu":
        raise CodecError(f"encode_matrix takes an integer matrix, not {q.dtype}")
    m, nc = q.shape
    if m == 0:
        return msgpack.packb([0, nc, b"", b""], use_bin_type=True)
    levels = hierarchy(m)
    enc = constriction.stream.queue.RangeEncoder()
    header: list = []
    prev_q = np.zeros(m, np.int64)
    prev_nb = np.zeros(m, np.int64)
    prev_res = np.zeros(m, np.int64)
    for ch in range(nc):
        col = q[:, ch].astype(np.int64)
        if int(np.abs(col).max()) > SYMBOL_LIMIT:
            raise CodecError(f"column {ch} holds a symbol beyond +-{SYMBOL_LIMIT} (windows are bounded)")
        nb, sb, lv = _full_context(col, levels)
        bucket = sb * _NUM_INTRA + _intra_bucket(prev_res)
        best = None
        for mode in range(NUM_MODES if ch > 0 else 2):
            res = col - _prediction(mode, nb, prev_q, prev_nb)
            specs, costs = fit_models(res, bucket, NUM_BUCKETS)
            bits = 0.0
            for spec, cost in zip(specs, costs):
                # A window wider than a model may have rules the mode out (mode 0's never is: the symbols
                # are within SYMBOL_LIMIT).
                bits += cost if spec[0] < 2 or spec[2] - spec[1] < MAX_WINDOW else math.inf
            if best is None or bits < best[0]:
                best = (bits, mode, res, specs)
        _, mode, res, specs = best
        header.append([mode, specs])
        # Symbols go level by level, bucket by bucket, each run in row order: one stable sort by (level,
        # bucket) gives that order (16-bit keys: NumPy sorts them by radix). One table per bucket, built
        # when first used (as decode_matrix builds them): each level would otherwise build the same tables.
        key = (lv * NUM_BUCKETS + bucket).astype(np.int16)
        order = np.argsort(key, kind="stable")
        runs = np.flatnonzero(np.diff(key[order])) + 1
        models: dict[int, object] = {}
        for start, end in zip([0, *runs.tolist()], [*runs.tolist(), m]):
            bk = int(key[order[start]]) % NUM_BUCKETS
            if bk not in models and specs[bk][0] >= 2:
                models[bk] = _categorical(specs[bk])
            encode_symbols(enc, res[order[start:end]], specs[bk], models.get(bk))
        prev_q, prev_nb, prev_res = col, nb, res
    words = enc.get_compressed().astype("<u4").tobytes()
    # Model specs are small ints with much repetition: zstd halves them or better.
    raw = msgpack.packb(header, use_bin_type=True)
    packed = zstandard.ZstdCompressor(level=19).compress(raw)
    payload = msgpack.packb([m, nc, packed, words], use_bin_type=True)
    # Never write what the decoder refuses (gspc/limits.py): tables wider than the payload warrants come from
    # steps far finer than the values' spread, which a larger lambda codes.
    entries = sum(table_entries(spec) for _, specs in header for spec in specs)
    if entries > max_model_entries(len(payload)) or len(raw) > max_model_list_bytes(len(packed)):
        raise ValueRangeError(
            f"a coded matrix's models need {entries:,} table entries for {len(payload):,} bytes, more than "
            "a decoder accepts; a larger lambda codes it"
        )
    return payload


def _unpack_models(packed: bytes, budget: DecodeBudget | None = None) -> list:
    # One zstd frame, nothing after it; a frame that declares more than the limit is refused before
    # zstandard allocates the declared size (it ignores max_output_size for declared sizes).
    # The limit grows with the frame (gspc/limits.py): every decompressed byte is parsed and checked.
    limit = max_model_list_bytes(len(packed))
    size = zstandard.frame_content_size(packed)
    if size > limit:
        raise CodecError(
            f"entropy models declare {size} bytes from a {len(packed)}-byte frame (at most {limit})"
        )
    if budget is not None and size > budget.model_bytes:
        raise CodecError("the file's entropy models decompress to more bytes in all than its bytes allow")
    if budget is not None:
        limit = min(limit, budget.model_bytes)
    raw = zstandard.ZstdDecompressor().decompress(packed, max_output_size=limit, allow_extra_data=False)
    if budget is not None and not budget.spend_model_bytes(len(raw)):
        raise CodecError("the file's entropy models decompress to more bytes in all than its bytes allow")
    return msgpack.unpackb(raw, raw=False)


def _read_matrix(
    payload: bytes, shape: tuple[int, int] | None, budget: DecodeBudget | None = None
) -> tuple[int, int, list, bytes]:
    """(rows, columns, checked model list, words) of a matrix payload, every rule of spec 10.0 checked that
    needs no symbol decoded (an empty matrix: no models, no words)."""
    ecm = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    if not (isinstance(ecm, list) and len(ecm) == 4):
        raise CodecError("entropy-coded matrix is not an array of 4 elements")
    m, nc, packed, words = ecm
    if not (_is_int(m) and _is_int(nc) and isinstance(packed, bytes) and isinstance(words, bytes)):
        raise CodecError("entropy-coded matrix has fields of the wrong types")
    if shape is not None and (m, nc) != tuple(shape):
        raise CodecError(f"entropy-coded matrix is {m}x{nc}, expected {shape[0]}x{shape[1]}")
    if m < 0 or nc < 0:
        raise CodecError(f"entropy-coded matrix has a negative shape {m}x{nc}")
    if m == 0:
        if packed or words:
            raise CodecError("an entropy-coded matrix of 0 rows has models or words")
        return m, nc, [], words
    if len(words) % 4:
        raise CodecError(f"range coder words take {len(words)} bytes, not a multiple of 4")
    return m, nc, check_models(_unpack_models(packed, budget), nc, len(payload), budget), words


def matrix_table_entries(payload: bytes, budget: DecodeBudget | None = None) -> int:
    """Entries of the probability tables a matrix payload's models build, read and checked as
    :func:`decode_matrix` reads them, no table built: the matrices of one chunk at attribute codec version 4
    share one bound (spec 10.10, gspc/limits.py max_model_entries), summed from these first."""
    try:
        _, _, header, _ = _read_matrix(payload, None, budget)
    except CodecError:
        raise
    except Exception as err:  # malformed payloads surface as one-line codec errors
        raise CodecError(f"corrupt entropy-coded payload ({type(err).__name__}: {err})") from None
    return sum(table_entries(spec) for _, specs in header for spec in specs)


def decode_matrix(
    payload: bytes, shape: tuple[int, int] | None = None, budget: DecodeBudget | None = None
) -> np.ndarray:
    """Inverse of :func:`encode_matrix`. With ``shape``, a matrix of another shape is refused before
    anything of its size is allocated (spec 10.0: the caller knows the shape). ``budget``: what the file's
    decode may still spend, shared with its other matrices (a tiled file's, spec 10.14)."""
    try:
        m, nc, header, words = _read_matrix(payload, shape, budget)
        if m == 0:
            return np.zeros((0, nc), np.int64)
        dec = constriction.stream.queue.RangeDecoder(np.frombuffer(words, dtype="<u4").copy())
        levels = hierarchy(m)
        q = np.zeros((m, nc), np.int64)
        prev_q = np.zeros(m, np.int64)
        prev_nb = np.zeros(m, np.int64)
        prev_res = np.zeros(m, np.int64)
        for ch in range(nc):
            mode, specs = header[ch]
            models = [_categorical(s) if s[0] >= 2 else None for s in specs]
            col = np.zeros(m, np.int64)
            nb_all = np.zeros(m, np.int64)
            res_all = np.zeros(m, np.int64)
            for rows, left, right in levels:
                nb, sb = _context(col, rows, left, right)
                bucket = sb * _NUM_INTRA + _intra_bucket(prev_res[rows])
                res = np.zeros(rows.size, np.int64)
                # Bucket by bucket, each in row order (as encode_matrix wrote them).
                order = np.argsort(bucket.astype(np.int16), kind="stable")
                ends = np.cumsum(np.bincount(bucket, minlength=NUM_BUCKETS)).tolist()
                for bk, (start, end) in enumerate(zip([0, *ends[:-1]], ends)):
                    if end > start:
                        res[order[start:end]] = decode_symbols(dec, end - start, specs[bk], models[bk])
                col[rows] = res + _prediction(mode, nb, prev_q[rows], prev_nb[rows])
                if rows.size and np.abs(col[rows]).max() > INT_LIMIT:
                    raise CodecError(f"column {ch} decodes to a value outside -2^48..2^48")
                nb_all[rows], res_all[rows] = nb, res
            q[:, ch] = col
            prev_q, prev_nb, prev_res = col, nb_all, res_all
        return q
    except CodecError:
        raise
    except Exception as err:  # malformed payloads surface as one-line codec errors
        raise CodecError(f"corrupt entropy-coded payload ({type(err).__name__}: {err})") from None


# ---------------------------------------------------------------------------------------------
# Raw bits


# Values per block of pack_bits / unpack_bits: a uint64 per bit of a large scene's positions at once costs
# far more memory than the payload (bench/scale.md, "Reading").
BITS_BLOCK = 1 << 16


def pack_bits(values: np.ndarray, lengths: np.ndarray) -> bytes:
    """Concatenate the low ``lengths[i]`` bits of ``values[i]`` (MSB first) into bytes."""
    values = np.asarray(values, dtype=np.uint64)
    lengths = np.asarray(lengths, dtype=np.int64)
    width = int(lengths.max()) if lengths.size else 0
    if width == 0:
        return b""
    shifts = np.arange(width - 1, -1, -1, dtype=np.int64)  # MSB first within the field
    parts = []
    for a in range(0, len(values), BITS_BLOCK):
        v, n = values[a : a + BITS_BLOCK, None], lengths[a : a + BITS_BLOCK, None]
        bits = ((v >> shifts[None, :].astype(np.uint64)) & np.uint64(1)).astype(np.uint8)
        parts.append(bits[shifts[None, :] < n])
    return np.packbits(np.concatenate(parts)).tobytes()


def unpack_bits(data: bytes, lengths: np.ndarray) -> np.ndarray:
    lengths = np.asarray(lengths, dtype=np.int64)
    total = int(lengths.sum())
    out = np.zeros(lengths.size, np.uint64)
    if total == 0:
        if data:
            raise CodecError(f"raw-bit section has {len(data)} bytes, its lengths need none")
        return out
    # Exactly ceil(total / 8) bytes with zero padding bits (spec 10.0 "Raw bits"): every payload has one form.
    if len(data) != (total + 7) // 8:
        raise CodecError(f"raw-bit section has {len(data)} bytes, its lengths need {(total + 7) // 8}")
    bits = np.unpackbits(np.frombuffer(data, np.uint8))
    if bits[total:].any():
        raise CodecError("raw-bit section has non-zero padding bits")
    ends = np.cumsum(lengths)
    for a in range(0, lengths.size, BITS_BLOCK):
        n = lengths[a : a + BITS_BLOCK]
        first = int(ends[a] - n[0])
        block = bits[first : int(ends[a + n.size - 1])].astype(np.uint64)
        owner = np.repeat(np.arange(n.size), n)
        pos = np.arange(block.size) - (np.cumsum(n) - n)[owner]
        shift = (n[owner] - 1 - pos).astype(np.uint64)
        np.add.at(out[a : a + BITS_BLOCK], owner, block << shift)
    return out
