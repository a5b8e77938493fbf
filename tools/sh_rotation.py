"""Rotating a Gaussian's view-dependent colour: the matrix that turns real SH coefficients of degrees 1-3
(gspc/render/sh.py's basis and order) with a rotation of the scene.

A Gaussian turned by R must show from direction ``d`` the colour it showed from ``R^T d``. Each band of
degree l is closed under rotation, so the new coefficients of a band are a (2l+1)x(2l+1) matrix times the
old ones: fitted by least squares from the basis at well-spread directions and at those directions turned
back, which is exact for band-limited functions (any set of directions on which the band's basis has full
rank gives the same matrix).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from gspc.render.sh import sh_basis
from gspc.scene import num_sh_rest

# Directions for the fit: far more than a band's 7 functions, spread evenly, so the least squares is
# well conditioned for every band.
FIT_DIRECTIONS = 64


def sphere_directions(n: int) -> np.ndarray:
    """``n`` unit vectors on a Fibonacci sphere (float64, (n, 3))."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def _basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    return sh_basis(torch.from_numpy(dirs), degree).numpy()


def sh_rest_rotation(R: np.ndarray, degree: int) -> np.ndarray:
    """(K, K) block-diagonal matrix M, K = num_sh_rest(degree), with new_rest[:, j] = sum_k M[j, k] rest[:, k]
    for a scene turned by the rotation matrix ``R`` (coefficient-major SH rest, as GaussianScene holds it)."""
    k = num_sh_rest(degree)
    M = np.zeros((k, k))
    if degree == 0:
        return M
    dirs = sphere_directions(FIT_DIRECTIONS)
    before = _basis(dirs, degree)  # Y(d)
    after = _basis(dirs @ np.asarray(R, np.float64), degree)  # Y(R^T d): rows d^T R = (R^T d)^T
    for band in range(1, degree + 1):
        lo, hi = band * band, (band + 1) * (band + 1)  # the band's columns, DC at column 0
        # Y_band(R^T d) = A Y_band(d) at every direction, and the new coefficients are A^T c: A^T solves
        # Y_band(d)^T A^T = Y_band(R^T d)^T row by row.
        A_t, *_ = np.linalg.lstsq(before[:, lo:hi], after[:, lo:hi], rcond=None)
        M[lo - 1 : hi - 1, lo - 1 : hi - 1] = A_t
    return M


def rotate_sh_rest(rest: np.ndarray, R: np.ndarray, degree: int) -> np.ndarray:
    """SH rest (N, K, 3) of Gaussians turned by ``R``."""
    return np.einsum("jk,nkc->njc", sh_rest_rotation(R, degree), rest)
