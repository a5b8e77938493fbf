"""gspc's SPZ and .glb files read by other people's tools: splat-transform's SPZ reader and the Khronos glTF
validator. They run under Node from a folder outside the repository (nothing is downloaded at test time);
the tests skip where it is missing:

  npm install --prefix NPM_DIR @playcanvas/splat-transform@3.7.0 gltf-validator@2.0.0-dev.3.10
  GSPC_NPM_DIR=NPM_DIR python -m pytest tests/test_viewer_tools.py     (NPM_DIR defaults to /tmp/gspc-spz-npm)
"""

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import torch
from scenes import random_scene, spz_range_scene

from gspc.io import read_ply, read_spz, write_glb, write_spz

NPM_DIR = Path(os.environ.get("GSPC_NPM_DIR", "/tmp/gspc-spz-npm"))
TOOLS = Path(__file__).resolve().parents[1] / "tools"


def needs(package: str) -> Path:
    if shutil.which("node") is None or not (NPM_DIR / "node_modules" / package).is_dir():
        pytest.skip(f"{package} is not installed under {NPM_DIR} (see this file's docstring)")
    return NPM_DIR


def node(*args, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=300, cwd=cwd)


@pytest.mark.parametrize("version,stated", [(2, False), (3, False), (3, True), (4, True)])
def test_splat_transform_reads_our_spz_as_we_do(tmp_path, version, stated):
    npm = needs("@playcanvas/splat-transform")
    scene = spz_range_scene(n=200, degree=3)
    scene.coordinates = "RUB" if stated else None  # stated: written as RDF with a coordinate record
    write_spz(scene, tmp_path / "s.spz", version=version)
    cli = npm / "node_modules" / ".bin" / "splat-transform"
    res = node(cli, "-w", tmp_path / "s.spz", tmp_path / "s.ply", cwd=tmp_path)
    assert res.returncode == 0, res.stdout + res.stderr
    ours, theirs = read_spz(tmp_path / "s.spz"), read_ply(tmp_path / "s.ply")
    for attr in ("means", "quats", "log_scales", "opacities", "sh_dc", "sh_rest"):
        torch.testing.assert_close(getattr(theirs, attr), getattr(ours, attr), atol=1e-6, rtol=0, msg=attr)


@pytest.mark.parametrize("degree", [0, 3])
def test_the_gltf_validator_finds_nothing_but_the_extensions_attribute_names(tmp_path, degree):
    """The validator (its last release) predates KHR_gaussian_splatting: it reports the extension as one it
    cannot check, and each of the extension's namespaced attributes as an invalid core attribute name. Any
    other error or warning (framing, alignment, accessor bounds, buffer lengths) fails."""
    npm = needs("gltf-validator")
    write_glb(random_scene(300, sh_degree=degree, seed=12), tmp_path / "s.glb")
    res = node("node", TOOLS / "validate_gltf.mjs", npm, tmp_path / "s.glb")
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    messages = report["issues"]["messages"]
    errors = [m for m in messages if m["severity"] == 0]
    assert len(errors) == 4 + (degree + 1) ** 2 - 1  # rotation, scale, opacity and each SH coefficient
    for m in errors:
        assert m["code"] == "MESH_PRIMITIVE_INVALID_ATTRIBUTE", m
        assert m["pointer"].startswith("/meshes/0/primitives/0/attributes/KHR_gaussian_splatting:"), m
    others = {(m["code"], m["severity"]) for m in messages if m["severity"] != 0}
    assert others == {("UNSUPPORTED_EXTENSION", 2)} and report["issues"]["numWarnings"] == 0
    assert report["info"]["totalVertexCount"] == 300 and report["info"]["drawCallCount"] == 1
