import constriction
import numpy as np
import pytest

import gspc.codec.entropy as entropy
import gspc.codec.fit_cpu as fit_cpu
from gspc.codec.entropy import (
    PRECISION,
    SYMBOL_LIMIT,
    _categorical,
    bit_length,
    decode_matrix,
    encode_matrix,
    fit_model,
    fit_models,
    fixed_point_table,
    model_weights,
    pack_bits,
    unpack_bits,
)
from gspc.errors import CodecError, ValueRangeError


def _roundtrip(q):
    out = decode_matrix(encode_matrix(q))
    assert out.dtype == np.int64 and np.array_equal(out, q)


def test_bit_length():
    x = np.array([0, 1, 2, 3, 4, 255, 256, 2**48 - 1, 2**48])
    assert bit_length(x).tolist() == [0, 1, 2, 2, 3, 8, 9, 48, 49]


@pytest.mark.parametrize("m", [1, 2, 3, 63, 64, 65, 1000])
def test_matrix_roundtrip_sizes(m):
    rng = np.random.default_rng(m)
    _roundtrip(rng.integers(-5, 6, size=(m, 3)))


def test_matrix_roundtrip_mixed_channels():
    rng = np.random.default_rng(0)
    m = 5000
    walk = np.cumsum(rng.integers(-3, 4, m))
    q = np.stack(
        [
            walk,
            walk + rng.integers(-1, 2, m),
            np.zeros(m, int),
            rng.integers(0, 2, m),
            rng.integers(-(10**5), 10**5, m),
        ],
        axis=1,
    )
    _roundtrip(q)


def test_models_wider_than_the_payload_warrants_are_refused_by_both_sides():
    # Uniform 21-bit values in few rows: each bucket's window spans 2^21 symbols, far more table entries than
    # the payload may ask for (gspc/limits.py): the encoder refuses as a too-small lambda.
    q = np.random.default_rng(3).integers(-(2**20), 2**20, (5000, 1))
    with pytest.raises(ValueRangeError, match="larger lambda"):
        encode_matrix(q)


def test_context_pays_on_smooth_data():
    rng = np.random.default_rng(1)
    walk = np.cumsum(rng.integers(-2, 3, 20000))[:, None]
    iid = rng.permutation(walk[:, 0])[:, None]
    assert len(encode_matrix(walk)) < 0.6 * len(encode_matrix(iid))


def test_models_are_integer_tables():
    rng = np.random.default_rng(2)
    for sym in [rng.integers(0, 3, 100), np.rint(rng.laplace(0, 40, 3000)).astype(int)]:
        spec, _ = fit_model(sym)
        assert all(isinstance(v, int) for v in spec)
        w = model_weights(spec)
        assert (w == np.floor(w)).all() and (w >= 0).all()


def test_raw_bits_roundtrip():
    rng = np.random.default_rng(3)
    v = rng.integers(0, 2**47, 500).astype(np.uint64)
    lengths = bit_length(v.astype(np.int64))
    assert np.array_equal(unpack_bits(pack_bits(v, lengths), lengths), v)


def test_corrupt_payload_raises_codec_error():
    payload = encode_matrix(np.arange(100)[:, None])
    with pytest.raises(CodecError):
        decode_matrix(payload[:-7])


def _coder_symbol_at(model, quantile: int) -> int:
    # A one-symbol ANS stream whose state has low 24 bits = quantile decodes the symbol whose
    # cumulative interval [cdf[s], cdf[s+1]) holds it: this reads the coder's own fixed-point table.
    dec = constriction.stream.stack.AnsCoder(np.array([quantile, 1], dtype=np.uint32))
    return int(dec.decode(model, 1)[0])


