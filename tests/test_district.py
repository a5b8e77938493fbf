"""The district builder (tools/make_district.py) and what it shares with the scale workload: SH rotation
(tools/sh_rotation.py), the normalised assets (tools/scale_assets.py) and the streamed PLY
(tools/ply_stream.py)."""

from __future__ import annotations

import hashlib
import json
import math

import make_district
import numpy as np
import pytest
import torch
from ply_stream import write_ply_parts
from scale_assets import (
    LEGO,
    Placement,
    axis_angle,
    load_asset,
    load_capture,
    normalise,
    quat_matrix,
    quat_mul,
)
from scenes import random_scene
from sh_rotation import rotate_sh_rest, sh_rest_rotation, sphere_directions

from gspc.cameras import Camera
from gspc.io import read_scene
from gspc.io.camera_files import load_cameras
from gspc.io.cameras_json import save_cameras_json
from gspc.io.ply import write_ply
from gspc.metrics import psnr
from gspc.render import render
from gspc.render.sh import sh_basis
from gspc.scene import make_scene
from gspc.views import look_at


def _rotation(seed: int) -> tuple[np.ndarray, np.ndarray]:
    g = np.random.default_rng(seed)
    axis = g.normal(size=3)
    return axis_angle(axis / np.linalg.norm(axis), g.uniform(0.3, 3.0))


def _lego_asset(every: int):
    if not LEGO.is_file():
        pytest.skip("examples/lego/point_cloud.ply is not in this checkout")
    lego = load_asset(LEGO)
    return lego.subset(np.arange(0, lego.n, every))


def test_turned_sh_shows_from_each_direction_what_it_showed_from_the_direction_turned_back():
    R, _ = _rotation(0)
    rest = np.random.default_rng(1).normal(size=(5, 15, 3))
    turned = rotate_sh_rest(rest, R, 3)
    d = torch.from_numpy(np.random.default_rng(2).normal(size=(40, 3)))
    d = d / d.norm(dim=1, keepdim=True)
    now = torch.einsum("dk,nkc->ndc", sh_basis(d, 3)[:, 1:], torch.from_numpy(turned))
    before = torch.einsum("dk,nkc->ndc", sh_basis(d @ torch.from_numpy(R), 3)[:, 1:], torch.from_numpy(rest))
    assert torch.allclose(now, before, atol=1e-12)
    M = sh_rest_rotation(R, 3)
    assert np.allclose(M @ M.T, np.eye(15), atol=1e-12)  # orthogonal, band by band
    assert np.allclose(sh_rest_rotation(np.eye(3), 3), np.eye(15), atol=1e-12)
    assert np.allclose(np.linalg.norm(sphere_directions(7), axis=1), 1.0)


