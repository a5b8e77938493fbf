"""Writers chosen by the output's extension: SPZ (our bytes against Niantic's writer, round trips within SPZ's
steps, the coordinate-system record) and glTF binary with KHR_gaussian_splatting (its structure, read back);
the convention a source states travelling through a .gspc file; bad outputs in one line, warnings in none."""

import gzip
import json
import os
import struct
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_runs import assert_one_line_error, run
from scenes import random_scene, spz_range_scene

from gspc.errors import InputError
from gspc.format import container
from gspc.format.header import SceneSummary
from gspc.io import read_ply, read_scene, read_spz, scene_writer, write_glb, write_ply, write_scene, write_spz
from gspc.io.coordinates import axes, oriented
from gspc.io.spz import decode_spz
from gspc.io.spz_writer import spz_bytes
from gspc.pipeline import EncodeOptions, encode
from gspc.scene import SH_C0, make_scene

DATA = Path(__file__).parent / "data" / "spz"
EPS = 1e-6
RDF_RECORD = struct.pack("<III", 0xADBE0003, 4, 6)


# ---------------------------------------------------------------- SPZ


@pytest.mark.parametrize("name", ["donut256", "synth_sh3"])
@pytest.mark.parametrize("version", [3, 4])
def test_spz_bytes_equal_niantics_writer(name, version):
    """tests/data/spz holds Niantic's C++ writer's output (through splat-transform 3.7.0) for the same PLY."""
    ours = spz_bytes(read_ply(DATA / f"{name}.ply"), version)
    assert ours == (DATA / f"{name}.v{version}.spz").read_bytes()


def test_spz_version_2_agrees_with_spz_js():
    """spz-js rounds in float32, so one position byte of 128 Gaussians lands one step away."""
    ours = decode_spz(spz_bytes(read_ply(DATA / "synth_sh3.ply"), 2))[1]
    theirs = read_spz(DATA / "synth_sh3.v2.spz")
    assert (ours.means - theirs.means).abs().max() <= 2.0**-12 + EPS
    for attr in ("quats", "log_scales", "opacities", "sh_dc", "sh_rest"):
        assert torch.equal(getattr(ours, attr), getattr(theirs, attr)), attr


@pytest.mark.parametrize("version", [2, 3, 4])
def test_spz_round_trip_is_within_spz_steps(version):
    scene = spz_range_scene()
    header, back = decode_spz(spz_bytes(scene, version))
    assert (header.version, header.fractional_bits, back.coordinates) == (version, 12, None)
    assert (back.means - scene.means).abs().max() <= 2.0**-13 + EPS
    alpha = (torch.sigmoid(back.opacities) - torch.sigmoid(scene.opacities)).abs().max()
    assert alpha <= 0.5 / 255 + EPS
    assert (back.log_scales - scene.log_scales).abs().max() <= 1 / 32 + EPS
    assert (back.sh_dc - scene.sh_dc).abs().max() <= 0.5 / (0.15 * 255) + EPS
    # Buckets of 8 bytes (5 bits) in band 1 and of 16 (4 bits) above, plus the byte's own rounding.
    assert (back.sh_rest[:, :3] - scene.sh_rest[:, :3]).abs().max() <= 4.5 / 128 + EPS
    assert (back.sh_rest[:, 3:] - scene.sh_rest[:, 3:]).abs().max() <= 8.5 / 128 + EPS
    unit = scene.quats / scene.quats.norm(dim=1, keepdim=True)
    cosine = (unit * back.quats).sum(1).abs()
    assert cosine.min() >= (0.99 if version == 2 else 1 - 1e-5)
    again = decode_spz(spz_bytes(back, version))[1]  # decoded values code to themselves (rotations: nearly)
    for attr in ("means", "opacities", "sh_dc", "log_scales", "sh_rest"):
        assert torch.equal(getattr(again, attr), getattr(back, attr)), attr


def test_spz_sh_precision_can_be_raised():
    scene = spz_range_scene(degree=1)
    back = decode_spz(spz_bytes(scene, 3, sh_bits=(8, 8)))[1]
    assert (back.sh_rest - scene.sh_rest).abs().max() <= 0.5 / 128 + EPS
    with pytest.raises(InputError, match="outside 1-8 bits"):
        spz_bytes(scene, 3, sh_bits=(9, 4))
    with pytest.raises(InputError, match="SPZ version 5 cannot be written"):
        spz_bytes(scene, 5)


