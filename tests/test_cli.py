"""End-to-end CLI runs on a tiny synthetic scene, and bad input giving one-line errors."""

import pytest
import torch
from cli_runs import assert_one_line_error, run

from gspc.io import read_scene


@pytest.mark.slow
def test_encode_decode_end_to_end(tmp_path, scene_file):
    gspc_file = tmp_path / "s.gspc"
    res = run("encode", scene_file, "-o", gspc_file, "--views", 6, "--max-side", 48)
    assert res.exit_code == 0, res.output
    assert gspc_file.stat().st_size > 0
    res = run("info", gspc_file)
    assert res.exit_code == 0, res.output
    assert "POSN" in res.output
    out = tmp_path / "out.ply"
    res = run("decode", gspc_file, "-o", out, "--iterations", 5)
    assert res.exit_code == 0, res.output
    dec = read_scene(out)
    assert dec.num_gaussians > 0 and dec.sh_degree == 1
    assert all(torch.isfinite(t).all() for t in dec.tensors().values())
    res = run("eval", scene_file, out, "--views", 2, "--max-side", 32)
    assert res.exit_code == 0 and "PSNR" in res.output, res.output
    res = run("decode", gspc_file, "-o", tmp_path / "free.ply", "--iterations", 2, "--no-cells")
    assert res.exit_code == 0, res.output


def test_info_and_render_scene(tmp_path, scene_file):
    res = run("info", scene_file)
    assert res.exit_code == 0, res.output
    res = run("render", scene_file, "-o", tmp_path / "imgs", "--views", 2, "--max-side", 32)
    assert res.exit_code == 0, res.output
    assert len(list((tmp_path / "imgs").glob("*.png"))) == 2


def test_convert_round_trip(tmp_path, scene_file):
    res = run("convert", scene_file, "-o", tmp_path / "c.ply")
    assert res.exit_code == 0, res.output
    assert read_scene(tmp_path / "c.ply").num_gaussians == read_scene(scene_file).num_gaussians


def test_bad_inputs_give_one_line_errors(tmp_path, scene_file):
    assert_one_line_error(run("info", tmp_path / "missing.ply"), "missing.ply")
    junk = tmp_path / "junk.ply"
    junk.write_bytes(b"hello world")
    assert_one_line_error(run("encode", junk, "-o", tmp_path / "x.gspc"), "junk.ply")
    assert not (tmp_path / "x.gspc").exists()
    notgspc = tmp_path / "n.gspc"
    notgspc.write_bytes(b"not a gspc file at all")
    assert_one_line_error(run("decode", notgspc, "-o", tmp_path / "o.ply"), "")
    assert not (tmp_path / "o.ply").exists()
    assert_one_line_error(
        run("encode", scene_file, "-o", tmp_path / "y.gspc", "--quality", "best"), "quality"
    )
    assert_one_line_error(
        run("encode", scene_file, "-o", tmp_path / "y.gspc", "--views-fraction", 0), "fraction"
    )
    badcams = tmp_path / "cams.json"
    badcams.write_text("{not json")
    assert_one_line_error(
        run("encode", scene_file, "-o", tmp_path / "y.gspc", "--cameras", badcams), "cams.json"
    )
    assert not (tmp_path / "y.gspc").exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the no-GPU message")
def test_cuda_request_without_gpu(tmp_path, scene_file):
    gspc_file = tmp_path / "s.gspc"
    assert run("encode", scene_file, "-o", gspc_file, "--views", 4, "--max-side", 32).exit_code == 0
    assert_one_line_error(run("decode", gspc_file, "-o", tmp_path / "o.ply", "--device", "cuda"), "cuda")
    assert not (tmp_path / "o.ply").exists()
    assert_one_line_error(run("render", scene_file, "-o", tmp_path / "imgs", "--device", "cuda"), "cuda")
    assert not (tmp_path / "imgs").exists()
    assert_one_line_error(run("eval", scene_file, scene_file, "--device", "cuda"), "cuda")
    assert_one_line_error(run("render", scene_file, "-o", tmp_path / "imgs", "--device", "tpu"), "tpu")


def test_corrupt_file_and_missing_restorer_give_one_line_errors(tmp_path, scene_file):
    from gspc.format import container

    gspc_file = tmp_path / "s.gspc"
    assert run("encode", scene_file, "-o", gspc_file, "--views", 4, "--max-side", 32).exit_code == 0
    data = bytearray(gspc_file.read_bytes())
    data[len(data) // 2] ^= 0x40  # a flipped bit inside a chunk
    corrupt = tmp_path / "corrupt.gspc"
    corrupt.write_bytes(bytes(data))
    assert_one_line_error(run("decode", corrupt, "-o", tmp_path / "o.ply"), "")
    assert not (tmp_path / "o.ply").exists()

    # A restorer the decoder lacks: refused where it would restore (spec 10.8), not where nothing is restored.
    sided = tmp_path / "sided.gspc"
    coarse = ("--lambda", 40, "--views", 5, "--max-side", 40, "--check-iterations", 0)
    assert run("encode", scene_file, "-o", sided, *coarse).exit_code == 0
    for source, restores in ((sided, True), (gspc_file, False)):
        c = container.read(source)
        assert (c.find("SIDE", 0) is not None) == restores
        c.header["side_info"]["restorer"] = "no-such-model"
        renamed = tmp_path / "renamed.gspc"
        container.write(renamed, c.header, c.chunks)
        res = run("decode", renamed, "-o", tmp_path / "o.ply")
        if restores:
            assert_one_line_error(res, "no-such-model")
            assert not (tmp_path / "o.ply").exists()
        else:
            assert res.exit_code == 0 and (tmp_path / "o.ply").exists()
            (tmp_path / "o.ply").unlink()
    assert_one_line_error(run("encode", scene_file, "-o", tmp_path / "x.gspc", "--restorer", "nope"), "nope")


def test_messages_print_square_brackets_as_written(tmp_path, scene_file, monkeypatch):
    # rich reads "[cuda]" as markup and drops it: first seen on a GPU, where the renderer's install hint
    # "pip install 'gspc[cuda]'" printed as "pip install 'gspc'".
    assert_one_line_error(run("info", tmp_path / "scene[cuda].ply"), "scene[cuda].ply")
    res = run("convert", scene_file, "-o", tmp_path / "out[1].ply")
    assert res.exit_code == 0 and "out[1].ply" in res.output, res.output
    import gspc.pipeline as pipeline

    monkeypatch.setattr(pipeline, "renderer_info", lambda *a, **k: "torch (pip install 'gspc[cuda]')")
    enc = tmp_path / "s.gspc"
    res = run("encode", scene_file, "-o", enc, "--views", 3, "--max-side", 24, "--no-side-info")
    assert res.exit_code == 0 and "'gspc[cuda]'" in " ".join(res.output.split()), res.output
