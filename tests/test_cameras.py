import json
import math
import struct
import warnings

import imagecodecs
import numpy as np
import pytest
import torch
from input_files import COLMAP_CAMS, write_colmap_bin, write_colmap_txt
from scenes import floater_scene, random_scene

from gspc.cameras import Camera, natural_key
from gspc.errors import InputError
from gspc.io.camera_files import load_cameras
from gspc.io.cameras_json import save_cameras_json
from gspc.io.transforms import image_size
from gspc.views import (
    between_views,
    halfway,
    look_at,
    robust_bounds,
    sample_views,
    split_test_views,
    synthesize_views,
)


def _project(cam: Camera, p) -> tuple[float, float, float]:
    """(u, v, z) of world point p."""
    x = cam.world_to_cam[:3, :3] @ np.asarray(p, dtype=np.float64) + cam.world_to_cam[:3, 3]
    u, v, w = cam.K @ x
    return u / w, v / w, x[2]


def _random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _random_cameras(n, rng):
    cams = []
    for i in range(n):
        w2c = np.eye(4)
        w2c[:3, :3] = _random_rotation(rng)
        w2c[:3, 3] = rng.normal(size=3)
        K = np.array(
            [[rng.uniform(300, 900), 0, rng.uniform(100, 200)], [0, rng.uniform(300, 900), 90.5], [0, 0, 1]]
        )
        cams.append(Camera(w2c, K, 320, 180 + i, f"img_{i}"))
    return cams


def _png_header(w: int, h: int) -> bytes:
    # Signature and IHDR only: enough for image_size, which never decodes pixels.
    return b"\x89PNG\r\n\x1a\n" + struct.pack(">I4sIIBBBBB", 13, b"IHDR", w, h, 8, 6, 0, 0, 0) + b"\0" * 4


def test_natural_sort_key():
    names = ["r_10", "r_2", "r_1", "a", "r_02b"]
    assert sorted(names, key=natural_key) == ["a", "r_1", "r_2", "r_02b", "r_10"]


# --- INRIA cameras.json ---------------------------------------------------------------------------


def test_cameras_json_round_trip(tmp_path):
    cams = _random_cameras(12, np.random.default_rng(0))
    path = tmp_path / "cameras.json"
    save_cameras_json(cams, path)
    assert [p.name for p in tmp_path.iterdir()] == ["cameras.json"]  # no temp file left behind
    loaded = load_cameras(path)
    assert [c.name for c in loaded] == [f"img_{i}" for i in range(12)]  # natural order: img_2 < img_10
    for a, b in zip(cams, loaded, strict=True):
        np.testing.assert_allclose(b.world_to_cam, a.world_to_cam, atol=1e-12)
        np.testing.assert_array_equal(b.K, a.K)
        assert (b.width, b.height) == (a.width, a.height)
    assert load_cameras(tmp_path)[0].name == "img_0"  # a folder holding cameras.json
    rec = json.loads(path.read_text())[0]
    assert {"id", "img_name", "width", "height", "position", "rotation", "fx", "fy"} <= rec.keys()


def test_inria_without_principal_point_uses_centre(tmp_path):
    rec = {"id": 0, "img_name": "x", "width": 64, "height": 48, "position": [0, 0, -3]}
    rec |= {"rotation": np.eye(3).tolist(), "fx": 50.0, "fy": 50.0}
    (tmp_path / "c.json").write_text(json.dumps([rec]))
    (cam,) = load_cameras(tmp_path / "c.json")
    assert (cam.cx, cam.cy) == (32, 24)
    u, v, z = _project(cam, [0, 0, 0])
    assert (u, v, z) == pytest.approx((32, 24, 3))


# --- transforms.json ------------------------------------------------------------------------------


def _transforms(tmp_path, top: dict, frames: list) -> str:
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps({**top, "frames": frames}))
    return path


