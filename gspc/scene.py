"""GaussianScene: the one in-memory form of a 3DGS scene that every gspc module exchanges.

Attributes are stored as in INRIA's training code (the "raw" parameters the optimiser sees):
quaternions unnormalised (w, x, y, z), log scales, opacity logits, SH coefficients where the DC
term maps to colour as ``0.5 + SH_C0 * sh_dc``. ``sh_rest`` is coefficient-major, shape
``(N, K, 3)`` with ``K = (sh_degree + 1) ** 2 - 1``; the INRIA PLY stores it channel-major and
the PLY module converts.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import torch

from gspc.errors import InputError

ATTRIBUTE_NAMES = ("means", "quats", "log_scales", "opacities", "sh_dc", "sh_rest")
# The degree-0 SH basis constant 1 / (2 sqrt(pi)), as in INRIA 3DGS; the renderer, readers and statistics
# take it from here.
SH_C0 = 0.28209479177387814
# Quantised formats (SOG, compressed PLY, SPZ) store alpha in a few bits, where 0 and 1 have infinite
# logits: their readers clamp alpha into [OPACITY_EPS, 1 - OPACITY_EPS] first, as PlayCanvas's SOG reader
# and splat-transform's SPZ reader do.
OPACITY_EPS = 1e-6


def alpha_to_logit(alpha: np.ndarray) -> np.ndarray:
    """Opacity logits of activated opacities ``alpha`` (numpy), clamped as the formats' readers clamp."""
    a = np.clip(alpha, OPACITY_EPS, 1.0 - OPACITY_EPS)
    return np.log(a / (1.0 - a))


def num_sh_rest(sh_degree: int) -> int:
    """Number of non-DC SH coefficients per colour channel."""
    return (sh_degree + 1) ** 2 - 1


def sh_degree_from_rest(k: int) -> int:
    """Inverse of :func:`num_sh_rest`; raises InputError for counts that match no degree."""
    for d in range(4):
        if num_sh_rest(d) == k:
            return d
    raise InputError(f"{k} SH rest coefficients per channel match no SH degree 0-3")


@dataclass
class GaussianScene:
    means: torch.Tensor  # (N, 3)
    quats: torch.Tensor  # (N, 4) w, x, y, z; not necessarily unit length
    log_scales: torch.Tensor  # (N, 3)
    opacities: torch.Tensor  # (N,) logits
    sh_dc: torch.Tensor  # (N, 3)
    sh_rest: torch.Tensor  # (N, K, 3)
    sh_degree: int = 0
    # Per-Gaussian PLY properties gspc does not interpret (e.g. normals); kept for round trips.
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    # The axis convention the arrays are in as the source stated it ("RUB", "RDF", ...), None when it stated
    # none; writers convert to their format's convention (gspc/io/coordinates.py).
    coordinates: str | None = None

    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])

    def tensors(self) -> dict[str, torch.Tensor]:
        return {name: getattr(self, name) for name in ATTRIBUTE_NAMES}

    def map(self, fn) -> GaussianScene:
        """A new scene with ``fn`` applied to every attribute tensor."""
        return replace(self, **{k: fn(v) for k, v in self.tensors().items()})

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> GaussianScene:
        return self.map(lambda t: t.to(device=device, dtype=dtype))

    def detach(self) -> GaussianScene:
        return self.map(lambda t: t.detach().clone())

    def subset(self, index: torch.Tensor | np.ndarray) -> GaussianScene:
        """Gaussians selected by a boolean mask or an index array, extras included."""
        idx = torch.as_tensor(np.asarray(index)) if not isinstance(index, torch.Tensor) else index
        idx_np = idx.cpu().numpy()
        out = self.map(lambda t: t[idx.to(t.device)])
        out.extra = {k: v[idx_np] for k, v in self.extra.items()}
        return out

    @staticmethod
    def concat(parts: list[GaussianScene]) -> GaussianScene:
        """The Gaussians of ``parts`` one after another (one SH degree; extras common to all kept)."""
        if not parts:
            raise InputError("no Gaussians to join")
        degrees = {p.sh_degree for p in parts}
        if len(degrees) != 1:
            raise InputError(f"parts of SH degrees {sorted(degrees)} cannot be joined")
        tensors = {k: torch.cat([getattr(p, k) for p in parts]) for k in ATTRIBUTE_NAMES}
        names = set.intersection(*(set(p.extra) for p in parts))
        extra = {k: np.concatenate([p.extra[k] for p in parts]) for k in sorted(names)}
        return GaussianScene(
            **tensors, sh_degree=parts[0].sh_degree, extra=extra, coordinates=parts[0].coordinates
        )

    def validate(self) -> GaussianScene:
        """Check shapes and finiteness; returns self so it chains. Raises InputError."""
        n = self.num_gaussians
        if n == 0:
            raise InputError("scene has zero Gaussians")
        if not 0 <= self.sh_degree <= 3:
            raise InputError(f"SH degree {self.sh_degree} is outside 0-3")
        k = num_sh_rest(self.sh_degree)
        expected = {
            "means": (n, 3),
            "quats": (n, 4),
            "log_scales": (n, 3),
            "opacities": (n,),
            "sh_dc": (n, 3),
            "sh_rest": (n, k, 3),
        }
        for name, shape in expected.items():
            t = getattr(self, name)
            if tuple(t.shape) != shape:
                raise InputError(f"attribute {name} has shape {tuple(t.shape)}, expected {shape}")
            if not _all_finite(t):
                bad = int((~torch.isfinite(t)).reshape(n, -1).any(1).sum())
                raise InputError(f"attribute {name} has NaN or Inf values in {bad} Gaussian(s)")
        # Exactly zero, not a zero norm: a tiny quaternion's float32 norm underflows to 0 though its
        # direction is defined (readers normalise those, gspc/io/interop.py).
        zero = (self.quats == 0).all(dim=1)
        if zero.any():
            raise InputError(f"{int(zero.sum())} Gaussian(s) have an all-zero rotation quaternion")
        return self


