"""gspc's compiled CPU kernels (numba, gspc/render/kernels.py JIT): whether this machine has compiled them,
and compiling them once as a stage of its own, so that a first run says why it starts slowly instead of
waiting silently inside its first render (bench/startup.md).
"""

from __future__ import annotations

import importlib
import os

import numpy as np

from gspc.progress import Progress

# The modules whose kernels numba compiles and caches (gspc/render/kernels.py JIT: cache=True).
KERNEL_MODULES = (
    "gspc.render.project_cpu",
    "gspc.render.composite_cpu",
    "gspc.codec.fit_cpu",
    "gspc.encoder.significance_cpu",
)
STAGE = "compile kernels (once per machine)"


def uncompiled_kernels(modules: tuple[str, ...] = KERNEL_MODULES) -> list[str]:
    """The cached kernels whose compiled form numba's cache lacks on this machine ("module.function")."""
    missing = []
    for name in modules:
        module = importlib.import_module(name)
        for attr, value in vars(module).items():
            cache_file = getattr(getattr(value, "_cache", None), "_cache_file", None)
            index = getattr(cache_file, "_index_path", None)
            if index is not None and not os.path.exists(index):
                missing.append(f"{name}.{attr}")
    return missing


def compile_kernels(progress: Progress | None, encoder: bool = False) -> bool:
    """Compile the CPU kernels a run uses where this machine has not: a small render forward and backward,
    and for the ``encoder`` a small measure and coding. Returns whether it compiled anything."""
    if not uncompiled_kernels():
        return False
    from gspc.cameras import Camera
    from gspc.render import render
    from gspc.scene import make_scene

    if progress:
        progress(STAGE, 0, 1)
    g = np.random.default_rng(0)
    n = 64
    scene = make_scene(
        g.normal(0, 0.2, (n, 3)) + [0, 0, 2],
        g.normal(0, 1, (n, 4)),
        np.full((n, 3), -3.0),
        np.full(n, 1.0),
        g.normal(0, 0.3, (n, 3)),
        g.normal(0, 0.05, (n, 15, 3)),
        3,
    )
    camera = Camera(np.eye(4), np.array([[16.0, 0, 8], [0, 16.0, 8], [0, 0, 1]]), 16, 16, "warm-up")
    moving = scene.map(lambda t: t.clone().requires_grad_(True))
    render(moving, camera).image.sum().backward()
    if encoder:
        from gspc.encoder.coding import encode_attributes
        from gspc.encoder.significance import encoder_significance
        from gspc.presets import quality_preset

        sig = encoder_significance(scene, [camera], (0.0, 0.0, 0.0))
        encode_attributes(scene, quality_preset("low").attributes, significance=sig)
    if progress:
        progress(STAGE, 1, 1)
    return True