def test_spz_positions_beyond_twelve_fractional_bits_coarsen_then_refuse():
    scene = spz_range_scene(n=20, degree=0)
    scene.means[0] = torch.tensor([5000.0, 0.0, -3.0])  # 5000 * 2^12 > 2^23
    header, back = decode_spz(spz_bytes(scene, 3))
    assert header.fractional_bits == 10
    assert (back.means - scene.means).abs().max() <= 2.0**-11 + EPS
    scene.means[0, 0] = 9e6
    with pytest.raises(InputError, match="beyond SPZ's 24-bit positions") as err:
        spz_bytes(scene, 3)
    assert "\n" not in str(err.value)


def test_values_far_outside_spz_clamp_without_warnings():
    scene = spz_range_scene(n=8, degree=3)
    big = float(np.finfo(np.float32).max)
    scene.sh_rest[0] = big
    scene.sh_rest[1] = -big
    scene.sh_dc[2] = big
    scene.log_scales[3] = -big
    scene.opacities[4] = big
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = decode_spz(spz_bytes(scene, 3))[1]
    assert back.sh_rest[0].min() > 0.99 and back.sh_rest[1].max() == -1.0
    assert back.sh_dc[2].min() > 3.3 and back.log_scales[3].max() == -10.0
    assert torch.sigmoid(back.opacities[4]) > 0.999


def test_format_limits_end_in_one_line(monkeypatch, tmp_path):
    """SPZ counts Gaussians in 32 bits and a .glb stops below 4 GiB: both refused before writing."""
    scene = spz_range_scene(n=30, degree=0)
    monkeypatch.setattr("gspc.io.spz_writer.MAX_COUNT", 20)
    with pytest.raises(InputError, match="30 Gaussians: SPZ counts at most 20 \\(32 bits\\)"):
        write_spz(scene, tmp_path / "s.spz")
    monkeypatch.setattr("gspc.io.glb.MAX_GLB_BYTES", 1000)
    with pytest.raises(InputError, match="the .glb would take .* bytes; the format stops at 1,000"):
        write_glb(scene, tmp_path / "s.glb")
    assert not list(tmp_path.iterdir())


def test_a_stated_convention_is_written_as_opencv_with_a_record():
    scene = spz_range_scene(n=50, degree=2)
    scene.coordinates = "RUB"
    expected = oriented(scene, "RDF")
    for version in (3, 4):
        data = spz_bytes(scene, version)
        header, back = decode_spz(data)
        assert header.has_extensions and back.coordinates == "RDF"
        assert (back.means - expected.means).abs().max() <= 2.0**-13 + EPS
        raw = gzip.decompress(data) if version == 3 else data
        assert raw.endswith(RDF_RECORD) if version == 3 else raw[32:44] == RDF_RECORD, version
    header, back = decode_spz(spz_bytes(scene, 2))  # GaussianSplats3D refuses trailing bytes: no record
    assert not header.has_extensions and back.coordinates is None
    assert (back.means - expected.means).abs().max() <= 2.0**-13 + EPS


def _with_record(data: bytes, code: bytes) -> bytes:
    """A version-3 file with a coordinate-system record holding ``code`` appended."""
    raw = bytearray(gzip.decompress(data))
    raw[14] |= 2
    return gzip.compress(bytes(raw) + struct.pack("<II", 0xADBE0003, len(code)) + code, mtime=0)


def test_coordinate_records_read_or_refused():
    data = spz_bytes(spz_range_scene(n=10, degree=0), 3)
    assert decode_spz(_with_record(data, struct.pack("<I", 4)))[1].coordinates == "RUB"
    assert decode_spz(_with_record(data, struct.pack("<I", 16)))[1].coordinates == "RBU"
    assert decode_spz(_with_record(data, struct.pack("<I", 0)))[1].coordinates is None  # UNSPECIFIED
    with pytest.raises(InputError, match="names system 17, not one of 1-16"):
        decode_spz(_with_record(data, struct.pack("<I", 17)), "f.spz")
    with pytest.raises(InputError, match="holds 2 bytes, not 4"):
        decode_spz(_with_record(data, b"\0\0"), "f.spz")