def _all_finite(t: torch.Tensor, rows: int = 65536) -> bool:
    """torch.isfinite(t).all() in blocks of rows: whole, its temporaries would outweigh the SH rest of a
    large scene (bench/scale.md, "Reading")."""
    return all(bool(torch.isfinite(t[i : i + rows]).all()) for i in range(0, len(t), rows))


def with_drawn(scene: GaussianScene, drawn: GaussianScene | None) -> GaussianScene:
    """``scene`` with ``drawn`` after it (a tile's neighbours, rendered with it: spec 10.15), or ``scene``
    itself where there is none."""
    return scene if drawn is None else GaussianScene.concat([scene, drawn])


def make_scene(
    means,
    quats,
    log_scales,
    opacities,
    sh_dc,
    sh_rest=None,
    sh_degree: int | None = None,
    dtype: torch.dtype = torch.float32,
) -> GaussianScene:
    """Build a scene from arrays or tensors; ``sh_rest`` may be omitted for degree 0."""

    def t(x):
        if isinstance(x, torch.Tensor):
            return x.to(dtype)
        return torch.from_numpy(np.ascontiguousarray(x)).to(dtype)

    n = len(means)
    if sh_rest is None:
        sh_rest = torch.zeros(n, 0, 3)
    sh_rest = t(sh_rest)
    deg = sh_degree_from_rest(sh_rest.shape[1]) if sh_degree is None else sh_degree
    return GaussianScene(t(means), t(quats), t(log_scales), t(opacities).reshape(-1), t(sh_dc), sh_rest, deg)


def validate_named(scene: GaussianScene, source: object) -> GaussianScene:
    """``scene.validate()`` with the offending file or object named in the error."""
    try:
        return scene.validate()
    except InputError as err:
        raise InputError(f"{source}: {err}") from err


def scene_equal(a: GaussianScene, b: GaussianScene) -> bool:
    """Bit-exact equality of every attribute (used by codec and I/O tests)."""
    if a.sh_degree != b.sh_degree:
        return False
    return all(torch.equal(getattr(a, name), getattr(b, name)) for name in ATTRIBUTE_NAMES)
