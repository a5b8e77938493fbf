import io
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from input_files import SH_C0, make_compressed_ply
from plyfile import PlyData, PlyElement
from scenes import random_scene
from sog_files import make_sog

from gspc.errors import InputError
from gspc.io import read_compressed_ply, read_ply, read_scene, read_sog, write_ply
from gspc.io.ply import inria_bytes_per_gaussian
from gspc.scene import scene_equal

# ---------------------------------------------------------------- INRIA PLY


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_ply_round_trip_is_bit_exact(tmp_path, degree):
    scene = random_scene(7, sh_degree=degree)
    write_ply(scene, tmp_path / "s.ply")
    back = read_ply(tmp_path / "s.ply")
    assert back.sh_degree == degree
    assert scene_equal(scene, back)
    assert (tmp_path / "s.ply").stat().st_size > 7 * inria_bytes_per_gaussian(degree)


def test_ply_layout_is_inria_channel_major(tmp_path):
    scene = random_scene(7, sh_degree=2)
    write_ply(scene, tmp_path / "s.ply")
    ply = PlyData.read(str(tmp_path / "s.ply"))
    assert not ply.text and ply.byte_order == "<"
    names = list(ply["vertex"].data.dtype.names)
    assert names[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert names[-8:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert len(names) * 4 == inria_bytes_per_gaussian(2)
    data = ply["vertex"].data
    # f_rest_j for j in [c*K, (c+1)*K) is coefficient j - c*K of channel c.
    assert np.array_equal(data["f_rest_1"], scene.sh_rest[:, 1, 0].numpy())
    assert np.array_equal(data["f_rest_8"], scene.sh_rest[:, 0, 1].numpy())
    assert np.array_equal(data["f_rest_23"], scene.sh_rest[:, 7, 2].numpy())
    assert np.array_equal(data["rot_0"], scene.quats[:, 0].numpy())
    assert not data["nx"].any()


def test_ply_extras_and_normals_are_kept(tmp_path):
    scene = random_scene(7, sh_degree=1)
    normals = np.arange(7, dtype=np.float32)
    scene.extra = {
        "red": np.arange(7, dtype=np.uint8),
        "nx": normals,
        "ny": normals,
        "nz": normals,
        "w": np.ones(7),
    }
    write_ply(scene, tmp_path / "s.ply")
    back = read_ply(tmp_path / "s.ply")
    assert scene_equal(scene, back)
    assert set(back.extra) == {"red", "nx", "ny", "nz", "w"}
    assert back.extra["red"].dtype == np.uint8 and np.array_equal(back.extra["red"], scene.extra["red"])
    assert back.extra["w"].dtype == np.float64
    assert np.array_equal(back.extra["nz"], normals)


@pytest.mark.parametrize("text,order", [(True, "="), (False, ">")])
def test_ply_reads_ascii_and_big_endian(tmp_path, text, order):
    scene = random_scene(4, sh_degree=3)
    write_ply(scene, tmp_path / "le.ply")
    ply = PlyData.read(str(tmp_path / "le.ply"))
    PlyData([PlyElement.describe(ply["vertex"].data, "vertex")], text=text, byte_order=order).write(
        str(tmp_path / "other.ply")
    )
    assert scene_equal(scene, read_ply(tmp_path / "other.ply"))


def test_ply_write_is_atomic(tmp_path):
    good = random_scene(7, sh_degree=0)
    write_ply(good, tmp_path / "s.ply")
    before = (tmp_path / "s.ply").read_bytes()
    bad = random_scene(7, sh_degree=0)
    bad.means[0, 0] = float("nan")
    with pytest.raises(InputError):
        write_ply(bad, tmp_path / "s.ply")
    assert (tmp_path / "s.ply").read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["s.ply"]
    with pytest.raises(InputError, match="output directory"):
        write_ply(good, tmp_path / "no" / "s.ply")


def _write_vertex(path: Path, columns: dict[str, np.ndarray], dtype: str = "<f4") -> None:
    arr = np.empty(len(next(iter(columns.values()))), dtype=[(k, dtype) for k in columns])
    for k, v in columns.items():
        arr[k] = v
    PlyData([PlyElement.describe(arr, "vertex")]).write(str(path))


def _inria_columns(n: int = 3, n_rest: int = 0) -> dict[str, np.ndarray]:
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", *[f"f_rest_{i}" for i in range(n_rest)]]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    return {k: np.full(n, 0.5, np.float32) for k in names}


def test_ply_errors(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        read_scene(tmp_path / "absent.ply")
    (tmp_path / "text.ply").write_text("hello world\n")
    with pytest.raises(InputError, match="unrecognised scene file"):
        read_scene(tmp_path / "text.ply")
    with pytest.raises(InputError, match="not a PLY file"):
        read_ply(tmp_path / "text.ply")
    (tmp_path / "empty.ply").write_bytes(b"")
    with pytest.raises(InputError, match="empty"):
        read_scene(tmp_path / "empty.ply")


def test_ply_truncated(tmp_path):
    write_ply(random_scene(50, sh_degree=1), tmp_path / "s.ply")
    data = (tmp_path / "s.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[: len(data) - 100])
    with pytest.raises(InputError, match="truncated"):
        read_scene(tmp_path / "cut.ply")
    (tmp_path / "header.ply").write_bytes(data[:40])
    with pytest.raises(InputError, match="truncated"):
        read_scene(tmp_path / "header.ply")


def test_ply_missing_properties_are_named(tmp_path):
    cols = _inria_columns()
    del cols["scale_1"], cols["rot_3"]
    _write_vertex(tmp_path / "m.ply", cols)
    with pytest.raises(InputError, match="missing vertex properties: scale_1, rot_3"):
        read_scene(tmp_path / "m.ply")


def test_ply_bad_sh_count(tmp_path):
    _write_vertex(tmp_path / "sh.ply", _inria_columns(n_rest=6))
    with pytest.raises(InputError, match="6 f_rest properties match no SH degree"):
        read_scene(tmp_path / "sh.ply")
    _write_vertex(tmp_path / "sh4.ply", _inria_columns(n_rest=4))
    with pytest.raises(InputError, match="not a multiple of 3"):
        read_scene(tmp_path / "sh4.ply")


def test_ply_nan_and_inf(tmp_path):
    cols = _inria_columns(n=4)
    cols["opacity"][2] = np.nan
    _write_vertex(tmp_path / "nan.ply", cols)
    with pytest.raises(InputError, match="opacities has NaN or Inf values in 1 Gaussian"):
        read_scene(tmp_path / "nan.ply")
    cols = _inria_columns(n=4)
    cols["y"][:2] = np.inf
    _write_vertex(tmp_path / "inf.ply", cols)
    with pytest.raises(InputError, match="means has NaN or Inf values in 2 Gaussian"):
        read_scene(tmp_path / "inf.ply")


def test_ply_infinite_opacity_logits_mean_alpha_one_and_zero(tmp_path):
    """splat-transform's compressed-PLY reader and spz-js write +-inf logits for alpha 1 and 0."""
    cols = _inria_columns(n=3)
    cols["opacity"][:2] = [np.inf, -np.inf]
    _write_vertex(tmp_path / "inf.ply", cols)
    scene = read_scene(tmp_path / "inf.ply")
    alpha = torch.sigmoid(scene.opacities)
    assert torch.isfinite(scene.opacities).all()
    assert alpha[0] == 1.0 and 1.0 - alpha[1] == 1.0  # exactly, in float32
    assert scene.opacities[2] == 0.5  # finite logits untouched
    cols["opacity"][2] = np.nan
    _write_vertex(tmp_path / "nan.ply", cols)
    with pytest.raises(InputError, match="attribute opacities has NaN"):
        read_scene(tmp_path / "nan.ply")


@pytest.mark.parametrize("tiny", [1e-30, 1e-40])  # 1e-40 is subnormal in float32
def test_ply_tiny_quaternion_is_normalised(tmp_path, tiny):
    cols = _inria_columns(n=2)
    cols["rot_0"][0], cols["rot_1"][0], cols["rot_2"][0], cols["rot_3"][0] = tiny, 2 * tiny, 0.0, -2 * tiny
    _write_vertex(tmp_path / "tiny.ply", cols)
    scene = read_scene(tmp_path / "tiny.ply")
    stored = np.array([tiny, 2 * tiny, 0.0, -2 * tiny], np.float32).astype(np.float64)  # subnormals round
    np.testing.assert_allclose(scene.quats[0].numpy(), stored / np.linalg.norm(stored), rtol=1e-6)
    np.testing.assert_allclose(scene.quats[0].numpy(), [1 / 3, 2 / 3, 0, -2 / 3], rtol=1e-4)
    assert torch.equal(scene.quats[1], torch.full((4,), 0.5))  # ordinary rows keep their bits


@pytest.mark.filterwarnings("error")
def test_ply_huge_quaternion_is_normalised(tmp_path):
    """Issue 50: (3e38, 3e38, 3e38, 3e38) is a direction; its float32 norm overflows, so it is made unit
    length where it is read rather than turning into an all-zero rotation inside the encoder."""
    cols = _inria_columns(n=2)
    cols["rot_0"][0], cols["rot_1"][0], cols["rot_2"][0], cols["rot_3"][0] = 3e38, 3e38, 3e38, -3e38
    _write_vertex(tmp_path / "huge.ply", cols)
    scene = read_scene(tmp_path / "huge.ply")
    np.testing.assert_allclose(scene.quats[0].numpy(), [0.5, 0.5, 0.5, -0.5], rtol=1e-6)
    assert torch.equal(scene.quats[1], torch.full((4,), 0.5))


def test_ply_zero_and_non_finite_quaternions_are_refused(tmp_path):
    cols = _inria_columns(n=3)
    for name in ("rot_0", "rot_1", "rot_2", "rot_3"):
        cols[name][1] = 0.0
    _write_vertex(tmp_path / "zero.ply", cols)
    with pytest.raises(InputError, match="1 Gaussian\\(s\\) have an all-zero rotation quaternion"):
        read_scene(tmp_path / "zero.ply")
    cols = _inria_columns(n=3)
    cols["rot_2"][0] = np.inf
    _write_vertex(tmp_path / "inf.ply", cols)
    with pytest.raises(InputError, match="attribute quats has NaN or Inf"):
        read_scene(tmp_path / "inf.ply")


def test_ply_doubles_beyond_float32_are_named(tmp_path):
    cols = {k: v.astype(np.float64) for k, v in _inria_columns(n=3).items()}
    _write_vertex(tmp_path / "ok.ply", cols, "<f8")
    assert read_scene(tmp_path / "ok.ply").means[0, 0] == 0.5
    cols["scale_1"][2] = -1e300
    cols["opacity"][0] = np.inf  # an infinite double is still the alpha-1 logit, not an overflow
    _write_vertex(tmp_path / "big.ply", cols, "<f8")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a clear error, not numpy's overflow warning
        with pytest.raises(InputError, match="property 'scale_1' has 1 value\\(s\\) beyond float32's range"):
            read_scene(tmp_path / "big.ply")
    cols["scale_1"][2] = 0.5
    _write_vertex(tmp_path / "inf.ply", cols, "<f8")
    assert torch.sigmoid(read_scene(tmp_path / "inf.ply").opacities[0]) == 1.0


def test_ply_zero_gaussians(tmp_path):
    _write_vertex(tmp_path / "zero.ply", _inria_columns(n=0))
    with pytest.raises(InputError, match="zero Gaussians"):
        read_scene(tmp_path / "zero.ply")


# ---------------------------------------------------------------- SOG


@pytest.mark.parametrize("bands", [0, 1, 3])
def test_sog_decodes_known_values(tmp_path, bands):
    exp = make_sog(tmp_path / "s.sog", bands=bands)
    scene = read_scene(tmp_path / "s.sog")
    assert scene.sh_degree == bands and scene.num_gaussians == 10
    np.testing.assert_allclose(scene.means.numpy(), exp["means"], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(scene.log_scales.numpy(), exp["log_scales"], rtol=1e-6)
    np.testing.assert_allclose(scene.sh_dc.numpy(), exp["sh_dc"], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(scene.sh_rest.numpy(), exp["sh_rest"], rtol=1e-6, atol=1e-7)
    # 8-bit smallest-three: each kept component is within half a step of 1/sqrt2 / 255 * 2.
    np.testing.assert_allclose(scene.quats.numpy(), exp["quats"], atol=0.01)
    np.testing.assert_allclose(scene.quats.norm(dim=1).numpy(), 1.0, atol=1e-6)
    alpha = torch.sigmoid(scene.opacities.double()).numpy()
    np.testing.assert_allclose(alpha[2:], exp["alpha"][2:], atol=1e-6)
    assert alpha[0] < 1e-5 and alpha[1] > 1 - 1e-5  # 0 and 255 clamp to finite logits


def test_sog_folder_layout(tmp_path):
    exp = make_sog(tmp_path / "s.sog")
    folder = tmp_path / "unzipped"
    with zipfile.ZipFile(tmp_path / "s.sog") as z:
        z.extractall(folder)
    a = read_scene(folder)
    b = read_sog(folder / "meta.json")
    assert scene_equal(a, b) and scene_equal(a, read_scene(tmp_path / "s.sog"))
    np.testing.assert_allclose(a.log_scales.numpy(), exp["log_scales"], rtol=1e-6)


def test_sog_errors(tmp_path):
    (tmp_path / "bad.sog").write_bytes(b"PK\x03\x04 this is not really a zip")
    with pytest.raises(InputError, match="not a readable SOG zip"):
        read_scene(tmp_path / "bad.sog")

    make_sog(tmp_path / "v1.sog", meta_override=lambda m: m.update(version=1))
    with pytest.raises(InputError, match="SOG version 1 is not supported"):
        read_scene(tmp_path / "v1.sog")

    make_sog(tmp_path / "zero.sog", meta_override=lambda m: m.update(count=0))
    with pytest.raises(InputError, match="zero Gaussians"):
        read_scene(tmp_path / "zero.sog")

    make_sog(tmp_path / "big.sog", meta_override=lambda m: m.update(count=13))
    with pytest.raises(InputError, match="12 pixels for 13 Gaussians"):
        read_scene(tmp_path / "big.sog")

    make_sog(tmp_path / "book.sog", meta_override=lambda m: m["scales"].update(codebook=[1.0, 2.0]))
    with pytest.raises(InputError, match="scales.codebook"):
        read_scene(tmp_path / "book.sog")

    make_sog(tmp_path / "nan.sog", meta_override=lambda m: m["means"].update(mins=[float("nan"), 0, 0]))
    with pytest.raises(InputError, match="means.mins"):
        read_scene(tmp_path / "nan.sog")

    make_sog(tmp_path / "nofile.sog", meta_override=lambda m: m["quats"].update(files=["gone.webp"]))
    with pytest.raises(InputError, match="no member 'gone.webp'"):
        read_scene(tmp_path / "nofile.sog")

    make_sog(tmp_path / "nokey.sog", meta_override=lambda m: m.pop("sh0"))
    with pytest.raises(InputError, match="lacks 'sh0'"):
        read_scene(tmp_path / "nokey.sog")

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("meta.json", "{not json")
    (tmp_path / "json.sog").write_bytes(buf.getvalue())
    with pytest.raises(InputError, match="meta.json is not valid JSON"):
        read_scene(tmp_path / "json.sog")

    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("other.txt", "x")
    (tmp_path / "nometa.sog").write_bytes(buf.getvalue())
    with pytest.raises(InputError, match="no member 'meta.json'"):
        read_scene(tmp_path / "nometa.sog")


# ---------------------------------------------------------------- PlayCanvas compressed PLY


@pytest.mark.parametrize("colour_bounds,sh_bands", [(False, 0), (True, 0), (True, 2)])
def test_compressed_ply_decodes_known_values(tmp_path, colour_bounds, sh_bands):
    exp = make_compressed_ply(tmp_path / "c.ply", colour_bounds=colour_bounds, sh_bands=sh_bands)
    scene = read_scene(tmp_path / "c.ply")
    assert scene.num_gaussians == 300 and scene.sh_degree == sh_bands
    np.testing.assert_allclose(scene.means.numpy(), exp["means"], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(scene.log_scales.numpy(), exp["log_scales"], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(scene.sh_dc.numpy(), exp["sh_dc"], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(scene.sh_rest.numpy(), exp["sh_rest"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(scene.quats.numpy(), exp["quats"], atol=2e-3)
    alpha = torch.sigmoid(scene.opacities.double()).numpy()
    inner = (exp["alpha"] > 0) & (exp["alpha"] < 1)
    np.testing.assert_allclose(alpha[inner], exp["alpha"][inner], atol=1e-6)
    assert scene_equal(scene, read_compressed_ply(tmp_path / "c.ply"))


def test_compressed_ply_errors(tmp_path):
    make_compressed_ply(tmp_path / "c.ply", n=300)
    ply = PlyData.read(str(tmp_path / "c.ply"))
    chunk = ply["chunk"].data
    fewer = np.empty(1, dtype=chunk.dtype)
    fewer[:] = chunk[:1]
    PlyData([PlyElement.describe(fewer, "chunk"), ply["vertex"]]).write(str(tmp_path / "few.ply"))
    with pytest.raises(InputError, match="1 chunks cannot hold 300 splats"):
        read_scene(tmp_path / "few.ply")

    keep = [n for n in chunk.dtype.names if n != "max_scale_y"]
    partial = np.empty(len(chunk), dtype=[(n, "<f4") for n in keep])
    for n in keep:
        partial[n] = chunk[n]
    PlyData([PlyElement.describe(partial, "chunk"), ply["vertex"]]).write(str(tmp_path / "miss.ply"))
    with pytest.raises(InputError, match="missing chunk properties: max_scale_y"):
        read_scene(tmp_path / "miss.ply")

    write_ply(random_scene(7, sh_degree=0), tmp_path / "inria.ply")
    with pytest.raises(InputError, match="not a compressed PLY"):
        read_compressed_ply(tmp_path / "inria.ply")


@pytest.mark.filterwarnings("error")
def test_compressed_ply_bad_values_are_named_where_read(tmp_path):
    """Issue 50: a packed field stored as float holding NaN (once cast to an integer with a numpy warning),
    and a chunk bound of inf (once interpolated into NaN), are named by the reader."""
    make_compressed_ply(tmp_path / "c.ply", n=300)
    ply = PlyData.read(str(tmp_path / "c.ply"))
    vertex = ply["vertex"].data
    floats = np.empty(len(vertex), dtype=[(n, "<f4") for n in vertex.dtype.names])
    for n in vertex.dtype.names:
        floats[n] = vertex[n]
    floats["packed_scale"][7] = np.nan
    PlyData([ply["chunk"], PlyElement.describe(floats, "vertex")]).write(str(tmp_path / "nan.ply"))
    with pytest.raises(InputError, match="'packed_scale' holds nan"):
        read_scene(tmp_path / "nan.ply")
    ply["chunk"].data["min_y"][0] = -np.inf
    PlyData([ply["chunk"], ply["vertex"]]).write(str(tmp_path / "inf.ply"))
    with pytest.raises(InputError, match="'min_y' holds -inf"):
        read_scene(tmp_path / "inf.ply")


# ---------------------------------------------------------------- real files (../shared/data)

REAL = {
    "donut/fused.ply": 45_624,
    "statues/angel-kneeling.sog": 83_547,
    "statues/angel-with-candlestick.sog": 80_821,
    "statues/angel.sog": 71_359,
    "statues/massa.sog": 58_649,
    "statues/trumpet.sog": 89_292,
    "statues/angel.compressed.ply": 71_377,
}


@pytest.mark.parametrize("name", list(REAL))
def test_real_scenes_load_sanely(shared_data, name):
    scene = read_scene(shared_data / name)
    assert scene.num_gaussians == REAL[name]
    assert scene.sh_degree == 0
    if not name.endswith("fused.ply"):  # quantised formats store unit quaternions
        np.testing.assert_allclose(scene.quats.norm(dim=1).numpy(), 1.0, atol=1e-5)
    alpha = torch.sigmoid(scene.opacities)
    assert 0.3 < alpha.mean() < 0.7
    colour = 0.5 + SH_C0 * scene.sh_dc
    assert 0.1 < colour.median() < 0.9
    assert ((colour > -0.1) & (colour < 1.1)).float().mean() > 0.95
    extent = scene.means.quantile(0.99, dim=0) - scene.means.quantile(0.01, dim=0)
    scales = scene.log_scales.exp()
    # An object: its median splat is far smaller than the object, which is not degenerate in any axis.
    assert (extent > 0.05).all() and scales.median() < 0.05 * extent.max()


def test_real_sog_and_compressed_ply_agree(shared_data):
    """angel.sog and angel.compressed.ply are two encodings of one scene (SOG turned 180 deg about z)."""
    from scipy.spatial import cKDTree

    sog = read_scene(shared_data / "statues/angel.sog")
    cply = read_scene(shared_data / "statues/angel.compressed.ply")
    flipped = cply.means.numpy() * np.array([-1.0, -1.0, 1.0], np.float32)
    dist, idx = cKDTree(sog.means.numpy()).query(flipped)
    close = dist < 2e-3
    assert close.mean() > 0.99
    assert np.median(np.abs(cply.sh_dc.numpy()[close] - sog.sh_dc.numpy()[idx[close]])) < 1e-3
    assert np.median(np.abs(cply.log_scales.numpy()[close] - sog.log_scales.numpy()[idx[close]])) < 0.05
    # Rotating by 180 deg about z maps quaternion (w, x, y, z) to (-z, -y, x, w) (up to sign).
    a = cply.quats.numpy()[close]
    a = np.stack([-a[:, 3], -a[:, 2], a[:, 1], a[:, 0]], 1)
    b = sog.quats.numpy()[idx[close]]
    assert np.median(np.abs((a * b).sum(1))) > 0.999
