"""Batches (issue 52): ``gspc encode`` over several scenes or a folder of them writes one file per scene, the
bytes a single-scene run writes; a scene that fails is one line of its own and the others go on."""

import pytest
from cli_runs import assert_one_line_error, run
from scenes import random_scene
from test_tiles import QUICK, scene

from gspc.batch import BatchScene, find_scenes, is_batch
from gspc.errors import InputError
from gspc.io import write_ply
from gspc.io.cameras_json import save_cameras_json
from gspc.options import EncodeOptions
from gspc.pipeline import encode
from gspc.views import synthesize_views

FLAGS = ["--tile-size", QUICK["tile_size"], "--views", QUICK["synth_views"], "--max-side", QUICK["max_side"]]
FLAGS += ["--no-side-info"]  # QUICK's
FLAGS += ["--no-removal-search", "--tune-iterations", 0]


def _scene_folder(d, s, cameras=True):
    d.mkdir(parents=True)
    write_ply(s, d / "point_cloud.ply")
    if cameras:
        save_cameras_json(synthesize_views(s, 3, 32, 32), d / "cameras.json")
    return d


def test_scenes_are_found_by_file_and_folder_layout(tmp_path):
    root = tmp_path / "scenes"
    _scene_folder(root / "b", random_scene(50, seed=1))
    _scene_folder(root / "a", random_scene(50, seed=2), cameras=False)
    write_ply(random_scene(50, seed=3), root / "c.ply")
    (root / "notes.txt").write_text("not a scene")
    (root / "empty").mkdir()
    found = find_scenes([root])
    assert [s.name for s in found] == ["a", "b", "c"]
    assert found[0].cameras is None and found[1].cameras == root / "b" / "cameras.json"
    assert found[1].path == root / "b" / "point_cloud.ply"
    assert find_scenes([root / "b"]) == [found[1]]  # a scene folder is one scene
    assert is_batch([root]) and is_batch([root / "c.ply", root / "c.ply"]) and not is_batch([root / "c.ply"])
    with pytest.raises(InputError, match="holds no scene"):
        find_scenes([root / "empty"])
    with pytest.raises(InputError, match="two scenes named c"):
        find_scenes([root / "c.ply", root])
    assert find_scenes([tmp_path / "missing.ply"]) == [BatchScene("missing", tmp_path / "missing.ply")]


@pytest.mark.slow
def test_a_batch_writes_each_scenes_own_bytes_and_goes_on_past_a_failure(tmp_path):
    root = tmp_path / "in"
    small = _scene_folder(root / "small", random_scene(300, sh_degree=1, seed=0))
    tiled = root / "tiled.ply"
    write_ply(scene(), tiled)
    (root / "broken.ply").write_bytes(b"ply\nformat nonsense\n")
    out = tmp_path / "out"
    res = run("encode", root, "-o", f"{out}/", *FLAGS, "--workers", 2)
    assert res.exit_code == 1, res.output
    lines = res.output.splitlines()
    assert [line for line in lines if line.startswith("error:")][0].startswith("error: broken:"), res.output
    assert sum(line.startswith("error:") for line in lines) == 1, res.output  # exit 1 says the rest
    assert "Traceback" not in res.output and "ok" in res.output
    assert sorted(p.name for p in out.iterdir()) == ["small.gspc", "tiled.gspc"]  # nothing of the broken one
    for name, src, cams in (
        ("small", small / "point_cloud.ply", small / "cameras.json"),
        ("tiled", tiled, None),
    ):
        one = tmp_path / f"{name}.gspc"
        encode(src, one, cams, EncodeOptions(**QUICK, workers=1))
        assert (out / f"{name}.gspc").read_bytes() == one.read_bytes(), name


def test_a_batch_takes_no_cameras_option_and_writes_into_a_folder(tmp_path):
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    write_ply(random_scene(50, seed=1), a)
    write_ply(random_scene(50, seed=2), b)
    assert_one_line_error(run("encode", a, b, "-o", tmp_path / "o", "--cameras", a), "--cameras")
    (tmp_path / "file").write_text("")
    assert_one_line_error(run("encode", a, b, "-o", tmp_path / "file"), "must name a folder")
