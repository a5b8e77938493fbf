"""Small scenes for tests and tools/fuzz_inputs.py: a plausible object (a blob of Gaussians around the
origin, :func:`random_scene`, every distribution a keyword), unbounded scenes (an object with a background
shell and far floaters) for the contracted grid and its far set, a cloud with far faint floaters for framing
views, a box whose statistics are known in closed form; :func:`with_shells` surrounds a real object with
shells of large Gaussians (tools/bench_precision.py); :func:`spz_range_scene` stays inside what SPZ
represents."""

import math
from dataclasses import dataclass

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.scene import GaussianScene, make_scene
from gspc.views import robust_bounds


def random_scene(
    n: int = 300,
    sh_degree: int = 1,
    seed: int = 0,
    log_scale: float = -3.0,
    opacity_logit: float = 1.0,
    dc_std: float = 0.5,
    rest_std: float = 0.1,
    spread: float = 0.3,
    scale_std: float = 0.3,
    opacity_std: float = 1.0,
    far: float = 1.0,
    dtype: torch.dtype = torch.float32,
    **over,
) -> GaussianScene:
    """``n`` Gaussians about the origin, every attribute normal: positions of std ``spread``, log scales
    ``log_scale`` +- ``scale_std``, opacity logits ``opacity_logit`` +- ``opacity_std``, colours (DC) of std
    ``dc_std``, SH rest of std ``rest_std``. ``far`` moves the first tenth that many times further out (a
    background far away: a contracted grid). ``over`` replaces any of make_scene's arrays; every array is
    drawn all the same, so the others do not depend on what is replaced."""
    g = np.random.default_rng(seed)
    k = (sh_degree + 1) ** 2 - 1
    attrs = dict(
        means=g.normal(0, spread, (n, 3)),
        quats=g.normal(0, 1, (n, 4)),
        log_scales=g.normal(log_scale, scale_std, (n, 3)),
        opacities=g.normal(opacity_logit, opacity_std, n),
        sh_dc=g.normal(0, dc_std, (n, 3)),
        sh_rest=g.normal(0, rest_std, (n, k, 3)),
    )
    attrs.update(over)
    scene = make_scene(**attrs, sh_degree=sh_degree, dtype=dtype)
    if far != 1.0:
        scene.means[: n // 10] *= far
    return scene


def coarse_residual_scene(seed: int = 1) -> GaussianScene:
    """200 Gaussians of SH degree 2, larger, more opaque and more colourful than :func:`random_scene`'s: at a
    coarse rate (lam 40) their residuals are clearly above the skip threshold, so side information is sent."""
    return random_scene(
        200, sh_degree=2, seed=seed, log_scale=-2.8, opacity_logit=1.5, dc_std=0.6, rest_std=0.2
    )


def floater_scene(n: int = 3000, seed: int = 0, floaters: int = 30) -> GaussianScene:
    """A normal cloud (std 2, 1, 0.5 about (5, -3, 1)) whose first ``floaters`` Gaussians are far (std 500)
    and faint: bounds and synthesised views must frame the cloud, not them."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([2.0, 1.0, 0.5]) + torch.tensor([5.0, -3.0, 1.0])
    opac = torch.full((n,), 2.0)
    means[:floaters] = torch.randn(floaters, 3, generator=g) * 500
    opac[:floaters] = -4.0
    return make_scene(
        means, torch.randn(n, 4, generator=g), torch.full((n, 3), -3.0), opac, torch.zeros(n, 3)
    )


def box_scene(n: int = 1000, degree: int = 3, seed: int = 1) -> GaussianScene:
    """Gaussians uniform in the box [-1, 1] x [-1, 3] x [-1, 5], all of size 0.01, DC 0 (grey) and SH rest
    0.1; the first quarter transparent (logit -10), the rest half opaque: statistics known in closed form."""
    g = torch.Generator().manual_seed(seed)
    k = (degree + 1) ** 2 - 1
    means = torch.rand(n, 3, generator=g) * torch.tensor([2.0, 4.0, 6.0]) - 1.0
    return GaussianScene(
        means=means,
        quats=torch.randn(n, 4, generator=g),
        log_scales=torch.full((n, 3), math.log(0.01)),
        opacities=torch.cat([torch.full((n // 4,), -10.0), torch.full((n - n // 4,), 0.0)]),
        sh_dc=torch.zeros(n, 3),
        sh_rest=torch.full((n, k, 3), 0.1),
        sh_degree=degree,
    )


def varied_scene(n: int = 500, degree: int = 3, seed: int = 0, **over) -> GaussianScene:
    """Gaussians spread widely in every attribute (sizes over e^-4 +- 1, opacities over every level, half of
    them with SH rest), for the codec's tests; ``over`` replaces any of make_scene's arrays."""
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    attrs = dict(
        means=rng.normal(size=(n, 3)),
        quats=rng.normal(size=(n, 4)),
        log_scales=rng.normal(-4, 1, size=(n, 3)),
        opacities=rng.normal(1, 2, size=n),
        sh_dc=rng.normal(size=(n, 3)),
        sh_rest=rng.normal(0, 0.05, size=(n, k, 3)) * (rng.uniform(size=(n, 1, 1)) < 0.5),
    )
    attrs.update(over)
    return make_scene(**attrs, sh_degree=degree)


def spz_range_scene(n: int = 300, degree: int = 3, seed: int = 3) -> GaussianScene:
    """Values inside what SPZ represents (log scales in [-10, 6), SH rest in [-1, 1], colours within its
    bytes), higher SH bands weaker as in trained scenes: its round trips measure SPZ's steps alone."""
    rng = np.random.default_rng(seed)
    k = (degree + 1) ** 2 - 1
    return make_scene(
        rng.uniform(-5, 5, (n, 3)),
        rng.normal(size=(n, 4)),
        rng.uniform(-9, 2, (n, 3)),
        rng.uniform(-6, 6, n),
        rng.uniform(-3, 3, (n, 3)),
        rng.uniform(-0.95, 0.95, (n, k, 3)) * np.linspace(1, 0.3, max(k, 1))[None, :k, None],
        degree,
    )


def glossy_scene(n: int = 30_000, seed: int = 0, opacity: float = 1.5) -> GaussianScene:
    """An object of strongly view-dependent colour (SH degree 3, bands as strong as the DC, decaying gently
    with degree), the kind of glossy material whose SH the codec's fixed SH rules would cost most.
    ``opacity``: the mean opacity logit (1.5: mostly opaque; -1: mostly faint, as trained captures are)."""
    g = np.random.default_rng(seed)
    k = 15
    decay = np.repeat([1.0, 0.8, 0.6], [3, 5, 7])[None, :, None]
    return make_scene(
        g.normal(0, 0.3, (n, 3)),
        g.normal(0, 1, (n, 4)),
        g.normal(-3.6, 0.3, (n, 3)),
        g.normal(opacity, 1.0, n),
        g.normal(0, 0.5, (n, 3)),
        g.normal(0, 0.35, (n, k, 3)) * decay,
        3,
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


@dataclass(frozen=True)
class Shells:
    """Shells of large Gaussians around an object, as a far wall or sky, and far floaters; distances in the
    object's radii (its robust box's half diagonal, as gspc/views.py synthesize_views frames it)."""

    radii: tuple[float, ...] = (10.0, 30.0, 100.0)  # one shell at each
    fraction: float = 0.02  # each shell holds this fraction of the object's count (at least one)
    jitter: float = 0.1  # a shell Gaussian's distance: its shell's radius x U(1 - jitter, 1 + jitter)
    floaters: int = 20
    floater_radii: tuple[float, float] = (200.0, 1000.0)  # floaters' distances, log-uniform between
    # Sizes grow in proportion to distance, by one factor for every added Gaussian: the one that makes a
    # shell's Gaussians (by their longest axes) cover ``cover`` x its sphere (sum of pi sigma^2 over
    # 4 pi d^2), so each shell is a sky behind the object rather than a scatter of stars.
    cover: float = 1.0
    seed: int = 0

    def counts(self, n: int) -> tuple[int, ...]:
        """Gaussians in each shell for an object of ``n``, then the floaters."""
        return (*(max(1, round(self.fraction * n)) for _ in self.radii), self.floaters)


def with_shells(obj: GaussianScene, shells: Shells = Shells()) -> GaussianScene:
    """``obj`` (first, unchanged) followed by ``shells``: each added Gaussian copies a random object
    Gaussian's attributes (so colours, opacities and shapes are real ones), is placed in a uniformly random
    direction from the object's centre, and has its scales grown in proportion to its distance (see
    :class:`Shells`). Deterministic in ``shells.seed``."""
    rng = np.random.default_rng(shells.seed)
    lo, hi = robust_bounds(obj)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2)
    counts = shells.counts(obj.num_gaussians)
    spread = (1 - shells.jitter, 1 + shells.jitter)
    dist = [r * rng.uniform(*spread, c) for r, c in zip(shells.radii, counts)]
    dist.append(np.exp(rng.uniform(*np.log(shells.floater_radii), counts[-1])))
    d = np.concatenate(dist) * radius  # world distances from the centre
    direction = rng.normal(size=(d.size, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    src = torch.from_numpy(rng.integers(0, obj.num_gaussians, d.size))
    added = {k: v[src].detach().clone() for k, v in obj.tensors().items()}
    added["means"] = torch.from_numpy(centre + direction * d[:, None]).to(obj.means.dtype)
    # Each copy keeps its shape, its longest axis set to sigma = d * angle, where a shell's m Gaussians of
    # that angle cover its sphere ``cover`` times: m pi angle^2 = 4 pi cover.
    angle = np.sqrt(4.0 * shells.cover / counts[0])
    longest = added["log_scales"].max(dim=1, keepdim=True).values
    size = torch.from_numpy(np.log(d * angle)).to(obj.log_scales.dtype)
    added["log_scales"] = added["log_scales"] - longest + size[:, None]
    merged = {k: torch.cat([v.detach(), added[k]]) for k, v in obj.tensors().items()}
    return GaussianScene(**merged, sh_degree=obj.sh_degree)