def test_a_turned_copy_renders_as_the_original_from_the_camera_turned_with_it():
    scene = random_scene(300, sh_degree=3, seed=4, rest_std=0.3)
    asset = normalise(scene, "random")
    R, q = _rotation(5)
    scale, offset = 1.7, np.array([3.0, -2.0, 0.5])
    original = make_scene(**asset.placed(Placement(np.eye(3), np.array([1.0, 0, 0, 0]), np.zeros(3))))
    moved = make_scene(**asset.placed(Placement(R, q, offset, scale)))
    K = np.array([[110.0, 0.0, 64.0], [0.0, 110.0, 48.0], [0.0, 0.0, 1.0]])
    w2c = look_at(np.array([1.6, -1.1, 0.7]), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    # The same view of the moved copy: world x' = s R x + t, so the camera turns by R and its centre moves.
    R_cam = w2c[:3, :3] @ R.T
    centre = scale * R @ (-w2c[:3, :3].T @ w2c[:3, 3]) + offset
    w2c_moved = np.eye(4)
    w2c_moved[:3, :3], w2c_moved[:3, 3] = R_cam, -R_cam @ centre
    before = render(original, Camera(w2c, K, 128, 96)).image
    after = render(moved, Camera(w2c_moved, K, 128, 96)).image
    assert float(before.std()) > 0.05  # something to compare
    assert float(psnr(before, after)) > 50.0
    # Without turning the SH rest, the view-dependent colour would not follow: the test can tell.
    unturned = make_scene(**{**asset.placed(Placement(R, q, offset, scale)), "sh_rest": asset.sh_rest})
    assert float(psnr(before, render(unturned, Camera(w2c_moved, K, 128, 96)).image)) < 40.0


def test_streamed_parts_are_the_bytes_write_ply_writes(tmp_path):
    scene = random_scene(300, sh_degree=3, seed=6)
    write_ply(scene, tmp_path / "whole.ply")
    parts = [scene.subset(np.arange(0, 120)), scene.subset(np.arange(120, 300))]
    write_ply_parts(tmp_path / "parts.ply", 300, 3, parts)
    assert (tmp_path / "parts.ply").read_bytes() == (tmp_path / "whole.ply").read_bytes()
    with pytest.raises(ValueError, match="header says"):
        write_ply_parts(tmp_path / "short.ply", 301, 3, parts)
    assert not (tmp_path / "short.ply").exists() and len(list(tmp_path.iterdir())) == 2  # no debris


def test_a_tiny_district_of_the_lego_reads_back_with_distinct_copies(tmp_path):
    lego = _lego_asset(every=25)
    doc = make_district.make_district([lego], 4000, tmp_path / "d", seed=3, views=6, size=(80, 60))
    scene = read_scene(tmp_path / "d" / "point_cloud.ply")
    assert scene.num_gaussians == doc["gaussians"] and scene.sh_degree == 3
    assert all(bool(torch.isfinite(t).all()) for t in scene.tensors().values())
    copies = doc["copies"]
    assert len(copies) >= 5 and sum(c["gaussians"] for c in copies) >= 4000
    assert doc["gaussians"] == sum(c["gaussians"] for c in copies) + sum(
        b["gaussians"] for b in doc["backdrop"]
    )
    rows = [scene.means[c["first_row"] : c["first_row"] + c["gaussians"]].double().numpy() for c in copies]
    dcs = [scene.sh_dc[c["first_row"] : c["first_row"] + c["gaussians"]].double().numpy() for c in copies]
    for i in range(len(rows)):
        for j in range(i):  # no two copies alike in shape (centred), place or colour
            assert not np.allclose(rows[i] - rows[i].mean(0), rows[j] - rows[j].mean(0), atol=1e-3)
            assert not np.allclose(rows[i].mean(0), rows[j].mean(0), atol=1e-2)
            assert not np.allclose(dcs[i], dcs[j], atol=1e-3)
    # scene.json's transform rebuilds a copy's rows
    c = copies[-1]
    R = quat_matrix(np.array(c["quat_wxyz"]))
    assert np.allclose(c["scale"] * lego.means @ R.T + c["offset"], rows[-1], atol=1e-4)
    cams = load_cameras(tmp_path / "d" / "cameras.json")
    assert len(cams) == 6 and {c.width for c in cams} == {80}
    assert doc["visible_share"]["copies"] > 0.9
    saved = json.loads((tmp_path / "d" / "scene.json").read_text())
    assert saved["gaussians"] == doc["gaussians"] and saved["views"] == {
        "street": 4,
        "aerial": 2,
        "size": [80, 60],
    }


def test_the_same_seed_writes_the_same_district_and_another_seed_another(tmp_path):
    lego = _lego_asset(every=50)

    def digest(folder: str, seed: int) -> str:
        make_district.make_district([lego], 1500, tmp_path / folder, seed=seed, views=3, backdrop=False)
        return hashlib.sha256((tmp_path / folder / "point_cloud.ply").read_bytes()).hexdigest()

    assert digest("a", 0) == digest("b", 0) != digest("c", 1)


def test_the_statues_stand_upright_on_their_pedestals(shared_data):
    # The SOG files are y-down: standing upright puts the dark pedestal at the bottom, the pale figure above.
    statue = load_asset(shared_data / "statues" / "angel.sog")
    z = statue.means[:, 2]
    brightness = statue.sh_dc.mean(1)
    assert brightness[z > 0.2].mean() > brightness[(z < -0.2) & (z > -0.5)].mean() + 0.3
    donut = load_asset(shared_data / "donut" / "fused.ply")
    assert donut.half[2] < donut.half[0]  # lying flat


def test_a_fitted_capture_is_turned_up_by_its_cameras_and_cropped_to_its_object(tmp_path):
    if not LEGO.is_file():
        pytest.skip("examples/lego/point_cloud.ply is not in this checkout")
    # The lego fit stood on its head, with a far "room" around it: upright and without the room again.
    R, q = axis_angle((1.0, 0.0, 0.0), math.pi)
    scene = read_scene(LEGO)
    scene = scene.subset(np.arange(0, scene.num_gaussians, 5))
    (tmp_path / "upright").mkdir()
    write_ply(scene, tmp_path / "upright" / "point_cloud.ply")
    (tmp_path / "upright" / "cameras.json").write_bytes((LEGO.parent / "cameras.json").read_bytes())
    means = scene.means.double().numpy()
    far = np.random.default_rng(0).normal(size=(300, 3))
    far = 6.0 * far / np.linalg.norm(far, axis=1, keepdims=True)
    n = scene.num_gaussians
    flipped = make_scene(
        np.concatenate([means @ R.T, far]),
        np.concatenate([quat_mul(q, scene.quats.double().numpy()), np.tile([1.0, 0, 0, 0], (300, 1))]),
        np.concatenate([scene.log_scales.double().numpy(), np.full((300, 3), -1.0)]),
        np.concatenate([scene.opacities.double().numpy(), np.full(300, 2.0)]),
        np.concatenate([scene.sh_dc.double().numpy(), np.zeros((300, 3))]),
        np.concatenate([rotate_sh_rest(scene.sh_rest.double().numpy(), R, 3), np.zeros((300, 15, 3))]),
        3,
    )
    write_ply(flipped, tmp_path / "point_cloud.ply")  # the flipped capture
    turn = np.eye(4)
    turn[:3, :3] = R.T  # world_to_cam of the flipped world: the old one after undoing the flip
    cams = [Camera(c.world_to_cam @ turn, c.K, c.width, c.height, c.name) for c in load_cameras(LEGO.parent)]
    save_cameras_json(cams, tmp_path / "cameras.json")
    capture = load_capture(tmp_path / "point_cloud.ply")
    upright = load_capture(tmp_path / "upright" / "point_cloud.ply")
    assert capture.n == upright.n == n
    assert np.corrcoef(capture.means[:, 2], upright.means[:, 2])[0, 1] > 0.999