@pytest.mark.parametrize("seed", range(4))
def test_coder_uses_exactly_our_integer_table(seed):
    rng = np.random.default_rng(seed)
    sym = np.rint(rng.laplace(0, [0.3, 3, 30, 300][seed], 2000)).astype(np.int64)
    for spec in [fit_model(sym)[0], [2, -40, 25, 3, seed * 7, seed * 5], [3, 5, 9, 0, 1, 1023, 0, 7]]:
        f = fixed_point_table(spec)
        assert f.sum() == 1 << PRECISION and (f >= 1).all()
        cdf = np.concatenate([[0], np.cumsum(f)])
        model = _categorical(spec)
        picks = np.unique(np.r_[0, 1, 2, np.argsort(f)[:5], np.argsort(f)[-5:], f.size - 1])
        picks = picks[picks < f.size]
        for i in picks:
            assert _coder_symbol_at(model, int(cdf[i])) == i
            assert _coder_symbol_at(model, int(cdf[i + 1] - 1)) == i


def test_symbols_beyond_the_limit_are_refused():
    q = np.zeros((10, 2), np.int64)
    q[3, 1] = SYMBOL_LIMIT + 1
    with pytest.raises(CodecError, match="beyond"):
        encode_matrix(q)
    q[3, 1] = -SYMBOL_LIMIT
    _roundtrip(q)
    with pytest.raises(CodecError, match="integer matrix"):
        encode_matrix(q.astype(np.float64))


def test_prediction_needing_too_wide_a_window_is_not_chosen(monkeypatch):
    # Channel 1 repeats channel 0 except where they swap +-L: predicting from channel 0 (mode 2) would be
    # cheapest but needs residuals of +-2L, a window wider than a model may have; mode 0 codes it. (Its
    # tables exceed what so small a payload may build, gspc/limits.py: lifted here to test the modes alone.)
    monkeypatch.setattr(entropy, "max_model_entries", lambda payload_bytes: 1 << 40)
    rng = np.random.default_rng(1)
    a = np.where(rng.uniform(size=4000) < 0.5, SYMBOL_LIMIT, -SYMBOL_LIMIT)
    b = a.copy()
    b[::50] = -b[::50]
    q = np.stack([a, b], axis=1).astype(np.int32)
    out = decode_matrix(encode_matrix(q))
    assert np.array_equal(out, q)


def test_bits_packed_in_blocks_are_the_bits_packed_at_once(monkeypatch):
    rng = np.random.default_rng(4)
    v = rng.integers(0, 2**40, 300).astype(np.uint64) >> rng.integers(0, 41, 300).astype(np.uint64)
    lengths = bit_length(v.astype(np.int64))  # zero lengths included
    whole = pack_bits(v, lengths)
    monkeypatch.setattr(entropy, "BITS_BLOCK", 7)
    assert pack_bits(v, lengths) == whole
    assert np.array_equal(unpack_bits(whole, lengths), v)


def _cross_entropy_bits(counts: np.ndarray, w: np.ndarray) -> float:
    p = w / w.sum()
    nz = counts > 0
    return float(-(counts[nz] * np.log2(p[nz])).sum())