# ---------------------------------------------------------------- glTF binary


def parse_glb(data: bytes) -> tuple[dict, bytes]:
    """JSON and BIN chunks of a .glb, checking the container's framing and alignment."""
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_length % 4 == 0
    text = data[20 : 20 + json_length]
    at = 20 + json_length
    bin_length, bin_type = struct.unpack_from("<II", data, at)
    assert bin_type == 0x004E4942 and bin_length % 4 == 0 and at + 8 + bin_length == len(data)
    return json.loads(text.rstrip(b" ")), data[at + 8 :]


def accessor_array(gltf: dict, blob: bytes, semantic: str) -> np.ndarray:
    primitive = gltf["meshes"][0]["primitives"][0]
    accessor = gltf["accessors"][primitive["attributes"][semantic]]
    view = gltf["bufferViews"][accessor["bufferView"]]
    dtype = {5126: np.float32, 5121: np.uint8}[accessor["componentType"]]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[accessor["type"]]
    assert view["byteOffset"] % 4 == 0 and view["byteOffset"] + view["byteLength"] <= len(blob)
    assert view["byteLength"] == accessor["count"] * width * np.dtype(dtype).itemsize
    array = np.frombuffer(blob, dtype, accessor["count"] * width, view["byteOffset"])
    return array.reshape(accessor["count"], width) if width > 1 else array


@pytest.mark.parametrize("degree", [0, 3])
def test_glb_structure_and_values(tmp_path, degree):
    scene = random_scene(120, sh_degree=degree, seed=8)
    write_glb(scene, tmp_path / "s.glb")
    gltf, blob = parse_glb((tmp_path / "s.glb").read_bytes())
    assert gltf["asset"]["version"] == "2.0" and gltf["extensionsUsed"] == ["KHR_gaussian_splatting"]
    primitive = gltf["meshes"][0]["primitives"][0]
    assert primitive["mode"] == 0
    assert primitive["extensions"]["KHR_gaussian_splatting"] == {
        "kernel": "ellipse",
        "colorSpace": "srgb_rec709_display",
    }
    sh_names = [f"SH_DEGREE_{d}_COEF_{n}" for d in range(1, degree + 1) for n in range(2 * d + 1)]
    names = ["ROTATION", "SCALE", "OPACITY", "SH_DEGREE_0_COEF_0", *sh_names]
    ext = "KHR_gaussian_splatting:"
    assert set(primitive["attributes"]) == {"POSITION", "COLOR_0", *(ext + n for n in names)}
    assert all(a["count"] == 120 for a in gltf["accessors"])
    assert gltf["buffers"] == [{"byteLength": len(blob)}]
    # An unstated scene is taken as OpenCV (RDF) and turned into glTF's LUF: x and y change sign.
    expected = oriented(scene, "LUF")
    position = accessor_array(gltf, blob, "POSITION")
    np.testing.assert_array_equal(position, expected.means.numpy())
    np.testing.assert_array_equal(position[:, :2], -scene.means.numpy()[:, :2])
    pos_accessor = gltf["accessors"][primitive["attributes"]["POSITION"]]
    assert pos_accessor["min"] == position.min(0).tolist() and pos_accessor["max"] == position.max(0).tolist()
    rotation = accessor_array(gltf, blob, ext + "ROTATION")
    np.testing.assert_allclose(np.linalg.norm(rotation, axis=1), 1.0, atol=1e-6)
    unit = expected.quats / expected.quats.norm(dim=1, keepdim=True)
    np.testing.assert_allclose(rotation, unit[:, [1, 2, 3, 0]].numpy(), atol=1e-6)
    np.testing.assert_allclose(
        accessor_array(gltf, blob, ext + "SCALE"), expected.log_scales.exp(), rtol=1e-6
    )
    opacity = accessor_array(gltf, blob, ext + "OPACITY")
    np.testing.assert_allclose(opacity, torch.sigmoid(scene.opacities), rtol=1e-6)
    np.testing.assert_array_equal(accessor_array(gltf, blob, ext + "SH_DEGREE_0_COEF_0"), scene.sh_dc.numpy())
    for k, name in enumerate(sh_names):
        np.testing.assert_array_equal(accessor_array(gltf, blob, ext + name), expected.sh_rest[:, k].numpy())
    colour = accessor_array(gltf, blob, "COLOR_0").astype(np.float64) / 255  # linear, from sRGB
    srgb = np.clip(0.5 + SH_C0 * scene.sh_dc.numpy(), 0, 1)
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    np.testing.assert_allclose(colour[:, :3], linear, atol=0.5 / 255 + 1e-6)
    np.testing.assert_allclose(colour[:, 3], opacity, atol=0.5 / 255 + 1e-6)


