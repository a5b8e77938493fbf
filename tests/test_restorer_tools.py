"""tools/make_restorer_data.py and tools/train_restorer.py on a tiny made-up scene."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from make_restorer_data import make_data, parse_rates, parse_scene, side_info_symbols
from scenes import random_scene

from gspc.codec import residuals
from gspc.io import write_ply
from gspc.restore.data import side_info_from_npz
from gspc.restore.restorer import load_restorer

TOOLS = Path(__file__).resolve().parents[1] / "tools"


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("restorer")
    for i in range(2):
        scene = random_scene(
            300, sh_degree=1, seed=i, spread=0.6, log_scale=-2.75, scale_std=0.45, dc_std=1.0, rest_std=0.3
        )
        write_ply(scene, root / f"s{i}.ply")
    specs = [
        parse_scene(f"{root / 's0.ply'},views=4"),
        parse_scene(f"{root / 's1.ply'},views=5,split=val,bg=1,fraction=0.6"),
    ]
    out = root / "data"
    doc = make_data(out, specs, parse_rates("low,12:6"), [2.0], max_side=40)
    assert len(doc["entries"]) == 2 * 4 + 2 * 3
    return out


def _train(data: Path, run: Path, *extra: str, ddp: int = 0) -> subprocess.CompletedProcess:
    args = [str(TOOLS / "train_restorer.py"), str(data), str(run), "--patch", "24", "--batch", "2"]
    args += ["--width", "8", "--epoch-steps", "2", "--log-every", "1", "--warmup", "1", *extra]
    if ddp:
        cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", str(ddp)]
        cmd += ["--master_port", "29517", *args]
    else:
        cmd = [sys.executable, *args]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    return res


def test_data_files_mirror_the_encoder(data_dir):
    doc = json.loads((data_dir / "manifest.json").read_text())
    e = doc["entries"][0]
    assert e["split"] == "train" and e["height"] == 40 and e["rate"] == "low"
    with np.load(data_dir / e["file"]) as z:
        assert z["degraded"].shape == (40, 40, 3)
        assert z["degraded"].min() >= 0 and z["degraded"].max() <= 1  # clamped renders
        assert len(z["distances"]) == 2
        assert int(z["scale_1"]) == e["scale"] == 2  # the low preset's half-resolution residuals
        assert side_info_from_npz(z, 1).shape == (40, 40, 3)
    # At full resolution (12:6) R~ is closer to R than zero is.
    e = next(e for e in doc["entries"] if e["rate"] == "lam12_d6")
    with np.load(data_dir / e["file"]) as z:
        r, rt = z["residual"].astype(np.float32), side_info_from_npz(z, 1)
        assert np.abs(rt).max() > 0 and np.abs(rt - r).mean() < np.abs(r).mean() + 1e-6
    # Resuming regenerates nothing: files keep their modification times.
    before = {p: p.stat().st_mtime_ns for p in data_dir.rglob("*.npz")}
    specs = [parse_scene(s["path"] + ",views=4") for s in doc["settings"]["scenes"][:1]]
    make_data(data_dir, specs, parse_rates("low,12:6"), [2.0], max_side=40)
    assert all(p.stat().st_mtime_ns == t for p, t in before.items())


@pytest.mark.parametrize("scale", [1, 2, 3])
def test_stored_side_info_is_what_the_decoder_gets(scale):
    r = np.random.default_rng(scale).normal(0, 0.05, (37, 29, 3)).astype(np.float32)
    sym = side_info_symbols(r, 4.0, scale=scale)
    z = {"residual": r, "q_0": sym["q"], "gain_0": sym["gain"], "offset_0": sym["offset"]}
    if scale != 1:
        z["scale_0"] = sym["scale"]
    payload, meta = residuals.encode_residual(r, residuals.ResidualParams(distance=4.0, scale=scale))
    assert np.array_equal(side_info_from_npz(z, 0), residuals.decode_residual(payload, meta))
    assert parse_rates("low,12:8:2")[1].scale == 2 and parse_rates("low")[0].scale >= 1


@pytest.mark.slow
def test_train_resume_ship_and_ddp(data_dir, tmp_path):
    straight, split = tmp_path / "a", tmp_path / "b"
    res = _train(data_dir, straight, "--steps", "4", "--ship", "tiny", "--weights-dir", str(tmp_path / "w"))
    _train(data_dir, split, "--steps", "4", "--stop-after", "2")
    assert not (split / "summary.json").exists()
    _train(data_dir, split, "--steps", "4")
    a = torch.load(straight / "last.pt", weights_only=True)
    b = torch.load(split / "last.pt", weights_only=True)
    assert a["step"] == b["step"] == 4
    for k, v in a["model"].items():
        assert torch.equal(v, b["model"][k]), k  # resuming continues the same run exactly
    rows = (straight / "log.csv").read_text().splitlines()
    assert rows[0].startswith("step,") and any(r.split(",")[-2] != "" for r in rows[1:])
    summary = json.loads((straight / "summary.json").read_text())
    assert set(summary["validation"]) == {"low", "lam12_d6"} and "shipped" in res.stdout
    restorer = load_restorer("tiny", weights_dir=tmp_path / "w")
    img = torch.rand(40, 40, 3)
    assert restorer.restore(img, torch.zeros_like(img)).shape == img.shape

    ddp = tmp_path / "ddp"
    _train(data_dir, ddp, "--steps", "2", ddp=2)
    ck = torch.load(ddp / "last.pt", weights_only=True)
    assert ck["step"] == 2 and len(ck["gen_states"]) == 2
