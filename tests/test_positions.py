from dataclasses import replace

import numpy as np
import pytest
from scenes import far_scene, far_sizes, unbounded

from gspc.codec import positions as pos
from gspc.format.attribute_section import AttributeSection


def test_morton_roundtrip():
    rng = np.random.default_rng(0)
    v = rng.integers(0, 2**16, size=(1000, 3))
    assert np.array_equal(pos.morton_decode(pos.morton_encode(v, 16), 16), v)


@pytest.mark.parametrize("bits", [1, 8, 16, 17])
def test_positions_roundtrip(bits):
    rng = np.random.default_rng(bits)
    means = rng.uniform(-1, 1, size=(3000, 3)) * [1, 10, 0.1]
    voxels, order, grid = pos.curve_order(means, bits)
    assert not grid.is_contracted  # a bounded box: the plain grid
    assert bits <= grid.bits <= pos.MAX_BITS  # the long axis takes the bits it needs, up to the format's
    out = pos.decode_positions(pos.encode_positions(voxels, grid), grid, len(voxels))
    assert np.array_equal(out, voxels)
    codes = pos.morton_encode(out, grid.bits)
    assert (np.diff(codes) >= 0).all()  # decoded order is the curve order
    err = np.abs(pos.dequantise(voxels, grid.lo, grid.step) - means[order])
    assert (err <= np.asarray(grid.step) * 0.5 + 1e-6 * np.abs(means[order]).max()).all()


@pytest.mark.parametrize("scene", ["box", "unbounded"])
def test_fractional_precision_lies_between_whole_bits(scene):
    """A precision between whole bits (the rate's, gspc/encoder/params.py) is a step between theirs on a grid
    of the bits above it: every voxel fits, decodes within half a step, and whole precisions give the grids
    they always did."""
    rng = np.random.default_rng(3)
    means = rng.uniform(-1, 1, size=(3000, 3)) * [1, 10, 0.1] if scene == "box" else unbounded()
    grids = {p: pos.curve_order(means, p) for p in (11.0, 11.4, 12.0)}
    if scene == "box":
        lo, hi = means.min(0), means.max(0)
        side = np.exp(np.log(hi - lo).mean()) / 2047  # cubic voxels, as many as 11 bits per axis make
        assert np.allclose(grids[11.0][2].step, side, rtol=1e-12, atol=0)
    voxels, order, grid = grids[11.4]
    assert 12 <= grid.bits <= grids[12.0][2].bits  # a contracted grid adds what its extent needs
    assert all(c < f < w for c, f, w in zip(grids[12.0][2].step, grid.step, grids[11.0][2].step))
    out = pos.decode_positions(pos.encode_positions(voxels, grid), grid, len(voxels))
    assert np.array_equal(out, voxels) and out.max() <= (1 << grid.bits) - 1
    if scene == "box":
        err = np.abs(pos.dequantise(voxels, grid.lo, grid.step) - means[order])
        assert (err <= np.asarray(grid.step) * 0.5 + 1e-6).all()


@pytest.mark.parametrize("aspect", [(1.0, 1.0, 1.0), (1.0, 2.9, 0.8), (1.0, 1000.0, 1.0), (1.0, 5.0, 0.0)])
def test_voxels_are_cubic_and_as_many_as_the_precision_gives(aspect):
    """Every axis the points spread along gets the same step, the voxel count over the bounds is what p bits
    per axis would give (a tall statue's voxels were 2.9 times longer than wide), the grid's bits hold the
    longest axis, and beyond MAX_BITS the voxels grow; a flat axis keeps step 1."""
    rng = np.random.default_rng(7)
    means = rng.uniform(0, 1, size=(5000, 3)) * aspect
    extent = means.max(0) - means.min(0)
    p = 11.0
    voxels, order, grid = pos.curve_order(means, p)
    spread = extent > 0
    steps = np.asarray(grid.step)
    assert np.allclose(steps[spread], steps[spread][0], rtol=1e-12) and (steps[~spread] == 1.0).all()
    cells = np.prod(extent[spread] / steps[spread])
    if grid.bits < pos.MAX_BITS:
        assert np.isclose(cells, (2.0**p - 1) ** spread.sum(), rtol=1e-9)
        assert (extent / steps).max() <= (1 << grid.bits) - 1 < 2 * (extent / steps).max() + 1
    else:  # 1000:1:1 at 11 bits needs 17.6 bits on its long axis: coarser voxels, within the format
        assert cells < (2.0**p - 1) ** 3 and (extent / steps).max() <= (1 << pos.MAX_BITS) - 1
    out = pos.decode_positions(pos.encode_positions(voxels, grid), grid, len(voxels))
    assert np.array_equal(out, voxels)
    err = np.abs(pos.dequantise(voxels, grid.lo, grid.step) - means[order])
    assert (err <= steps * 0.5 + 1e-7 * np.abs(means).max()).all()  # and float32's rounding


