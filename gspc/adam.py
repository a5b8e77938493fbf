"""Adam for refinement: the kernel of ``torch.optim.Adam(fused=True)``, called without torch.optim.

torch.optim's Optimizer imports torch._dynamo (the compiler) the first time one is made, and nothing else
on gspc's paths does: seconds of every process that refines (the decoder, and the encoder's check), for a
compiler gspc never uses (bench/speed.md, "Encoder's model fitting and refinement's Adam"). This class
keeps Adam's state as that optimizer does (first and second moments, a float32 step count per tensor) and
runs the same fused kernel with the same arguments, so its steps are bit-identical to it
(tests/test_adam.py).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch


class FusedAdam:
    """Adam over parameter groups (dicts with ``params`` and ``lr``; other keys are kept and ignored), without
    weight decay or amsgrad. ``lr`` may change between steps, as the refinement's schedule does."""

    def __init__(self, groups: Sequence[dict], betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        self.param_groups = list(groups)
        self.betas, self.eps = betas, eps
        self._state: dict[int, tuple[torch.Tensor, ...]] = {}  # id(param) -> (param, m, v, step)

    def zero_grad(self) -> None:
        for g in self.param_groups:
            for p in g["params"]:
                p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One step of every parameter that has a gradient (the others keep their state untouched)."""
        for g in self.param_groups:
            # The kernel takes tensors of one device and dtype per call, as torch.optim groups them.
            by_kind: dict[tuple, list[list[torch.Tensor]]] = {}
            for p in g["params"]:
                if p.grad is None:
                    continue
                if id(p) not in self._state:
                    self._state[id(p)] = (
                        p,
                        torch.zeros_like(p, memory_format=torch.preserve_format),
                        torch.zeros_like(p, memory_format=torch.preserve_format),
                        torch.zeros((), dtype=torch.float32, device=p.device),
                    )
                _, m, v, t = self._state[id(p)]
                lists = by_kind.setdefault((p.device, p.dtype), [[], [], [], [], []])
                for lst, x in zip(lists, (p, p.grad, m, v, t)):
                    lst.append(x)
            for params, grads, ms, vs, steps in by_kind.values():
                torch._foreach_add_(steps, 1)
                torch._fused_adam_(
                    params,
                    grads,
                    ms,
                    vs,
                    [],
                    steps,
                    amsgrad=False,
                    lr=float(g["lr"]),
                    beta1=self.betas[0],
                    beta2=self.betas[1],
                    weight_decay=0.0,
                    eps=self.eps,
                    maximize=False,
                    grad_scale=None,
                    found_inf=None,
                )
