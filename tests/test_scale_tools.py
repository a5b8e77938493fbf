"""The scale workload builder (tools/make_scale_scenes.py, its assets in tools/scale_assets.py) and the CLI's
thread default (gspc/cli.py)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest
import scale_assets
import torch

from gspc import cli
from gspc.render.project import quat_to_rotmat
from gspc.workers import default_workers

ROOT = Path(__file__).resolve().parents[1]


def test_rotating_a_copy_turns_its_gaussians_with_it():
    # Turning means by R must turn every Gaussian's axes by R too: R(q * q0) = R(q) R(q0).
    R, q = scale_assets.axis_angle((0.0, 0.0, 1.0), 1.1)
    quats = np.random.default_rng(0).normal(size=(50, 4))
    turned = quat_to_rotmat(torch.from_numpy(scale_assets.quat_mul(q, quats)))
    before = quat_to_rotmat(torch.from_numpy(quats))
    for i in range(3):
        for j in range(3):
            expected = sum(R[i, k] * before[k][j] for k in range(3))
            assert torch.allclose(turned[i][j], expected, atol=1e-12)
    Rx, _ = scale_assets.axis_angle((1.0, 0.0, 0.0), math.pi / 2)
    assert np.allclose(
        Rx @ [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]
    )  # make_scale_scenes.py's turn of the statues: y onto z


def test_plan_keeps_copies_whole_and_lands_just_above_the_size():

    class Fake:
        def __init__(self, n: int):
            self.n = n

    assets = [Fake(n) for n in (71_359, 83_547, 80_821, 58_649, 89_292, 45_624, 20_000)]
    smallest = min(a.n for a in assets)
    for target in (100_000, 300_000, 1_000_000, 3_000_000):
        total = sum(assets[i].n for i in scale_assets.plan(assets, target))
        assert target <= total < target + smallest


def test_thread_default_is_one_and_the_cores_go_to_workers(monkeypatch):
    # gspc/cli.py DEFAULT_THREADS: threads that wait for each other slow a busy machine; the cores this
    # process may use are the workers' default (gspc/workers.py).
    expected = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert default_workers() == expected
    before = torch.get_num_threads()
    try:
        monkeypatch.setenv("GSPC_THREADS", "2")
        cli._use_threads()
        assert torch.get_num_threads() == min(2, expected)
        monkeypatch.delenv("GSPC_THREADS")
        cli._use_threads()
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


@pytest.mark.parametrize("value", ["", None])
def test_unset_or_empty_threads_means_the_default(monkeypatch, value):
    if value is None:
        monkeypatch.delenv("GSPC_THREADS", raising=False)
    else:
        monkeypatch.setenv("GSPC_THREADS", value)
    before = torch.get_num_threads()
    try:
        cli._use_threads()
        assert torch.get_num_threads() == cli.DEFAULT_THREADS
    finally:
        torch.set_num_threads(before)