def test_degenerate_points():
    means = np.full((50, 3), 1e6)
    voxels, order, grid = pos.curve_order(means, 16)
    out = pos.decode_positions(pos.encode_positions(voxels, grid), grid, 50)
    assert np.array_equal(out, voxels)
    assert (pos.dequantise(out, grid.lo, grid.step) == np.float32(1e6)).all()


def test_contract_and_expand_are_inverse_and_identity_near_the_centre():
    x = unbounded()
    centre, radius = pos.region_of_interest(x)
    y = pos.contract(x, centre, radius)
    back = pos.expand(y, centre, radius)
    assert np.allclose(back, x, rtol=1e-6, atol=1e-5)
    u = np.linalg.norm(x - centre, axis=1) / radius
    near = u <= 2.0
    assert np.allclose(y[near] * radius + centre, x[near])  # the first two radii are not contracted
    # Beyond, each octave of distance is one unit of grid radius (1 + log2 u, piecewise linear).
    rho = np.linalg.norm(y, axis=1)
    assert np.all(rho[~near] < 1 + np.log2(u[~near]) + 1e-9) and np.all(
        rho[~near] >= 1 + np.log2(u[~near]) - 0.09
    )


@pytest.mark.parametrize("bits", [8, 11, 14, 16])
def test_far_gaussians_keep_the_foreground_voxel_size(bits):
    x = unbounded()
    obj = x[:4000]
    _, _, plain = pos.curve_order(obj, bits)
    voxels, order, grid = pos.curve_order(x, bits)
    assert grid.is_contracted and grid.bits > bits
    out = pos.decode_positions(pos.encode_positions(voxels, grid), grid, len(voxels))
    assert np.array_equal(out, voxels)
    dec = pos.positions(voxels, grid)
    err = np.abs(dec - x[order])
    is_obj = order < 4000
    # The object keeps the voxel size it has alone (the grid is shifted, so half a step either way).
    assert (err[is_obj] <= np.asarray(plain.step) * 0.5 * 1.0001 + 1e-6).all()
    # Every Gaussian lies inside the cell the refinement keeps it in.
    assert (err <= pos.cell_half_widths(dec, grid) * 1.0001 + 1e-6).all()
    # Far ones err in proportion to their distance (about constant angular error seen from the centre).
    dist = np.linalg.norm(x[order] - grid.contraction.centre, axis=1)
    rel = err.max(1)[~is_obj] / dist[~is_obj]
    assert rel.max() < 2.0 * max(grid.step) * grid.contraction.radius / (0.5 * grid.contraction.radius)


