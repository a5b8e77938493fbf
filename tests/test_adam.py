"""gspc/adam.py: the fused Adam kernel without torch.optim, step for step the same as Adam(fused=True), and a
refinement that no longer imports torch's compiler."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from gspc.adam import FusedAdam

CUDA = torch.cuda.is_available()


def _params(seed: int, dtype: torch.dtype, device: str) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    shapes = [(50, 3), (50, 4), (50,), (50, 15, 3)]
    return [torch.randn(s, generator=g, dtype=dtype).to(device).requires_grad_(True) for s in shapes]


@pytest.mark.parametrize(
    "device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not CUDA, reason="needs a CUDA GPU"))]
)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_steps_are_bit_identical_to_torch_fused_adam(dtype, device):
    ours, theirs = _params(1, dtype, device), _params(1, dtype, device)
    mine = FusedAdam(
        [{"params": [p], "lr": 0.01 * (i + 1), "name": str(i)} for i, p in enumerate(ours)], eps=1e-15
    )
    ref = torch.optim.Adam(
        [{"params": [p], "lr": 0.01 * (i + 1)} for i, p in enumerate(theirs)], eps=1e-15, fused=True
    )
    g = torch.Generator().manual_seed(2)
    for step in range(6):
        scale = 10.0 ** (step % 3 - 1)
        grads = [torch.randn(p.shape, generator=g, dtype=dtype).to(device) * scale for p in ours]
        if step == 2:
            grads[1] = None  # a parameter without a gradient this step keeps its state (and its step count)
        for opt, params in ((mine, ours), (ref, theirs)):
            opt.zero_grad()
            for p, gr in zip(params, grads):
                p.grad = None if gr is None else gr.clone()
            for group, factor in zip(opt.param_groups, (1.0, 0.5, 0.25, 2.0)):
                group["lr"] = 0.01 * factor / (step + 1)  # the schedule changes rates between steps
            opt.step()
        for a, b in zip(ours, theirs):
            assert torch.equal(a, b)
    assert all(p.grad is not None for p in ours)
    mine.zero_grad()
    assert all(p.grad is None for p in ours)


def test_a_refinement_does_not_import_torchs_compiler():
    code = (
        "import sys, torch\n"
        "from gspc.refine import Refinement, Schedule\n"
        "from scenes import random_scene\n"
        "from gspc.views import synthesize_views\n"
        "s = random_scene(100, sh_degree=1, seed=0)\n"
        "cams = synthesize_views(s, 2, width=24, height=24)\n"
        "targets = [torch.rand(c.height, c.width, 3) for c in cams]\n"
        "Refinement(s, cams, targets, Schedule(2)).run()\n"
        "print('torch._dynamo' in sys.modules)\n"
    )
    tools = Path(__file__).resolve().parent.parent / "tools"  # scenes.py, as pytest's pythonpath has it
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tools), os.environ.get("PYTHONPATH", "")]))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