def test_transforms_opengl_to_opencv(tmp_path):
    # An OpenGL camera at (0, 0, 5) with identity rotation looks down -z at the origin, y up.
    c2w = np.eye(4)
    c2w[:3, 3] = [0, 0, 5]
    path = _transforms(
        tmp_path,
        {"fl_x": 100.0, "fl_y": 110.0, "cx": 60.0, "cy": 45.0, "w": 120, "h": 90},
        [{"file_path": "images/f_10.png", "transform_matrix": c2w.tolist()}],
    )
    (cam,) = load_cameras(path)
    assert cam.name == "f_10" and (cam.width, cam.height) == (120, 90)
    assert _project(cam, [0, 0, 0]) == pytest.approx((60, 45, 5))
    u, v, z = _project(cam, [1, 2, 0])  # right of and above the axis
    assert (u, v, z) == pytest.approx((60 + 100 / 5, 45 - 2 * 110 / 5, 5))
    np.testing.assert_allclose(cam.center, [0, 0, 5], atol=1e-12)


def test_transforms_size_from_image_and_angle(tmp_path):
    (tmp_path / "train").mkdir()
    (tmp_path / "train" / "r_0.png").write_bytes(_png_header(80, 60))
    rng = np.random.default_rng(1)
    frames = []
    for i in (0, 10, 2):
        c2w = np.eye(4)
        c2w[:3, :3], c2w[:3, 3] = _random_rotation(rng), rng.normal(size=3)
        frames.append({"file_path": f"./train/r_{i}", "transform_matrix": c2w.tolist()})
    path = _transforms(tmp_path, {"camera_angle_x": math.radians(90)}, frames)
    cams = load_cameras(path)
    assert [c.name for c in cams] == ["r_0", "r_2", "r_10"]
    assert all((c.width, c.height, c.cx, c.cy) == (80, 60, 40, 30) for c in cams)
    assert cams[0].fx == pytest.approx(40.0) and cams[0].fy == pytest.approx(40.0)
    with pytest.raises(InputError, match="80x60"):
        load_cameras(path, width=100, height=60)
    (tmp_path / "train" / "r_0.png").unlink()
    with pytest.raises(InputError, match="width and height"):
        load_cameras(path)
    assert load_cameras(path, width=100, height=50)[0].fx == pytest.approx(50.0)


def test_transforms_size_mismatch_with_arguments(tmp_path):
    path = _transforms(
        tmp_path, {"fl_x": 10, "w": 20, "h": 10}, [{"file_path": "a", "transform_matrix": np.eye(4).tolist()}]
    )
    with pytest.raises(InputError, match="20x10"):
        load_cameras(path, width=40, height=20)


def test_image_size_of_jpeg(tmp_path):
    img = np.zeros((37, 53, 3), np.uint8)
    (tmp_path / "a.jpg").write_bytes(imagecodecs.jpeg8_encode(img))
    assert image_size(tmp_path / "a.jpg") == (53, 37)
    (tmp_path / "b.png").write_bytes(imagecodecs.png_encode(img))
    assert image_size(tmp_path / "b.png") == (53, 37)
    (tmp_path / "c.bmp").write_bytes(b"BM" + b"\0" * 40)
    with pytest.raises(InputError):
        image_size(tmp_path / "c.bmp")


# --- COLMAP ---------------------------------------------------------------------------------------


def _check_colmap(cams):
    assert [c.name for c in cams] == ["DSC_9", "DSC_10"]
    a, b = cams
    assert (a.width, a.height, a.fx, a.fy, a.cx, a.cy) == (40, 30, 35, 35, 20, 15)
    assert (b.width, b.height, b.fx, b.fy, b.cx, b.cy) == (64, 48, 50, 55, 31, 23)
    assert _project(a, [0, 0, 0]) == pytest.approx((20, 15, 3))
    R = b.world_to_cam[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(b.world_to_cam[:3, 3], [0.5, -1.0, 4.0])
    q = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])
    # rotation about the quaternion's axis leaves the axis fixed
    np.testing.assert_allclose(R @ q[1:], q[1:], atol=1e-12)


def test_colmap_text(tmp_path):
    write_colmap_txt(tmp_path / "sparse" / "0")
    _check_colmap(load_cameras(tmp_path))
    _check_colmap(load_cameras(tmp_path / "sparse" / "0" / "images.txt"))


