"""Coordinate conventions: which way a scene's x, y and z axes point, and moving a scene between them.

A convention is named by three letters, one per axis in x, y, z order (gspc/format/coordinates.py): R or L
(right, left), U or D (up, down), B or F (back, front); for example "RUB" (OpenGL, three.js), "RDF" (OpenCV,
INRIA PLY, COLMAP), "LUF" (glTF) and "RFU" (Z-up, as Blender).

A scene's ``coordinates`` is the convention its arrays are in when its source stated one (an SPZ file's
coordinate-system record, a .gspc header); None when the source said nothing. Writers whose format implies
a convention take an unstated scene to be in OPENCV, the convention of the INRIA PLY files 3DGS training
writes and the one the viewers read SPZ and PLY in (bench/outputs.md, "Coordinate conventions").

Moving a scene between conventions is a signed permutation of its axes ``A``: positions become ``A p``, a
rotation R becomes ``A R A^T`` (quaternion vector part ``det(A) A v``, w unchanged), scales follow the
permutation, and each SH band is mixed by the matrix that carries the band's basis functions along.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from gspc.errors import InputError
from gspc.format.coordinates import CONVENTIONS
from gspc.scene import GaussianScene

OPENCV = "RDF"  # what gspc takes a scene whose source stated nothing to be in
GLTF = "LUF"  # glTF 2.0: +Y up, +Z front, right-handed
# Letter -> (axis of RUB it lies along, sign).
_DIRECTIONS = {"R": (0, 1), "L": (0, -1), "U": (1, 1), "D": (1, -1), "B": (2, 1), "F": (2, -1)}
_NORMALS = ("nx", "ny", "nz")  # PLY normals kept in scene.extra move with the axes


def check_convention(name: object, source: object = "coordinates") -> str:
    """``name`` if it names a convention; InputError listing the names otherwise."""
    if isinstance(name, str) and name in CONVENTIONS:
        return name
    text = repr(name)
    text = text if len(text) <= 20 else text[:17] + "..."
    raise InputError(f"{source}: {text} is not a coordinate convention (one of {', '.join(CONVENTIONS)})")


def axes(name: str) -> np.ndarray:
    """3x3 integer matrix whose column i is the direction of axis i of ``name``, in RUB coordinates."""
    m = np.zeros((3, 3), np.int64)
    for i, letter in enumerate(check_convention(name)):
        axis, sign = _DIRECTIONS[letter]
        m[axis, i] = sign
    return m


def transform(src: str, dst: str) -> np.ndarray:
    """The signed permutation taking coordinates in ``src`` to coordinates in ``dst``."""
    return axes(dst).T @ axes(src)


def is_right_handed(name: str) -> bool:
    return round(np.linalg.det(axes(name))) == 1


def oriented(scene: GaussianScene, dst: str) -> GaussianScene:
    """``scene`` with its arrays in convention ``dst`` (an unstated scene is taken to be in OPENCV).

    The result states ``dst`` only when the scene stated its own convention: an assumption is no statement.
    """
    src = scene.coordinates or OPENCV
    a = transform(src, check_convention(dst))
    stated = dst if scene.coordinates is not None else None
    if np.array_equal(a, np.eye(3, dtype=np.int64)):
        return replace(scene, coordinates=stated)
    order = np.abs(a).argmax(axis=1)  # new axis i is old axis order[i]
    sign = a[np.arange(3), order]

    def move(t: torch.Tensor) -> torch.Tensor:
        return t[:, torch.as_tensor(order)] * torch.as_tensor(sign, dtype=t.dtype, device=t.device)

    det = int(round(np.linalg.det(a)))
    quats = torch.cat([scene.quats[:, :1], move(scene.quats[:, 1:]) * det], dim=1)
    extra = dict(scene.extra)
    if all(name in extra for name in _NORMALS):
        normals = move(torch.from_numpy(np.stack([np.asarray(extra[n]) for n in _NORMALS], axis=1)))
        extra.update({name: normals[:, i].numpy() for i, name in enumerate(_NORMALS)})
    return replace(
        scene,
        means=move(scene.means),
        quats=quats,
        log_scales=scene.log_scales[:, torch.as_tensor(order)],
        sh_rest=_mix_sh(scene.sh_rest, scene.sh_degree, a),
        extra=extra,
        coordinates=stated,
    )


def sh_band_matrices(a: np.ndarray, degree: int) -> list[np.ndarray]:
    """For bands 1..degree, the matrix M with coefficients' = M coefficients (per colour channel) when
    directions move by the orthogonal ``a``: the colour seen along ``a d`` afterwards is the colour seen along
    ``d`` before. Fitted on sample directions (exact up to float64 rounding); entries within 1e-9 of an
    integer are snapped, so pure axis flips stay exact sign changes."""
    from gspc.render.sh import sh_basis  # the basis has one home; imported here, only when SH must move

    golden = np.pi * (3.0 - np.sqrt(5.0))  # 64 well-spread directions (a Fibonacci sphere)
    k = np.arange(64)
    z = 1.0 - (2.0 * k + 1.0) / 64
    r = np.sqrt(1.0 - z * z)
    dirs = np.stack([r * np.cos(golden * k), r * np.sin(golden * k), z], axis=1)
    before = sh_basis(torch.from_numpy(dirs), degree).numpy()
    after = sh_basis(torch.from_numpy(dirs @ a.T.astype(np.float64)), degree).numpy()
    out = []
    for band in range(1, degree + 1):
        cols = slice(band * band, (band + 1) * (band + 1))
        # sum_j c'_j Y_j(a d) = sum_j c_j Y_j(d) for every d: solve after @ M = before for the band.
        m, *_ = np.linalg.lstsq(after[:, cols], before[:, cols], rcond=None)
        snapped = np.round(m)
        out.append(np.where(np.abs(m - snapped) < 1e-9, snapped, m))
    return out


def _mix_sh(sh_rest: torch.Tensor, degree: int, a: np.ndarray) -> torch.Tensor:
    if degree == 0:
        return sh_rest
    out = torch.empty_like(sh_rest)
    for band, m in enumerate(sh_band_matrices(a, degree), start=1):
        cols = slice(band * band - 1, (band + 1) * (band + 1) - 1)
        mixed = torch.einsum("ij,njc->nic", torch.from_numpy(m), sh_rest[:, cols].double())
        out[:, cols] = mixed.to(sh_rest.dtype)
    return out
