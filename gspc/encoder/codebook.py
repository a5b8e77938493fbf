"""The encoder's codebook for the SH rest (attribute codec version 5, spec 10.16): which entries, and which
entry each Gaussian takes.

Weighted k-means over the SH rest of the Gaussians that carry one, each Gaussian weighted by what it paints
in the encoder's views (its blending weight: an entry's error shows in proportion), fitted on a sample and
then every Gaussian given its nearest entry as the decoder decodes it. Entries no Gaussian takes are
dropped, and the rest ordered by how many take them, so the indices the codec context-codes are small
where they are common. Deterministic: a fixed seed, so the same input gives the same file on every worker.
Whether a codebook pays is the encoder's trial (gspc/encoder/removal.py), not this module's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from gspc.codec.attributes import SHCodebook

# Entries per coded Gaussian at lambda 1, falling as 1 / lambda and kept within MIN_ENTRIES and the rules'
# most: on the lego fit (SOG's palette or not) more entries pay at finer rates, and 1,024 of its 20k
# Gaussians lost to the codec at lambda 4 where 4,096 gained (bench/precision.md, "The SH rest by codebook").
ENTRIES_PER_GAUSSIAN = 1.0
MIN_ENTRIES = 256
# Rows x entries under which the distances are computed in binary64 (see _nearest).
SMALL_PRODUCTS = 1 << 20


def codebook_entries(coded: int, lam: float, most: int) -> int:
    """How many entries a codebook for ``coded`` Gaussians at rate ``lam`` fits, at most ``most``."""
    return int(min(most, coded, max(MIN_ENTRIES, round(ENTRIES_PER_GAUSSIAN * coded / lam))))


@dataclass(frozen=True)
class CodebookParams:
    """The fit's knobs: Lloyd iterations, and sample rows per entry it fits on (every row when fewer), at
    most ``max_sample``: the fit's cost is sample rows x entries."""

    iterations: int = 8
    sample_per_entry: int = 16
    max_sample: int = 1 << 15
    seed_per_entry: int = 4  # rows per entry the seeds are drawn from, at most max_sample / 4
    block: int = 2048  # rows per distance block: their distances to every entry stay in cache
    seed: int = 0


def fit_codebook(
    rest: np.ndarray,
    rows: np.ndarray,
    weight: np.ndarray,
    entries: int,
    steps: np.ndarray,
    params: CodebookParams = CodebookParams(),
) -> SHCodebook:
    """A codebook of at most ``entries`` for the SH rest ``rest`` (N x K x 3, the input scene's) of the input
    Gaussians ``rows``, each weighted by ``weight`` (N, its blending weight), entries coded at ``steps``
    (K, class 0's ``sh_steps``); ``index`` is -1 outside ``rows``."""
    x = rest[rows].reshape(len(rows), -1).astype(np.float64)
    w = np.maximum(weight[rows].astype(np.float64), 0.0) + 1e-12
    step = np.repeat(np.asarray(steps, np.float64), 3)  # column 3 k + ch has coefficient k's step
    centres = _kmeans(x, w, entries, params)
    symbols = np.round(centres / step).astype(np.int64)
    symbols = np.unique(symbols, axis=0)  # entries that quantise alike are one
    index = _nearest(x, symbols * step, params.block)
    counts = np.bincount(index, minlength=len(symbols))
    order = np.lexsort((np.arange(len(symbols)), -counts))
    order = order[counts[order] > 0]
    remap = np.full(len(symbols), -1, np.int64)
    remap[order] = np.arange(len(order))
    full = np.full(len(rest), -1, np.int64)
    full[rows] = remap[index]
    return SHCodebook(symbols[order], full)


def _kmeans(x: np.ndarray, w: np.ndarray, entries: int, params: CodebookParams) -> np.ndarray:
    """Weighted Lloyd iterations on a weighted sample of ``x``; an entry no sample row takes keeps its
    place."""
    rng = np.random.default_rng(params.seed)
    n = len(x)
    if n <= entries:
        return x.copy()
    size = min(n, entries * params.sample_per_entry, params.max_sample)
    sample = np.sort(rng.choice(n, size, replace=False)) if size < n else np.arange(n)
    xs, ws = x[sample], w[sample]
    centres = _seeds(xs, ws, entries, params, rng)
    for _ in range(params.iterations):
        index = _nearest(xs, centres, params.block)
        total = np.bincount(index, weights=ws, minlength=entries)
        taken = total > 0
        for c in range(x.shape[1]):
            sums = np.bincount(index, weights=ws * xs[:, c], minlength=entries)
            centres[taken, c] = sums[taken] / total[taken]
    return centres


def _seeds(
    x: np.ndarray, w: np.ndarray, entries: int, params: CodebookParams, rng: np.random.Generator
) -> np.ndarray:
    """k-means++ seeds on at most ``seed_per_entry`` rows per entry: each next seed drawn in proportion to
    weight x squared distance from the seeds so far, so that no cluster starts with two seeds and another
    with none (Lloyd's iterations do not move a seed across a gap)."""
    rows = max(entries, min(entries * params.seed_per_entry, params.max_sample // 4))
    if len(x) > rows:
        pick = np.sort(rng.choice(len(x), rows, replace=False))
        x, w = x[pick], w[pick]
    first = int(rng.choice(len(x), p=w / w.sum()))
    centres = np.empty((entries, x.shape[1]))
    centres[0] = x[first]
    dist = ((x - x[first]) ** 2).sum(1)
    for c in range(1, entries):
        p = w * dist
        total = p.sum()
        nxt = int(rng.choice(len(x), p=p / total)) if total > 0 else c % len(x)
        centres[c] = x[nxt]
        np.minimum(dist, ((x - x[nxt]) ** 2).sum(1), out=dist)
    return centres


def _nearest(x: np.ndarray, centres: np.ndarray, block: int) -> np.ndarray:
    """Each row's nearest centre (squared distance; ties: the lower index), the products in binary32 where
    there are many: the fit's cost is these products. A few are in binary64, so that a small scene (the
    conformance vectors) codes the same bytes on every CPU whatever its binary32 kernels round."""
    dtype = torch.float32 if len(x) * len(centres) > SMALL_PRODUCTS else torch.float64
    c = torch.from_numpy(centres).to(dtype)
    norms = (c * c).sum(1)
    out = np.empty(len(x), np.int64)
    for a in range(0, len(x), block):
        xb = torch.from_numpy(x[a : a + block]).to(dtype)
        out[a : a + block] = torch.argmin(torch.addmm(norms[None, :], xb, c.T, alpha=-2.0), dim=1).numpy()
    return out