def test_colmap_binary(tmp_path):
    write_colmap_bin(tmp_path / "sparse" / "0")
    _check_colmap(load_cameras(tmp_path / "sparse" / "0"))


def test_colmap_distortion_warns_and_unknown_model_fails(tmp_path):
    cams = [
        (1, "OPENCV", 64, 48, [50.0, 55.0, 31.0, 23.0, 0.1, 0, 0, 0]),
        (2, "SIMPLE_RADIAL", 40, 30, [35, 20, 15, 0]),
    ]
    write_colmap_txt(tmp_path / "a", cams)
    with pytest.warns(UserWarning, match="OPENCV"):
        loaded = load_cameras(tmp_path / "a")
    assert loaded[1].fx == 50 and loaded[1].cy == 23
    write_colmap_txt(tmp_path / "b", [(1, "OPENCV_FISHEYE", 64, 48, [1.0] * 8), COLMAP_CAMS[1]])
    with pytest.raises(InputError, match="OPENCV_FISHEYE"):
        load_cameras(tmp_path / "b")
    write_colmap_txt(tmp_path / "c", [(1, "WEIRD", 64, 48, [1.0]), COLMAP_CAMS[1]])
    with pytest.raises(InputError, match="WEIRD"):
        load_cameras(tmp_path / "c")
    write_colmap_txt(tmp_path / "d", COLMAP_CAMS[1:])
    with pytest.raises(InputError, match="camera 1"):
        load_cameras(tmp_path / "d")


# --- bad input ------------------------------------------------------------------------------------


@pytest.mark.filterwarnings("error")
def test_camera_values_beyond_binary32_are_named(tmp_path):
    """Issue 50: a translation of 1e200 (cameras are rendered and stored in binary32) is refused where the
    camera is read, before any arithmetic overflows."""
    frame = {
        "file_path": "a",
        "transform_matrix": [[1, 0, 0, 1e200], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]],
    }
    (tmp_path / "t.json").write_text(json.dumps({"fl_x": 3, "w": 4, "h": 4, "frames": [frame]}))
    with pytest.raises(InputError, match="1e\\+200 in its pose, beyond binary32"):
        load_cameras(tmp_path / "t.json")


