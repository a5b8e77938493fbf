import struct
from dataclasses import replace

import msgpack
import numpy as np
import pytest

from gspc.codec.residuals import (
    IMAGE_CODECS,
    ResidualParams,
    choose_gain,
    decode_residual,
    encode_residual,
    plan_residual_rates,
    quality_for_distance,
)
from gspc.errors import CodecError, InputError
from gspc.format.container import Chunk
from gspc.format.side_chunk import read_side_views
from gspc.format.view_records import CameraRecord, ResidualRecord, ViewRecord

DISTANCES = {"jxl": 1.0, "webp": 2.0, "avif": 2.0}  # WebP / AVIF: quality 80


def camera(height: int, width: int) -> CameraRecord:
    return CameraRecord(width, height, struct.pack("<4f", width, width, width / 2, height / 2), bytes(48))


def _residual(seed=0, h=48, w=40, amp=0.05):
    """A smooth signed residual with some edges, like a render error."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] / 8.0
    base = np.sin(yy)[..., None] * np.cos(xx)[..., None] * np.array([1.0, 0.6, -0.4])
    return (amp * (base + 0.2 * rng.standard_normal((h, w, 3)))).astype(np.float32)


def _psnr(a, b):
    return 10 * np.log10(1.0 / np.mean((a - b) ** 2))


@pytest.mark.parametrize("codec", sorted(IMAGE_CODECS))
def test_round_trip_each_codec(codec):
    r = _residual()
    payload, meta = encode_residual(r, ResidualParams(codec=codec, distance=DISTANCES[codec]))
    # The record travels as msgpack in a 1.0 file's header: it reads back equal.
    stored = msgpack.unpackb(msgpack.packb(meta.to_dict()))
    assert ResidualRecord.from_dict(stored, camera(*r.shape[:2])) == meta
    out = decode_residual(payload, meta)
    assert out.shape == r.shape and out.dtype == np.float32
    # Far better than sending nothing (PSNR of a zero residual) and deterministic.
    assert _psnr(out, r) > _psnr(np.zeros_like(r), r) + 5
    assert np.array_equal(out, decode_residual(payload, meta))


def test_jxl_16_bit_round_trip():
    r = _residual()
    p16, m16 = encode_residual(r, ResidualParams(codec="jxl", distance=0.5, bits=16))
    assert m16.bits == 16 and m16.offset == 32768
    assert _psnr(decode_residual(p16, m16), r) > _psnr(np.zeros_like(r), r) + 10


def test_webp_refuses_16_bit():
    with pytest.raises(InputError):
        encode_residual(_residual(), ResidualParams(codec="webp", bits=16))


def test_gain_maps_percentile_to_range_and_is_capped():
    r = _residual(amp=0.1)
    g = choose_gain(r, 8, 100.0)
    assert np.isclose(np.abs(r).max() * g, 127, rtol=1e-5)
    assert choose_gain(np.zeros((4, 4, 3), np.float32), 8, 99.9, max_gain=300.0) == 300.0


def test_zero_residual_and_quiet_tiles():
    z = np.zeros((32, 32, 3), np.float32)
    payload, meta = encode_residual(z)
    # JPEG XL may leave +-1 level of ringing on a flat image: 1 / max_gain.
    assert np.abs(decode_residual(payload, meta)).max() <= 1.0 / meta.gain + 1e-9
    r = _residual(h=64, w=64)
    r[:32] *= 1e-3  # top half negligible
    _, meta = encode_residual(r, ResidualParams(tile=32, zero_rms=1e-3))
    assert meta.zeroed_tiles == 2


def test_bad_input_and_payload():
    with pytest.raises(InputError):
        encode_residual(np.zeros((8, 8), np.float32))
    with pytest.raises(CodecError):
        encode_residual(_residual(), ResidualParams(codec="nope"))
    payload, meta = encode_residual(_residual())
    with pytest.raises(CodecError):
        decode_residual(payload[: len(payload) // 3], meta)
    with pytest.raises(CodecError, match="expected 10x10"):
        decode_residual(payload, replace(meta, full_shape=(10, 10)))
    with pytest.raises(CodecError, match="declares"):  # read from the image header before decoding
        view = ViewRecord(camera(10, 10), replace(meta, full_shape=(10, 10)))
        read_side_views((view,), [Chunk("RESI", payload)], 1000)


def test_plan_rates_skips_quiet_views_and_refines_loud_ones():
    rs = [_residual(amp=a, seed=i) for i, a in enumerate([0.0, 0.02, 0.05, 0.2])]
    d = plan_residual_rates(rs, 2.0)
    assert d[0] is None
    assert d[1] > d[2] > d[3]
    assert all(1.0 <= v <= 4.0 for v in d[1:])
    assert plan_residual_rates([np.zeros((4, 4, 3), np.float32)], 2.0) == [None]


def test_reduced_resolution_round_trip():
    from gspc.codec.residuals import decode_residual, downsample, encode_residual, upsample

    y, x = np.mgrid[0:37, 0:50]
    wave = 0.05 * np.sin(x / 9.0) * np.cos(y / 7.0)
    smooth = np.stack([wave, -wave, 0.5 * wave], axis=2).astype(np.float32)
    for s in (2, 3):
        small = downsample(smooth, s)
        assert small.shape == (-(-37 // s), -(-50 // s), 3)
        back = upsample(small, s, 37, 50)
        assert back.shape == smooth.shape
        # A smooth field survives the box/bilinear pair far better than it is large.
        assert np.abs(back - smooth).mean() < 0.2 * np.abs(smooth).mean()
        payload, meta = encode_residual(smooth, ResidualParams(distance=1.0, scale=s))
        assert meta.scale == s and meta.full_shape == (37, 50) and meta.shape == (-(-37 // s), -(-50 // s))
        assert decode_residual(payload, meta).shape == (37, 50, 3)
    # Constant images are reproduced exactly by both directions.
    c = np.full((9, 7, 3), 0.25, np.float32)
    assert np.allclose(upsample(downsample(c, 4), 4, 9, 7), 0.25)


@pytest.mark.parametrize("codec", sorted(IMAGE_CODECS))
def test_distance_means_coarser_for_every_codec(codec):
    r = _residual(h=64, w=64)
    fine, _ = encode_residual(r, ResidualParams(codec=codec, distance=1.0))
    coarse, _ = encode_residual(r, ResidualParams(codec=codec, distance=6.0))
    assert len(coarse) < len(fine)
    assert quality_for_distance(2.0) == 80.0 and quality_for_distance(20) == 0.0


def test_misspelt_residual_knob_is_refused():
    with pytest.raises(TypeError):
        ResidualParams(level=2.0)  # the knob is called distance
