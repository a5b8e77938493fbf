"""Small random scenes for tests that need a plausible object (a blob of Gaussians around the origin)."""

import numpy as np

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
