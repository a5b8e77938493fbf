"""Camera and scene input at its edges (issue 26, item 4): huge or non-finite COLMAP quaternions, lens
distortion warned in one line, SOG bounds of +-1e308, and tools/fit_scene.py's bad photos and points."""

import math
import struct
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from cli_runs import run
from input_files import COLMAP_CAMS, COLMAP_IMGS, write_colmap_txt
from scenes import random_scene
from sog_files import make_sog

from gspc.errors import InputError
from gspc.io import read_scene, write_ply
from gspc.io.camera_files import load_cameras
from gspc.io.colmap import load_colmap_points

REPO = Path(__file__).resolve().parents[1]


def _with_quaternion(tmp_path, q):
    imgs = [(3, q, [0.5, -1.0, 4.0], 1, "a.jpg"), *COLMAP_IMGS[1:]]
    write_colmap_txt(tmp_path / "m", COLMAP_CAMS, imgs)
    return tmp_path / "m"


@pytest.mark.parametrize("q", [[1e300, 1e300, 0, 0], [1e-320, 0, 1e-320, 0], [-1e308, 1e308, 1e308, 1e308]])
def test_huge_and_tiny_quaternions_normalise_without_warnings(tmp_path, q):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cams = load_cameras(_with_quaternion(tmp_path, q))
    R = cams[0].world_to_cam[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    unit = np.array(q) / np.abs(q).max()
    unit /= np.linalg.norm(unit)
    np.testing.assert_allclose(R @ unit[1:], unit[1:], atol=1e-12)  # the same rotation, not the identity
    if q[0] == 1e300:
        assert not np.allclose(R, np.eye(3))


@pytest.mark.parametrize("q", [["inf", 0, 0, 0], ["nan", 1, 0, 0], [0, 0, 0, 0]])
def test_non_finite_and_zero_quaternions_are_refused(tmp_path, q):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match="quaternion"):
            load_cameras(_with_quaternion(tmp_path, q))


def test_lens_distortion_warning_is_one_line_in_the_cli(tmp_path):
    cams = [(1, "OPENCV", 64, 48, [50.0, 55.0, 31.0, 23.0, 0.1, 0, 0, 0]), COLMAP_CAMS[1]]
    write_colmap_txt(tmp_path / "m", cams)
    scene = tmp_path / "s.ply"
    write_ply(random_scene(100, sh_degree=0, seed=0), scene)
    res = run("render", scene, "-o", tmp_path / "imgs", "--cameras", tmp_path / "m", "--max-side", 16)
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.output.splitlines() if "lens distortion" in ln]
    assert len(lines) == 1 and lines[0].startswith("gspc: warning: "), res.output
    assert "colmap.py" not in res.output and "warnings.warn" not in res.output


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        ("mins", [-1e308] * 3, "means.mins"),
        ("maxs", [1e308] * 3, "means.maxs"),
        ("maxs", [89.0] * 3, "means.maxs"),
    ],
)
def test_sog_bounds_beyond_float32_are_refused_without_warnings(tmp_path, field, value, needle):
    make_sog(tmp_path / "s.sog", meta_override=lambda m: m["means"].update({field: value}))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match=needle):
            read_scene(tmp_path / "s.sog")


@pytest.mark.parametrize("key", ["scales", "sh0"])
def test_sog_codebooks_beyond_float32_are_refused(tmp_path, key):
    make_sog(tmp_path / "s.sog", meta_override=lambda m: m[key].update(codebook=[-1e308] * 256))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(InputError, match=f"{key}.codebook"):
            read_scene(tmp_path / "s.sog")


def test_sog_bounds_at_the_edge_decode(tmp_path):
    make_sog(tmp_path / "s.sog", meta_override=lambda m: m["means"].update(mins=[-88.0] * 3, maxs=[88.0] * 3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = read_scene(tmp_path / "s.sog")
    assert float(scene.means.abs().max()) <= math.expm1(88.0) * (1 + 1e-6)


def test_colmap_points_out_of_range_are_one_error(tmp_path):
    (tmp_path / "points3D.txt").write_text("1 0 0 0 300 0 0 0.5\n")
    with pytest.raises(InputError, match="do not parse"):
        load_colmap_points(tmp_path)
    (tmp_path / "points3D.txt").write_text("1 inf 0 0 3 0 0 0.5\n")
    with pytest.raises(InputError, match="non-finite"):
        load_colmap_points(tmp_path)


def _fit(source: Path, out: Path) -> subprocess.CompletedProcess:
    cmd = [sys.executable, str(REPO / "tools" / "fit_scene.py"), str(source), "-o", str(out)]
    cmd += ["--iterations", "1", "--gaussians", "100", "--downscale", "8"]
    env = {"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin", "GSPC_THREADS": "1"}
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)


@pytest.mark.slow
def test_fit_scene_reports_bad_photos_and_points_in_one_line(tmp_path):
    cap = tmp_path / "cap"
    write_colmap_txt(cap / "sparse" / "0")
    (cap / "sparse" / "0" / "points3D.bin").write_bytes(struct.pack("<Q", 1000) + b"\0" * 40)
    (cap / "images").mkdir()
    for name in ("DSC_9.JPG", "DSC_10.JPG"):
        (cap / "images" / name).write_bytes(b"not a photo")
    res = _fit(cap, tmp_path / "out")
    assert res.returncode != 0 and "Traceback" not in res.stderr, res.stderr
    assert res.stderr.strip().splitlines()[-1].startswith("fit_scene: error:"), res.stderr
    import imagecodecs

    for name, (w, h) in (("DSC_9.JPG", (40, 30)), ("DSC_10.JPG", (64, 48))):
        (cap / "images" / name).write_bytes(imagecodecs.jpeg_encode(np.zeros((h, w, 3), np.uint8)))
    res = _fit(cap, tmp_path / "out")
    assert res.returncode != 0 and "Traceback" not in res.stderr, res.stderr
    last = res.stderr.strip().splitlines()[-1]
    assert last.startswith("fit_scene: error:") and "points3D.bin" in last, res.stderr