@pytest.mark.parametrize("bits", [8, 11, 14])
def test_large_far_gaussians_form_a_far_set_on_a_coarser_grid(bits):
    x = unbounded()
    centre = x[:4000].mean(0)
    plain_v, plain_order, plain_grid = pos.curve_order(x, bits)  # no sizes: no far set
    assert plain_grid.far is None
    voxels, order, grid = pos.curve_order(x, bits, far_sizes(x, centre, 0.05))
    near, shift = grid.split(len(x))
    assert 1 <= shift <= pos.FAR_MAX_SHIFT and 0 < near < len(x)
    # Far voxels lie on the coarse grid; the payload round-trips and costs less than without a far set.
    assert not (voxels[near:] % (1 << shift)).any()
    payload = pos.encode_positions(voxels, grid)
    assert np.array_equal(pos.decode_positions(payload, grid, len(x)), voxels)
    assert len(payload) < len(pos.encode_positions(plain_v, plain_grid))
    # The near Gaussians are the same voxels, in the same order, as without a far set.
    far_rows = set(order[near:].tolist())
    keep = np.array([i not in far_rows for i in plain_order])
    assert np.array_equal(voxels[:near], plain_v[keep]) and np.array_equal(order[:near], plain_order[keep])
    # The far set holds only Gaussians beyond 2 R (the object is never coarsened), and every Gaussian
    # stays inside the cell refinement keeps it in.
    dec = pos.positions(voxels, grid)
    u = np.linalg.norm(x[order] - grid.contraction.centre, axis=1) / grid.contraction.radius
    assert (u[near:] > pos.IDENTITY_RADIUS).all()
    err = np.abs(dec - x[order])
    assert (err <= pos.cell_half_widths(dec, grid) * 1.0001 + 1e-6).all()


def test_small_far_gaussians_keep_the_fine_grid():
    # Beyond 2 R but no larger than the object's Gaussians: coarser voxels would be visible, so no far set.
    x = unbounded()
    _, _, grid = pos.curve_order(x, 11, np.full(len(x), 0.02))
    assert grid.is_contracted and grid.far is None


def test_far_set_payload_errors():
    x = unbounded()
    voxels, _, grid = pos.curve_order(x, 11, far_sizes(x, x[:4000].mean(0), 0.05))
    payload = pos.encode_positions(voxels, grid)
    import msgpack

    from gspc.errors import CodecError

    two = msgpack.packb(msgpack.unpackb(payload)[:2], use_bin_type=True)
    with pytest.raises(CodecError, match="4 msgpack bins"):
        pos.decode_positions(two, grid, len(x))
    with pytest.raises(CodecError, match="2 msgpack bins"):
        pos.decode_positions(payload, replace(grid, far=None), len(x))


def test_bit_length_is_exact_to_int64():
    from gspc.codec.entropy import bit_length

    x = np.array([0, 1, 2, 3, 2**52 - 1, 2**53 - 1, 2**53, 2**62, 2**63 - 1], np.int64)
    assert bit_length(x).tolist() == [0, 1, 2, 2, 52, 53, 54, 63, 63]


def test_an_unbounded_scene_round_trips_through_the_file(tmp_path):
    """A scene with far Gaussians through the file: codec version 2, positions within their cells."""
    from scenes import random_scene

    from gspc.format import container
    from gspc.io import read_scene, write_ply
    from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode

    scene = random_scene(400, sh_degree=0, seed=3)
    far = np.zeros((400, 3), np.float32)
    far[:20] = np.random.default_rng(3).normal(size=(20, 3)) * 200.0
    scene.means[:] = scene.means + __import__("torch").from_numpy(far)
    src, out, dec = tmp_path / "s.ply", tmp_path / "s.gspc", tmp_path / "d.ply"
    write_ply(scene, src)
    encode(src, out, opts=EncodeOptions(side_info=False, synth_views=4, keep_invisible=True, precision=False))
    meta = AttributeSection.from_dict(container.read(out).header["attributes"])
    assert meta.version == 2 and meta.position.is_contracted and container.read(out).version == (1, 4)
    decode(out, dec, DecodeOptions(refine=False, restore=False))
    got = read_scene(dec).means.numpy().astype(np.float64)
    ref = scene.means.numpy().astype(np.float64)
    # Match each decoded Gaussian to its source (curve order differs from input order) by nearest neighbour.
    d = np.sqrt(((got[:, None, :] - ref[None, :, :]) ** 2).sum(-1)).min(1)
    assert (d <= np.linalg.norm(pos.cell_half_widths(got, meta.position), axis=1) + 1e-5).all()


