"""The attribute codec's header section as a typed record (gspc/format/attribute_section.py): what the encoder
writes reads back equal, and every position field is bounded (spec 10.1) so hostile but finite values are
refused with one CodecError line instead of overflowing when positions are expanded."""

import warnings

import numpy as np
import pytest
import torch
from scenes import random_scene

from gspc.codec import positions as pos
from gspc.codec.attributes import decode_attributes
from gspc.encoder.coding import encode_attributes
from gspc.errors import CodecError, InputError
from gspc.format import container
from gspc.format.attribute_section import (
    MAX_CONTRACTED,
    MAX_COORDINATE,
    AttributeSection,
    Contraction,
    PositionGrid,
)
from gspc.pipeline import DecodeOptions, decode_bytes
from gspc.presets import QUALITY

HUGE = [1e20, 1e38, 1e100, 1e300, -1e20, -1e300]


@pytest.fixture(scope="module")
def sections() -> dict[int, tuple[AttributeSection, dict[str, bytes]]]:
    """A box grid (version 1) and a contracted one (version 2), with their payloads."""
    out = {}
    for far in (1.0, 400.0):  # a background 400x further out: a contracted grid
        enc = encode_attributes(random_scene(300, sh_degree=0, far=far), QUALITY["low"].attributes)
        out[enc.section.version] = (enc.section, enc.chunks)
    assert set(out) == {1, 2}
    return out


def test_the_encoders_section_reads_back_equal(sections):
    for section, _ in sections.values():
        assert AttributeSection.from_dict(section.to_dict()) == section


def _position_changes(meta: dict) -> list[tuple[str, dict]]:
    """Every position field set to each hostile value, one field (or coordinate) at a time."""
    grid = meta["position"]
    keys = ["lo", "step"] + (["centre", "radius"] if "radius" in grid else [])
    changes = []
    for key in keys:
        for v in HUGE:
            if isinstance(grid[key], list):
                for a in range(3):
                    value = list(grid[key])
                    value[a] = v
                    changes.append((key, {**grid, key: value}))
            else:
                changes.append((key, {**grid, key: v}))
    return changes


@pytest.mark.parametrize("version", [1, 2])
def test_huge_position_fields_are_one_codec_error(sections, version):
    section, chunks = sections[version]
    meta = section.to_dict()
    for key, grid in _position_changes(meta):
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no numpy overflow warning before the refusal
            with pytest.raises(CodecError) as err:
                AttributeSection.from_dict({**meta, "position": grid})
        message = str(err.value)
        assert "\n" not in message and "position" in message, (key, message)


@pytest.mark.parametrize("version", [1, 2])
def test_a_file_with_huge_position_fields_is_refused_by_decode(sections, version):
    """Through the whole decoder (the bug: every Gaussian decoded onto one point, exit 0)."""
    section, chunks = sections[version]
    meta = section.to_dict()
    side = {"background": [0.0, 0.0, 0.0], "restorer": "none"}
    for _, grid in _position_changes(meta)[::5]:
        data = container.pack(
            {"attributes": {**meta, "position": grid}, "side_info": side},
            [container.Chunk(t, p) for t, p in chunks.items()],
        )
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(CodecError, match="position"):
                decode_bytes(data, DecodeOptions(restore=False, refine=False))


def test_grids_at_the_bounds_decode_to_finite_positions():
    """The bounds' reason: at every corner of the largest grids allowed, each coordinate is a finite
    binary32 and no step of the expansion overflowed."""
    bits = pos.CONTRACTED_MAX_BITS
    step = 2 * MAX_CONTRACTED / ((1 << bits) - 1) * (1 - 1e-15)
    top = (1 << bits) - 1
    corners = np.array([[i, j, k] for i in (0, top) for j in (0, top) for k in (0, top)], np.int64)
    box_corners = np.minimum(corners, (1 << pos.MAX_BITS) - 1)
    contracted = PositionGrid(
        bits, (-MAX_CONTRACTED,) * 3, (step,) * 3, Contraction((MAX_COORDINATE,) * 3, MAX_COORDINATE)
    )
    box_step = 2 * MAX_COORDINATE / ((1 << pos.MAX_BITS) - 1) * (1 - 1e-15)
    box = PositionGrid(pos.MAX_BITS, (-MAX_COORDINATE,) * 3, (box_step,) * 3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isfinite(pos.positions(corners, contracted)).all()
        assert np.isfinite(pos.positions(box_corners, box)).all()


def test_a_grid_past_its_bound_is_refused():
    with pytest.raises(CodecError, match="beyond"):
        PositionGrid(21, (-MAX_CONTRACTED,) * 3, (1.0,) * 3, Contraction((0.0,) * 3, 1.0))
    with pytest.raises(CodecError, match="position.radius"):
        PositionGrid(11, (0.0,) * 3, (1e-3,) * 3, Contraction((0.0,) * 3, 2 * MAX_COORDINATE))
    with pytest.raises(CodecError, match="position.lo"):
        PositionGrid(11, (0.0, 0.0, 2 * MAX_COORDINATE), (1.0,) * 3)


def test_a_scene_beyond_the_coordinate_bound_is_an_input_error():
    scene = random_scene(300, sh_degree=0)
    with torch.no_grad():
        scene.means[0] = 1e30
    with pytest.raises(InputError, match="cannot be coded"):
        encode_attributes(scene, QUALITY["low"].attributes)


def test_a_grid_spanning_twice_its_points_is_kept_inside_the_bound():
    """Points out to 2^27 radii: the grid's bits would let its far corner pass +32 in grid space, so the
    encoder makes that axis's step finer; the positions still decode inside their cells."""
    g = np.random.default_rng(5)
    x = g.normal(size=(2000, 3))
    x[:50] = g.normal(size=(50, 3)) * 1e8
    voxels, order, grid = pos.curve_order(x, 16)
    top = np.asarray(grid.lo) + ((1 << grid.bits) - 1) * np.asarray(grid.step)
    assert grid.is_contracted and (np.abs(top) <= MAX_CONTRACTED).all()
    dec = pos.positions(voxels, grid)
    assert (np.abs(dec - x[order]) <= pos.cell_half_widths(dec, grid) * 1.0001 + 1e-6).all()
    assert np.array_equal(pos.decode_positions(pos.encode_positions(voxels, grid), grid, len(x)), voxels)


def test_decode_uses_the_typed_section(sections):
    section, chunks = sections[2]
    a = decode_attributes(chunks, section)
    b = decode_attributes(chunks, AttributeSection.from_dict(section.to_dict()))
    assert torch.equal(a.means, b.means)