def test_bad_camera_files(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        load_cameras(tmp_path / "nope.json")
    with pytest.raises(InputError, match="no cameras.json"):
        load_cameras(tmp_path)
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        load_cameras(tmp_path / "bad.json")
    (tmp_path / "odd.json").write_text('{"cameras": []}')
    with pytest.raises(InputError, match="neither"):
        load_cameras(tmp_path / "odd.json")
    (tmp_path / "inria.json").write_text('[{"width": 4, "height": 4, "position": [0, 0, 0]}]')
    with pytest.raises(InputError, match="'rotation'"):
        load_cameras(tmp_path / "inria.json")
    (tmp_path / "tf.json").write_text('{"fl_x": 3, "w": 4, "h": 4, "frames": [{"file_path": "a"}]}')
    with pytest.raises(InputError, match="transform_matrix"):
        load_cameras(tmp_path / "tf.json")
    (tmp_path / "nof.json").write_text(
        json.dumps({"w": 4, "h": 4, "frames": [{"transform_matrix": np.eye(4).tolist()}]})
    )
    with pytest.raises(InputError, match="focal"):
        load_cameras(tmp_path / "nof.json")
    m = np.eye(4)
    m[0, 0] = 2.0
    (tmp_path / "scaled.json").write_text(
        json.dumps({"fl_x": 3, "w": 4, "h": 4, "frames": [{"transform_matrix": m.tolist()}]})
    )
    with pytest.raises(InputError, match="orthonormal"):
        load_cameras(tmp_path / "scaled.json")
    frames = [{"file_path": "x/a.png", "transform_matrix": np.eye(4).tolist()}] * 2
    (tmp_path / "dup.json").write_text(json.dumps({"fl_x": 3, "w": 4, "h": 4, "frames": frames}))
    with pytest.raises(InputError, match="more than once"):
        load_cameras(tmp_path / "dup.json")
    with pytest.raises(InputError):
        load_cameras(tmp_path / "dup.json", width=4)


# --- synthesised views, sampling, splits -----------------------------------------------------------


def test_robust_bounds_ignore_floaters():
    lo, hi = robust_bounds(floater_scene())
    # 0.2%-99.8% of a normal cloud spans about 5.8 sigma (2, 1, 0.5); floaters at +-500 would dwarf that.
    assert np.all(hi - lo < [13, 6.5, 3.3]) and np.all(hi > lo)
    assert np.allclose((lo + hi) / 2, [5, -3, 1], atol=0.3)


@pytest.mark.parametrize("n,width,height,fov", [(1, 64, 64, 50.0), (24, 320, 180, 60.0), (7, 100, 200, 30.0)])
def test_synthesized_views_see_the_whole_volume(n, width, height, fov):
    scene = floater_scene()
    cams = synthesize_views(scene, n, width=width, height=height, fov_deg=fov)
    assert len(cams) == n and len({c.name for c in cams}) == n
    lo, hi = robust_bounds(scene)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    centre = (lo + hi) / 2
    for cam in cams:
        assert (cam.width, cam.height) == (width, height)
        R = cam.world_to_cam[:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        assert not np.all((cam.center >= lo) & (cam.center <= hi))  # never inside the volume
        for p in corners:
            u, v, z = _project(cam, p)
            assert z > 0 and 0 <= u <= width and 0 <= v <= height
        u, v, _ = _project(cam, centre)
        assert (u, v) == pytest.approx((width / 2, height / 2))
    again = synthesize_views(scene, n, width=width, height=height, fov_deg=fov)
    assert all(np.array_equal(a.world_to_cam, b.world_to_cam) for a, b in zip(cams, again, strict=True))


def test_synthesized_views_spread_and_poles():
    scene = floater_scene(500)
    cams = synthesize_views(scene, 40, up=(0, 1, 0))
    dirs = np.array([c.center for c in cams])
    dirs -= dirs.mean(0)
    assert np.abs(dirs.mean(0)).max() < 0.1 * np.linalg.norm(dirs, axis=1).mean()
    # a camera straight above the centre still gets a valid frame
    from gspc.views import look_at

    w2c = look_at([0, 0, 5], [0, 0, 0], [0, 0, 1])
    np.testing.assert_allclose(w2c[:3, :3] @ w2c[:3, :3].T, np.eye(3), atol=1e-12)
    with pytest.raises(InputError):
        synthesize_views(scene, 0)
    with pytest.raises(InputError):
        synthesize_views(scene, 3, fov_deg=180)
    with pytest.raises(InputError):
        synthesize_views(scene, 3, up=(0, 0, 0))


def _named(names):
    return [Camera(np.eye(4), np.eye(3), 4, 4, n) for n in names]


def test_sample_views():
    cams = _named([f"r_{i}" for i in range(100)])
    idx = sample_views(cams, 0.4)
    assert len(idx) == 40 == len(set(idx)) and idx == sorted(idx)
    assert np.all(np.diff(idx) >= 2) and np.all(np.diff(idx) <= 3)
    assert sample_views(cams, 1.0) == list(range(100))
    assert sample_views(cams, 1e-6) == [50]
    assert sample_views(cams, 0.4) == idx  # deterministic
    shuffled = _named(["b", "a", "c", "d"])
    assert [shuffled[i].name for i in sample_views(shuffled, 0.5)] == ["b", "d"]
    for bad in (0, -0.1, 1.5, float("nan"), "x"):
        with pytest.raises(InputError):
            sample_views(cams, bad)
    with pytest.raises(InputError):
        sample_views([], 0.5)


def test_split_test_views():
    names = [f"r_{i}" for i in range(20)]
    rng = np.random.default_rng(0)
    perm = rng.permutation(20)
    cams = _named([names[p] for p in perm])
    train, test = split_test_views(cams)
    assert sorted(cams[i].name for i in test) == ["r_0", "r_16", "r_8"]
    assert sorted(train + test) == list(range(20)) and not set(train) & set(test)
    with pytest.raises(InputError):
        split_test_views(cams, every=1)


def test_lego_transforms(shared_data):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cams = load_cameras(shared_data / "lego" / "transforms_train.json")
    assert len(cams) == 100
    assert cams[0].name == "r_0" and cams[2].name == "r_2" and cams[10].name == "r_10"
    for cam in cams:
        assert (cam.width, cam.height) == (800, 800)
        u, v, z = _project(cam, [0, 0, 0])
        assert z > 0 and abs(u - 400) < 1 and abs(v - 400) < 1
        # Blender's world z is up; in the image it points up (negative v)
        u2, v2, _ = _project(cam, [0, 0, 0.5])
        assert v2 < v
    train, test = split_test_views(cams)
    assert (len(train), len(test)) == (87, 13)


def test_limit_size_scales_only_large_views():
    from gspc.views import limit_size

    big = Camera(np.eye(4), [[800, 0, 400], [0, 800, 300], [0, 0, 1]], 800, 600, "big")
    small = Camera(np.eye(4), [[100, 0, 50], [0, 100, 40], [0, 0, 1]], 100, 80, "small")
    a, b = limit_size([big, small], 400)
    assert (a.width, a.height) == (400, 300) and np.allclose(a.K[:2], big.K[:2] / 2)
    assert b is small


def test_views_of_a_scene_with_a_background_frame_its_object():
    """A background shell (20% of the count, 30x away) and floaters do not push synthesised cameras away."""
    obj = random_scene(1000, sh_degree=0, seed=4)
    g = np.random.default_rng(4)
    d = g.normal(size=(220, 3))
    far = (
        d / np.linalg.norm(d, axis=1, keepdims=True) * np.r_[np.full(200, 30.0), np.full(20, 3000.0)][:, None]
    )
    world = obj.map(lambda t: torch.cat([t, t[:220]]))
    world.means[1000:] = torch.from_numpy(far.astype(np.float32))
    alone, around = synthesize_views(obj, 6), synthesize_views(world, 6)
    for a, b in zip(alone, around):
        assert np.allclose(a.center, b.center, atol=0.05 * np.linalg.norm(a.center))


def _looking(eye, target=(0.0, 0.0, 0.0), name=""):
    K = np.array([[50.0, 0, 32], [0, 50.0, 32], [0, 0, 1]])
    return Camera(look_at(np.array(eye), np.array(target), np.array([0.0, 0.0, 1.0])), K, 64, 64, name)


def test_halfway_is_the_midpoint_and_the_mean_turn():
    # Two cameras on a circle around the origin, 60 degrees apart: halfway stands between their centres
    # and looks 30 degrees from each.
    a = _looking([4.0, 0.0, 0.0], name="a")
    b = _looking([4.0 * math.cos(math.pi / 3), 4.0 * math.sin(math.pi / 3), 0.0], name="b")
    h = halfway(a, b)
    R = h.world_to_cam[:3, :3]
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(h.center, 0.5 * (a.center + b.center))
    for c in (a, b):
        turn = math.degrees(math.acos(np.clip((np.trace(R @ c.world_to_cam[:3, :3].T) - 1) / 2, -1, 1)))
        assert turn == pytest.approx(30.0, abs=1e-6)
    assert np.allclose(halfway(a, a).world_to_cam, a.world_to_cam)


def test_between_views_go_halfway_to_the_nearest_camera():
    cams = [_looking([4.0, 0, 0]), _looking([4.0, 0.4, 0]), _looking([-4.0, 0, 0]), _looking([0, 4.0, 0])]
    got = between_views(cams, [0, 2])
    assert np.allclose(got[0].center, [4.0, 0.2, 0.0])  # camera 1 is camera 0's nearest
    assert np.allclose(got[1].center, [-2.0, 2.0, 0.0])  # camera 3 is camera 2's
    alone = between_views([cams[0], _looking([4.0, 0, 0], target=(0, 1.0, 0))], [0])
    assert np.allclose(alone[0].world_to_cam, cams[0].world_to_cam)  # no other centre: itself