def test_far_set_header_is_checked():
    from gspc.encoder.coding import encode_attributes
    from gspc.errors import CodecError
    from gspc.format.attribute_section import FAR_VERSION
    from gspc.presets import QUALITY

    enc = encode_attributes(far_scene(), QUALITY["low"].attributes)
    meta = enc.section.to_dict()
    assert meta["version"] == FAR_VERSION
    assert AttributeSection.from_dict(meta) == enc.section
    grid, n = meta["position"], meta["n"]
    bad = [
        ({"far_count": n}, "far set"),
        ({"far_count": 0}, "far set"),
        ({"far_shift": grid["bits"]}, "far set"),
        ({"far_shift": 1.0}, "far_shift"),
    ]
    for change, message in bad:
        with pytest.raises(CodecError, match=message):
            AttributeSection.from_dict({**meta, "position": {**grid, **change}})
    without = {k: v for k, v in grid.items() if k != "far_shift"}
    with pytest.raises(CodecError, match="far set"):
        AttributeSection.from_dict({**meta, "position": without})
    with pytest.raises(CodecError, match="far set"):
        AttributeSection.from_dict({**meta, "version": 2})


def test_a_far_set_round_trips_through_the_file(tmp_path):
    """Large background Gaussians through gspc encode and decode: codec version 3, positions in their cells,
    the spec's second decoder agrees."""
    import spec_reader as sr

    from gspc.format import container
    from gspc.io import read_scene, write_ply
    from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode

    scene = far_scene()
    src, out, dec = tmp_path / "s.ply", tmp_path / "s.gspc", tmp_path / "d.ply"
    write_ply(scene, src)
    encode(src, out, opts=EncodeOptions(side_info=False, synth_views=4, keep_invisible=True, precision=False))
    meta = AttributeSection.from_dict(container.read(out).header["attributes"])
    assert meta.version == 3 and meta.position.far.count > 0
    from typer.testing import CliRunner

    from gspc.cli import app

    shown = CliRunner().invoke(app, ["info", str(out)], terminal_width=200).output
    assert f"a far set of {meta.position.far.count:,} Gaussians" in shown
    decode(out, dec, DecodeOptions(refine=False, restore=False))
    got = read_scene(dec).means.numpy()
    assert np.array_equal(sr.read_scene(out.read_bytes())[0]["means"], got)
    ref = scene.means.numpy().astype(np.float64)
    got = got.astype(np.float64)
    d = np.sqrt(((got[:, None, :] - ref[None, :, :]) ** 2).sum(-1)).min(1)
    assert (d <= np.linalg.norm(pos.cell_half_widths(got, meta.position), axis=1) + 1e-5).all()


def test_hostile_far_set_fields_and_payloads_are_codec_errors():
    """Every bad far_count, far_shift or POSN array of a version-3 file ends in CodecError, nothing else."""
    import msgpack

    from gspc.codec.attributes import decode_attributes
    from gspc.encoder.coding import encode_attributes
    from gspc.errors import CodecError
    from gspc.presets import QUALITY

    enc = encode_attributes(far_scene(), QUALITY["low"].attributes)
    meta, chunks = enc.section.to_dict(), enc.chunks
    grid = meta["position"]
    values = [-1, 0, meta["n"], meta["n"] + 1, 2**70, "x", None, 1.5, True, [1]]
    for key in ("far_count", "far_shift"):
        for value in values:
            with pytest.raises(CodecError):
                AttributeSection.from_dict({**meta, "position": {**grid, key: value}})
    parts = msgpack.unpackb(chunks["POSN"])
    for bad in ([*parts, b""], parts[:3], [parts[0], parts[1], parts[3], parts[2]], [*parts[:3], 7], b"\x00"):
        with pytest.raises(CodecError):
            decode_attributes({**chunks, "POSN": msgpack.packb(bad, use_bin_type=True)}, enc.section)