def _reference_fit(sym: np.ndarray) -> tuple[list[int], float]:
    """fit_model as first written, one context at a time: what fit_models must reproduce exactly."""
    if sym.size == 0:
        return [0], 0.0
    lo, hi = int(sym.min()), int(sym.max())
    if lo == hi:
        return [1, lo], 16.0
    n = sym.size
    c = int(np.sort(sym)[n // 2])
    r = np.abs(sym - c)
    n0, s = int((r == 0).sum()), float(r.sum())
    th, bo = entropy.THETAS[:, None], entropy.BOOSTS[None, :] / 8.0
    with np.errstate(divide="ignore", invalid="ignore"):
        z = bo + 2.0 * th / (1.0 - th)
        cost = (
            n * np.log2(z)
            - n0 * np.log2(bo)
            - np.where(th > 0, s * np.log2(np.where(th > 0, th, 1)), -np.inf)
        )
    cost[~np.isfinite(cost)] = np.inf
    u, b = np.unravel_index(int(np.argmin(cost)), cost.shape)
    geo = [2, lo, hi, c, int(u), int(b)]
    if hi - lo >= entropy._EMPIRICAL_MAX_WINDOW:
        return geo, float(cost[u, b]) + 64
    counts = np.bincount(sym - lo, minlength=hi - lo + 1)
    geo_bits = _cross_entropy_bits(counts, model_weights(geo)) + 64
    w = np.where(counts > 0, np.maximum(counts * entropy._EMPIRICAL_SCALE // counts.max(), 1), 0)
    table_bits = 8.0 * float(np.where(w < 128, 1, np.where(w < 256, 2, 3)).sum()) + 32
    emp_bits = _cross_entropy_bits(counts, w.astype(np.float64)) + table_bits
    return ([3, lo, hi, *(int(x) for x in w)], emp_bits) if emp_bits < geo_bits else (geo, geo_bits)


@pytest.mark.parametrize("seed", range(6))
def test_fit_models_is_fit_model_per_context_exactly(seed):
    # Contexts empty, constant, narrow (tables), wide (geometric only), negative and skewed, as the encoder's
    # buckets are: the same specs and the same float costs, bit for bit.
    rng = np.random.default_rng(seed)
    parts = [
        rng.geometric(0.3, 500) - 3,
        np.full(40, -7),
        rng.integers(-5000, 5000, 300),
        np.rint(rng.laplace(0, 2, 2000)).astype(np.int64),
        np.array([SYMBOL_LIMIT, -SYMBOL_LIMIT, 0]),
        rng.integers(0, 2, 7),
    ]
    ctx_of = [0, 2, 3, 5, 7, 8]  # contexts 1, 4, 6 stay empty
    sym = np.concatenate(parts).astype(np.int64)
    ctx = np.concatenate([np.full(p.size, c) for p, c in zip(parts, ctx_of)])
    order = rng.permutation(sym.size)
    sym, ctx = sym[order], ctx[order]
    specs, bits = fit_models(sym, ctx, 9)
    for k in range(9):
        assert (specs[k], bits[k]) == _reference_fit(sym[ctx == k]), k
    assert fit_model(sym[ctx == 3]) == _reference_fit(sym[ctx == 3])
    assert fit_models(np.zeros(0, np.int64), np.zeros(0, np.int64), 3) == ([[0], [0], [0]], [0.0, 0.0, 0.0])


def test_compiled_sums_are_numpys_sums():
    # The compiled fit's cross-entropies are NumPy's bit for bit only if its sums add in NumPy's order:
    # runs up to 128 in eight interleaved sums, longer ones split in two (lengths about the split points).
    rng = np.random.default_rng(7)
    for n in [*range(4, 40), 127, 128, 129, 135, 136, 255, 256, 257, 300, 511, 1000, 4099]:
        a = rng.standard_normal(n) * 10.0 ** rng.integers(-6, 6, n)
        assert fit_cpu._pairwise_sum(a, 0, n) == a.sum(), n
        assert fit_cpu._pairwise_sum(a, 3, n - 3) == a[3:].sum(), n


def test_bit_length_paths_agree():
    rng = np.random.default_rng(0)
    small = rng.integers(0, 1 << 53, 1000)
    big = np.concatenate([small, [(1 << 63) - 1, 1 << 53, (1 << 53) - 1]])
    assert np.array_equal(bit_length(big)[: small.size], bit_length(small))
    assert bit_length(big)[-3:].tolist() == [63, 54, 53]
    assert bit_length(np.array([(1 << 53) - 1])).tolist() == [53]


def test_fit_models_on_symbols_too_wide_to_pack():
    sym = np.array([2**58, -(2**58), 5, 7, -3, 2**58 - 1], dtype=np.int64)
    ctx = np.array([0, 0, 1, 1, 2, 0])
    specs, bits = fit_models(sym, ctx, 3)
    for k in range(3):
        assert (specs[k], bits[k]) == _reference_fit(sym[ctx == k]), k
