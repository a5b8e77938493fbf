"""Axis conventions: the sixteen names, and moving a scene between them without changing what it renders."""

import itertools

import numpy as np
import pytest
import torch
from scenes import random_scene

from gspc.errors import InputError
from gspc.format.coordinates import CONVENTIONS
from gspc.io.coordinates import GLTF, OPENCV, axes, check_convention, is_right_handed, oriented, transform
from gspc.render.sh import sh_basis


def _rotations(quats: torch.Tensor) -> torch.Tensor:
    w, x, y, z = (quats / quats.norm(dim=1, keepdim=True)).double().unbind(1)
    return torch.stack(
        [
            torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def _colours(scene, dirs: torch.Tensor) -> torch.Tensor:
    """The SH sum along ``dirs`` (before the renderer's clamp, which could hide a wrong sign)."""
    coeffs = torch.cat([scene.sh_dc[:, None], scene.sh_rest], dim=1).double()
    return (sh_basis(dirs, scene.sh_degree)[:, :, None] * coeffs).sum(1)


def _covariances(scene) -> torch.Tensor:
    r = _rotations(scene.quats)
    s = torch.diag_embed(scene.log_scales.double().exp() ** 2)
    return r @ s @ r.transpose(1, 2)


def test_names_and_handedness():
    assert len(CONVENTIONS) == 16 and len(set(CONVENTIONS)) == 16
    # SPZ's numbering: RUB is 4, RDF 6, LUF 7 (Niantic's load-spz.h).
    assert [CONVENTIONS.index(n) + 1 for n in ("RUB", "RDF", "LUF", "RFU")] == [4, 6, 7, 12]
    assert all(is_right_handed(n) for n in ("RUB", "RDF", "LUF", "RFU", "LDB"))
    assert not any(is_right_handed(n) for n in ("LUB", "RUF", "RDB", "LDF"))
    np.testing.assert_array_equal(transform("RDF", "RUB"), np.diag([1, -1, -1]))
    np.testing.assert_array_equal(transform(OPENCV, GLTF), np.diag([-1, -1, 1]))  # 180 degrees about z
    np.testing.assert_array_equal(axes("RFU") @ [0, 0, 1], [0, 1, 0])  # its z is up
    with pytest.raises(InputError, match="'XYZ' is not a coordinate convention"):
        check_convention("XYZ")


PAIRS = [("RUB", "RDF"), ("RDF", "LUF"), ("RUB", "LUB"), ("RFU", "RDF"), ("LBD", "RUF"), ("RDF", "RDF")]


@pytest.mark.parametrize("src,dst", PAIRS)
def test_a_moved_scene_renders_the_same(src, dst):
    """Means move by A, covariances by A . A^T, and the colour seen along A d is the colour seen along d."""
    scene = random_scene(50, sh_degree=3, seed=4)
    scene.coordinates = src
    moved = oriented(scene, dst)
    a = torch.from_numpy(transform(src, dst)).double()
    assert moved.coordinates == dst
    torch.testing.assert_close(moved.means.double(), scene.means.double() @ a.T)
    torch.testing.assert_close(_covariances(moved), a @ _covariances(scene) @ a.T)
    dirs = torch.nn.functional.normalize(torch.randn(50, 3, dtype=torch.float64), dim=1)
    before, after = _colours(scene, dirs), _colours(moved, dirs @ a.T)
    torch.testing.assert_close(after, before, atol=2e-6, rtol=0)
    torch.testing.assert_close(oriented(moved, src).sh_rest, scene.sh_rest, atol=2e-6, rtol=0)


def test_axis_flips_are_exact_and_every_pair_round_trips():
    scene = random_scene(20, sh_degree=3, seed=5)
    scene.coordinates = "RUB"
    flipped = oriented(scene, "RDF")
    assert torch.equal(flipped.means[:, 1], -scene.means[:, 1])  # sign changes only, no rounding
    assert torch.equal(flipped.sh_rest.abs(), scene.sh_rest.abs())
    for src, dst in itertools.product(("RUB", "LDF", "RFU", "LBD"), repeat=2):
        scene.coordinates = src
        back = oriented(oriented(scene, dst), src)
        torch.testing.assert_close(back.means, scene.means)
        torch.testing.assert_close(back.sh_rest, scene.sh_rest, atol=2e-6, rtol=0)


def test_an_unstated_scene_is_taken_as_opencv_and_stays_unstated():
    scene = random_scene(10, sh_degree=1, seed=6)
    same = oriented(scene, OPENCV)
    assert same.coordinates is None and same.means is scene.means
    gltf = oriented(scene, GLTF)
    assert gltf.coordinates is None
    assert torch.equal(gltf.means, scene.means * torch.tensor([-1.0, -1.0, 1.0]))


def test_normals_move_with_the_axes():
    scene = random_scene(4, sh_degree=0, seed=7)
    scene.extra = {
        "nx": np.ones(4, np.float32),
        "ny": np.full(4, 2.0, np.float32),
        "nz": np.zeros(4, np.float32),
    }
    scene.coordinates = "RDF"
    moved = oriented(scene, "RUB")
    assert moved.extra["ny"].tolist() == [-2.0] * 4 and scene.extra["ny"].tolist() == [2.0] * 4