def test_glb_refuses_scales_beyond_float32(tmp_path):
    scene = random_scene(10, sh_degree=0, seed=9)
    scene.log_scales[3, 1] = 90.0
    with pytest.raises(InputError, match="beyond float32 as a linear glTF SCALE"):
        write_glb(scene, tmp_path / "s.glb")
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------- choosing the writer


def test_the_extension_chooses_the_writer(tmp_path):
    scene = spz_range_scene(n=40, degree=1)
    assert scene_writer("a.PLY") is write_ply and scene_writer("a.Spz") is write_spz
    assert scene_writer("a.glb") is write_glb and scene_writer("/dev/null") is write_ply
    for name in ("s.ply", "s.spz", "plain"):
        write_scene(scene, tmp_path / name)
        assert read_scene(tmp_path / name).num_gaussians == 40
    write_scene(scene, tmp_path / "s.glb")
    assert (tmp_path / "s.glb").read_bytes()[:4] == b"glTF"
    with pytest.raises(
        InputError, match=r"does not write '\.sog' files; name the output \.ply, \.spz or \.glb"
    ):
        write_scene(scene, tmp_path / "s.sog")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plain", "s.glb", "s.ply", "s.spz"]


def test_cli_convert_writes_every_format_and_refuses_bad_outputs(tmp_path):
    source = DATA / "synth_sh3.v4.spz"
    for name in ("o.ply", "o.spz", "o.glb"):
        res = run("convert", source, "-o", tmp_path / name)
        assert res.exit_code == 0, res.output
    assert torch.equal(read_spz(tmp_path / "o.spz").means, read_spz(source).means)
    assert_one_line_error(run("convert", source, "-o", tmp_path / "o.splat"), ".ply, .spz or .glb")
    assert_one_line_error(run("convert", source, "-o", tmp_path), "is a folder")
    far = spz_range_scene(n=5, degree=0)
    far.means[0, 2] = 1e7
    write_ply(far, tmp_path / "far.ply")
    assert_one_line_error(
        run("convert", tmp_path / "far.ply", "-o", tmp_path / "far.spz"), "24-bit positions"
    )
    assert not (tmp_path / "o.splat").exists() and not (tmp_path / "far.spz").exists()


# ---------------------------------------------------------------- a stated convention through a .gspc file

FAST = EncodeOptions(
    side_info=False,
    synth_views=4,
    max_side=32,
    precision=False,
    tune_iterations=0,
    removal_search=False,
    keep_invisible=True,
)


def pole(up_axis: np.ndarray, n: int = 400):
    """Gaussians along ``up_axis`` from 0 to 2, a small disc at its foot: a scene with a clear up."""
    rng = np.random.default_rng(11)
    height = rng.uniform(0.0, 2.0, n)
    side = rng.normal(0.0, 0.05, (n, 3))
    means = height[:, None] * up_axis + side - (side @ up_axis)[:, None] * up_axis
    return make_scene(
        means,
        rng.normal(size=(n, 4)),
        rng.uniform(-5, -3, (n, 3)),
        rng.uniform(0, 4, n),
        rng.uniform(-1, 1, (n, 3)),
        rng.uniform(-0.3, 0.3, (n, 3, 3)),
        1,
    )


def physical_up(scene, stated: str | None) -> np.ndarray:
    """Each Gaussian's height along the physical up, reading its arrays in ``stated`` (None: RDF)."""
    return (scene.means.double().numpy() @ axes(stated or "RDF").T)[:, 1]


