"""Would a codebook of view-dependent colour pay (issue 51, item 3)? The SH rest as the attribute codec codes
it, against the SH rest as a vector-quantised codebook, each scored by its own error alone (every other
attribute the original's) at held-out views, before any codec version is built for it.

    GSPC_THREADS=1 python tools/bench_sh_codebook.py [--scenes lego,lego-sog,glossy,glossy-faint]

- **codec**: `encode_attributes` at the low preset's parameters with nothing removed (every Gaussian kept, so
  the error is the SH rest's alone) at each ``--lams``, with the preset's SH rules and with the SH trial's
  (every band of every Gaussian, no dead zone); bytes: the SHRS chunk.
- **codebook of E entries**: k-means of the SH rest vectors (K x 3 coefficients each) weighted by each
  Gaussian's blending weight over the encoder's views (gspc/encoder/significance.py, as the encoder would
  weigh them), ``--iterations`` Lloyd steps from E weighted-random rows; bytes: the entries at the codec's
  SH step of ``--entry-lambda`` (zstd of the 16-bit integers) plus each Gaussian's index at the empirical
  entropy of the indices (an ideal adaptive coder without context: what a context coder would have to beat).
  A palette source (lego-sog: SOG's own codebook) is also coded exactly: its distinct rows as entries, a
  byte a coefficient (SOG's 256-level codebook of coefficient values), indices as above.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, replace
from itertools import product

import numpy as np
import torch
import zstandard
from bench_setups import bench_scene, float_psnr, held_out

from gspc.cameras import Camera
from gspc.encoder.coding import encode_attributes
from gspc.encoder.params import SHRules
from gspc.encoder.significance import encoder_significance
from gspc.presets import quality_preset
from gspc.reconstruct import render_images
from gspc.scene import GaussianScene

# The codec's SH rules: the low preset's, and the trial's that keeps every band of every Gaussian.
RULES: dict[str, SHRules | None] = {
    "the preset's SH rules": None,
    "every band of every Gaussian": quality_preset("low").sh_options[0],
}


def with_rest(scene: GaussianScene, rest: np.ndarray) -> GaussianScene:
    """``scene`` with its SH rest replaced (float32, input order)."""
    coded = torch.as_tensor(rest, dtype=scene.sh_rest.dtype).reshape(scene.sh_rest.shape)
    return replace(scene, sh_rest=coded)


@dataclass(frozen=True)
class Scored:
    """A scene and its held-out views, where each coding of its SH rest is scored."""

    name: str
    scene: GaussianScene
    views: list[Camera]
    refs: list[torch.Tensor]
    background: tuple[float, float, float]

    def row(self, label: str, nbytes: float, rest: np.ndarray) -> None:
        coded = render_images(with_rest(self.scene, rest), self.views, self.background)
        p, n = float_psnr(coded, self.refs), self.scene.num_gaussians
        print(f"| {self.name} | {label} | {nbytes:,.0f} | {nbytes / n:.2f} | {p:.2f} |", flush=True)


def kmeans(
    x: np.ndarray, w: np.ndarray, k: int, iterations: int, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """(entries (k, D), each row's entry): weighted Lloyd steps from k rows drawn by weight."""
    g = np.random.default_rng(seed)
    p = w / w.sum()
    centres = x[g.choice(len(x), size=k, replace=False, p=p)].astype(np.float64)
    labels = np.zeros(len(x), dtype=np.int64)
    for _ in range(iterations):
        labels = nearest(x, centres)
        sums = np.zeros_like(centres)
        np.add.at(sums, labels, x * w[:, None])
        mass = np.bincount(labels, weights=w, minlength=k)
        filled = mass > 0
        centres[filled] = sums[filled] / mass[filled, None]
    return centres, nearest(x, centres)


def nearest(x: np.ndarray, centres: np.ndarray, block: int = 8192) -> np.ndarray:
    c2 = (centres**2).sum(axis=1)
    out = np.empty(len(x), dtype=np.int64)
    for i in range(0, len(x), block):
        xb = x[i : i + block]
        out[i : i + block] = np.argmin(c2[None, :] - 2.0 * xb @ centres.T, axis=1)
    return out


def entropy_bytes(labels: np.ndarray) -> float:
    counts = np.bincount(labels).astype(np.float64)
    p = counts[counts > 0] / len(labels)
    return float(-(p * np.log2(p)).sum() * len(labels) / 8.0)


def entry_bytes(entries: np.ndarray, step: float) -> int:
    q = np.round(entries / step).astype(np.int16)
    return len(zstandard.ZstdCompressor(level=19).compress(q.tobytes()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", default="lego,lego-sog,glossy,glossy-faint")
    ap.add_argument("--lams", default="2,4,8,16")
    ap.add_argument("--entries", default="256,1024,4096")
    ap.add_argument("--iterations", type=int, default=8)
    ap.add_argument("--entry-lambda", type=float, default=2.0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    low = quality_preset("low").attributes
    print("| scene | coding | SH rest bytes | B/G | held-out PSNR dB (SH rest error alone) |")
    print("|---|---|---:|---:|---:|")
    for name in args.scenes.split(","):
        scene, cams, bg = bench_scene(name)
        train, held = held_out(cams)
        scored = Scored(name, scene, held, render_images(scene, held, bg), bg)
        n = scene.num_gaussians
        x = scene.sh_rest.reshape(n, -1).double().numpy()
        sig = encoder_significance(scene, train, bg)
        every = replace(low, keep_invisible=True, keep_transparent=True)
        for (rules_name, rules), lam in product(RULES.items(), [float(v) for v in args.lams.split(",")]):
            params = every.with_lambda(lam) if rules is None else every.with_lambda(lam).with_sh_rules(rules)
            params = replace(params, precision=replace(params.precision, prune=0.0))
            enc = encode_attributes(scene, params, significance=sig)
            rest = np.zeros_like(x)
            rest[enc.kept] = enc.decoded.sh_rest.reshape(len(enc.kept), -1).double().numpy()
            scored.row(f"codec, {rules_name}, lambda {lam:g}", len(enc.chunks["SHRS"]), rest)
        step = low.sh_step * args.entry_lambda**low.sh_lam_exponent
        w = sig.weight + 1e-12
        for k in [int(v) for v in args.entries.split(",")]:
            entries, labels = kmeans(x, w, min(k, n), args.iterations)
            q = np.round(entries / step) * step
            scored.row(f"codebook {k}", entry_bytes(entries, step) + entropy_bytes(labels), q[labels])
        palette, labels = np.unique(x, axis=0, return_inverse=True)
        if len(palette) < n:  # a palette source: its own codebook, exactly, a byte a coefficient (SOG's)
            exact = palette.size + entropy_bytes(labels)
            scored.row(f"its palette ({len(palette)} entries, exact)", exact, x)


if __name__ == "__main__":
    main()
