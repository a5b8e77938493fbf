import numpy as np
import pytest

from gspc.codec import positions as pos


def test_morton_roundtrip():
    rng = np.random.default_rng(0)
    v = rng.integers(0, 2**16, size=(1000, 3))
    assert np.array_equal(pos.morton_decode(pos.morton_encode(v, 16), 16), v)


@pytest.mark.parametrize("bits", [1, 8, 16, 17])
def test_positions_roundtrip(bits):
    rng = np.random.default_rng(bits)
    means = rng.normal(size=(3000, 3)) * [1, 10, 0.1]
    voxels, order, grid = pos.curve_order(means, bits)
    out = pos.decode_positions(pos.encode_positions(voxels, bits), bits, len(voxels))
    assert np.array_equal(out, voxels)
    codes = pos.morton_encode(out, bits)
    assert (np.diff(codes) >= 0).all()  # decoded order is the curve order
    err = np.abs(pos.dequantise(voxels, grid["lo"], grid["step"]) - means[order])
    assert (err <= np.asarray(grid["step"]) * 0.5 + 1e-6 * np.abs(means[order]).max()).all()


def test_degenerate_points():
    means = np.full((50, 3), 1e6)
    voxels, order, grid = pos.curve_order(means, 16)
    out = pos.decode_positions(pos.encode_positions(voxels, 16), 16, 50)
    assert np.array_equal(out, voxels)
    assert (pos.dequantise(out, grid["lo"], grid["step"]) == np.float32(1e6)).all()