@pytest.mark.slow
def test_a_stated_convention_survives_encode_and_decode(tmp_path):
    """An SPZ that states RUB (its up is +y) -> .gspc (records RUB) -> .spz, .glb and .ply, all upright."""
    source = pole(np.array([0.0, 1.0, 0.0]))  # up is +y in RUB
    spz = tmp_path / "pole.spz"
    spz.write_bytes(_with_record(spz_bytes(source, 3), struct.pack("<I", 4)))
    assert read_scene(spz).coordinates == "RUB"
    encode(spz, tmp_path / "pole.gspc", opts=FAST)
    meta = container.read(tmp_path / "pole.gspc").header
    assert SceneSummary.from_dict(meta).coordinates == "RUB"
    res = run("info", tmp_path / "pole.gspc")
    assert "coordinates: RUB" in res.output, res.output
    for name in ("out.spz", "out.glb", "out.ply"):
        res = run("decode", tmp_path / "pole.gspc", "-o", tmp_path / name, "--no-refine")
        assert res.exit_code == 0, res.output
    back = read_spz(tmp_path / "out.spz")
    assert back.coordinates == "RDF"
    gltf, blob = parse_glb((tmp_path / "out.glb").read_bytes())
    glb_heights = accessor_array(gltf, blob, "POSITION")[:, 1]  # glTF: +y is up
    for heights in (physical_up(back, "RDF"), glb_heights, physical_up(read_ply(tmp_path / "out.ply"), None)):
        assert heights.min() > -0.1 and heights.max() > 1.9 and np.median(heights) > 0.8


def test_an_unstated_source_is_taken_as_opencv(tmp_path):
    """A PLY records nothing; its up is -y (OpenCV) and a .glb turns it up."""
    write_ply(pole(np.array([0.0, -1.0, 0.0])), tmp_path / "pole.ply")
    encode(tmp_path / "pole.ply", tmp_path / "pole.gspc", opts=FAST)
    assert SceneSummary.from_dict(container.read(tmp_path / "pole.gspc").header).coordinates is None
    res = run("decode", tmp_path / "pole.gspc", "-o", tmp_path / "out.glb", "--no-refine")
    assert res.exit_code == 0, res.output
    gltf, blob = parse_glb((tmp_path / "out.glb").read_bytes())
    assert np.median(accessor_array(gltf, blob, "POSITION")[:, 1]) > 0.8
    res = run("decode", tmp_path / "pole.gspc", "-o", tmp_path / "out.spz", "--no-refine")
    assert res.exit_code == 0 and read_spz(tmp_path / "out.spz").coordinates is None


@pytest.mark.slow
def test_no_warning_and_one_line_refusals_under_python_w_error(tmp_path):
    """The commands as a user runs them, with every warning an error."""
    env = {**os.environ, "GSPC_THREADS": "1"}

    def gspc(*args):
        cmd = [sys.executable, "-W", "error", "-m", "gspc.cli", *map(str, args)]
        return subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)

    source = DATA / "synth_sh3.v4.spz"
    for name in ("o.spz", "o.glb"):
        res = gspc("convert", source, "-o", tmp_path / name)
        assert res.returncode == 0 and "arning" not in res.stderr, res.stderr
    encode(source, tmp_path / "s.gspc", opts=FAST)
    res = gspc("decode", tmp_path / "s.gspc", "-o", tmp_path / "d.glb", "--no-refine")
    assert res.returncode == 0 and "arning" not in res.stderr, res.stderr
    for output, words in (
        (tmp_path / "d.xyz", "name the output .ply, .spz or .glb"),
        (tmp_path, "is a folder"),
    ):
        res = gspc("decode", tmp_path / "s.gspc", "-o", output)
        lines = res.stderr.strip().splitlines()
        assert res.returncode == 1 and len(lines) == 1 and words in lines[0], res.stderr
    assert not (tmp_path / "d.xyz").exists()


def test_header_records_the_convention_and_ignores_what_names_none():
    assert SceneSummary(3, 1, 4, "RUB").to_dict()["coordinates"] == "RUB"
    assert "coordinates" not in SceneSummary(3, 1, 4).to_dict()
    assert SceneSummary.from_dict({"scene": {"num_gaussians": 3, "coordinates": "LUF"}}).coordinates == "LUF"
    for junk in ("up", 6, ["RUB"], "x" * 10_000):
        assert (
            SceneSummary.from_dict({"scene": {"num_gaussians": 3, "coordinates": junk}}).coordinates is None
        )
