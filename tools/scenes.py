"""Small random scenes for tests and tools/fuzz_inputs.py: a plausible object (a blob of Gaussians around
the origin), and unbounded scenes (an object with a background shell and far floaters) for the contracted
grid and its far set."""

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.scene import GaussianScene, make_scene


def random_scene(
    n: int = 300,
    sh_degree: int = 1,
    seed: int = 0,
    log_scale: float = -3.0,
    opacity_logit: float = 1.0,
    dc_std: float = 0.5,
    rest_std: float = 0.1,
) -> GaussianScene:
    g = np.random.default_rng(seed)
    k = (sh_degree + 1) ** 2 - 1
    return make_scene(
        g.normal(0, 0.3, (n, 3)),
        g.normal(0, 1, (n, 4)),
        g.normal(log_scale, 0.3, (n, 3)),
        g.normal(opacity_logit, 1.0, n),
        g.normal(0, dc_std, (n, 3)),
        g.normal(0, rest_std, (n, k, 3)),
        sh_degree,
    )


def unbounded(seed: int = 0, n: int = 4000) -> np.ndarray:
    """An object (a unit ball) with 10% of its count in a shell at 30 radii and 5 floaters at 3000."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    obj = d * rng.uniform(0, 1, (n, 1)) ** (1 / 3)
    shell = d[: n // 10] * rng.uniform(27, 33, (n // 10, 1))
    far = d[:5] * 3000.0
    return np.concatenate([obj, shell, far]) + [5.0, -2.0, 1.0]


def far_sizes(x: np.ndarray, centre, grow: float) -> np.ndarray:
    """World sizes: 0.02 inside (the object's), growing as ``grow`` x the distance beyond 2 radii."""
    d = np.linalg.norm(x - centre, axis=1)
    return np.where(d > 2.0, grow * d, 0.02)


def far_scene(seed: int = 4):
    """An object with a background of large Gaussians (their size grows with their distance): version 3."""
    x = unbounded(seed, n=800)
    scene = random_scene(len(x), sh_degree=1, seed=seed)
    scene.means[:] = torch.from_numpy(x.astype(np.float32))
    sizes = far_sizes(x, x[:800].mean(0), 0.05)
    scene.log_scales[:] = torch.from_numpy(np.log(sizes).astype(np.float32))[:, None]
    return scene


def front_cameras(n=3, size=32) -> list[Camera]:
    """``n`` small cameras side by side, looking down +z at :func:`front_scene`."""
    cams = []
    for i in range(n):
        w2c = np.eye(4)
        w2c[0, 3] = 0.3 * (i - 1)  # small sideways shifts, all looking down +z
        K = np.array([[size, 0, size / 2], [0, size, size / 2], [0, 0, 1]], dtype=np.float64)
        cams.append(Camera(w2c, K, size, size, f"v{i}"))
    return cams


def front_scene(n=50, seed=0) -> GaussianScene:
    """``n`` Gaussians in a slab 2.5 in front of :func:`front_cameras`."""
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 3, generator=g) * torch.tensor([1.2, 1.2, 0.5]) + torch.tensor([-0.6, -0.6, 2.5])
    quats = torch.randn(n, 4, generator=g)
    log_scales = torch.full((n, 3), -2.5) + 0.3 * torch.randn(n, 3, generator=g)
    opacities = torch.randn(n, generator=g) + 1.0
    sh_dc = torch.randn(n, 3, generator=g)
    sh_rest = 0.1 * torch.randn(n, 3, 3, generator=g)
    return make_scene(means, quats, log_scales, opacities, sh_dc, sh_rest)
