import os
from pathlib import Path

import pytest
import torch
from scenes import random_scene

from gspc.io import write_ply

# One thread: results do not depend on the machine's core count. The CLI's commands default to every
# core (gspc/cli.py), so the tests that run them in-process pin one too.
torch.set_num_threads(1)
os.environ.setdefault("GSPC_THREADS", "1")

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    """../shared/data beside the checkout; tests that need it skip cleanly without it."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not beside this checkout")
    return SHARED_DATA


@pytest.fixture
def scene_file(tmp_path) -> Path:
    """A tiny scene (300 Gaussians of SH degree 1) as a PLY file, for the command line's tests."""
    p = tmp_path / "scene.ply"
    write_ply(random_scene(300, sh_degree=1, seed=0), p)
    return p
