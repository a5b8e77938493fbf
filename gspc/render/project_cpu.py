"""project.py's projection compiled for the CPU (numba), forward and backward, one pass per Gaussian.

Why: in PyTorch the projection is about a hundred elementwise operations on N-long vectors, forward and
again backward (each a full pass over memory), and beside the compiled compositor (composite_cpu.py) it
takes a large share of a render's forward+backward time (bench/render.md, "Moved from code comments").
Here each Gaussian is projected, and differentiated, in registers.

Same conventions as project.py (its comments say why each step is as it is): EWA splatting with the
Jacobian's x/z, y/z clamped to the widened frustum, the low-pass added to the 2D covariance, the
alpha >= 1/255 box, colour max(SH + 0.5, 0) in INRIA's basis (sh.py). A Gaussian whose centre has
z <= NEAR gets the stand-in depth 1, extents -1 and zero gradients; never-drawn ones (extents -1) get colour 0
(nothing reads it) and cost no SH evaluation. Inputs are read in their own dtype
(float32 from a scene, float64 in the reference tests) and every number is float64 from there; outputs and
gradients are written back in the input dtype.

The backward is the chain rule taken by hand, in reverse (comments name each step); tests compare it with
autograd through project.py's PyTorch path.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from gspc.render.kernels import JIT, ROWS_PER_TASK, block_bounds, parallel
from gspc.render.rules import ALPHA_MIN, EXTENT_ABS_MARGIN, EXTENT_REL_MARGIN, LOWPASS, NEAR
from gspc.render.sh import C1, C2, C3
from gspc.scene import SH_C0

# Divisors (kernels.JIT has no zero checks): z > NEAR, |q| > 0, det > 0.
BASIS = 16  # SH basis functions up to degree 3
C2_0, C2_1, C2_2, C2_3, C2_4 = C2
C3_0, C3_1, C3_2, C3_3, C3_4, C3_5, C3_6 = C3
OUTPUTS = 10  # columns of the forward's outputs' gradient: u, v, conic a, b, c, opacity, r, g, b, depth


def camera_numbers(rot, t, centre, intrinsics, limits, size) -> np.ndarray:
    """The 25 numbers the kernels read (float64): world-to-camera rotation (row-major, 0-8), translation
    (9-11), camera centre (12-14), fx fy cx cy (15-18), x/z and y/z limits (19-22), width, height (23, 24)."""
    parts = [np.ravel(np.asarray(p, np.float64)) for p in (rot, t, centre, intrinsics, limits, size)]
    return np.concatenate(parts)


@numba.njit(inline="always", error_model="numpy")
def _basis(x, y, z, degree, out):
    """out[0 .. (degree + 1)^2 - 1] = Y_k(x, y, z) (gspc/render/sh.py)."""
    out[0] = SH_C0
    if degree >= 1:
        out[1], out[2], out[3] = -C1 * y, C1 * z, -C1 * x
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out[4] = C2_0 * x * y
        out[5] = C2_1 * y * z
        out[6] = C2_2 * (2.0 * zz - xx - yy)
        out[7] = C2_3 * x * z
        out[8] = C2_4 * (xx - yy)
        if degree >= 3:
            out[9] = C3_0 * y * (3.0 * xx - yy)
            out[10] = C3_1 * x * y * z
            out[11] = C3_2 * y * (4.0 * zz - xx - yy)
            out[12] = C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
            out[13] = C3_4 * x * (4.0 * zz - xx - yy)
            out[14] = C3_5 * z * (xx - yy)
            out[15] = C3_6 * x * (xx - 3.0 * yy)


@numba.njit(inline="always", error_model="numpy")
def _basis_grad(x, y, z, degree, g):
    """sum_k g[k] dY_k/d(x, y, z), for g[k] = dL/dY_k."""
    dx = dy = dz = 0.0
    if degree >= 1:
        dx, dy, dz = -C1 * g[3], -C1 * g[1], C1 * g[2]
    if degree >= 2:
        dx += C2_0 * y * g[4] + C2_3 * z * g[7] - 2.0 * C2_2 * x * g[6] + 2.0 * C2_4 * x * g[8]
        dy += C2_0 * x * g[4] + C2_1 * z * g[5] - 2.0 * C2_2 * y * g[6] - 2.0 * C2_4 * y * g[8]
        dz += C2_1 * y * g[5] + 4.0 * C2_2 * z * g[6] + C2_3 * x * g[7]
        if degree >= 3:
            xx, yy, zz = x * x, y * y, z * z
            dx += (
                6.0 * C3_0 * x * y * g[9]
                + C3_1 * y * z * g[10]
                - 2.0 * C3_2 * x * y * g[11]
                - 6.0 * C3_3 * x * z * g[12]
                + C3_4 * (4.0 * zz - 3.0 * xx - yy) * g[13]
                + 2.0 * C3_5 * x * z * g[14]
                + 3.0 * C3_6 * (xx - yy) * g[15]
            )
            dy += (
                3.0 * C3_0 * (xx - yy) * g[9]
                + C3_1 * x * z * g[10]
                + C3_2 * (4.0 * zz - xx - 3.0 * yy) * g[11]
                - 6.0 * C3_3 * y * z * g[12]
                - 2.0 * C3_4 * x * y * g[13]
                - 2.0 * C3_5 * y * z * g[14]
                - 6.0 * C3_6 * x * y * g[15]
            )
            dz += (
                C3_1 * x * y * g[10]
                + 8.0 * C3_2 * y * z * g[11]
                + C3_3 * (6.0 * zz - 3.0 * xx - 3.0 * yy) * g[12]
                + 8.0 * C3_4 * x * z * g[13]
                + C3_5 * (xx - yy) * g[14]
            )
    return dx, dy, dz


@numba.njit(inline="always", error_model="numpy")
def _geometry(i, means, quats, log_scales, cam, rq, jw, a, s, t):
    """The projection's shared first half for Gaussian i: fills rq (3, 3) the rotation of the normalised
    quaternion, jw (2, 3) the rows of J W, a (2, 3) = J W Rq, s (3,) the scales, t = a S (2, 3); returns the
    camera point (x, y, z with the stand-in depth), whether it is in front, the normalised quaternion and
    its norm, the clamped x/z, y/z with whether each was inside its limits, and the 2D covariance."""
    mx, my, mz = np.float64(means[i, 0]), np.float64(means[i, 1]), np.float64(means[i, 2])
    x = cam[0] * mx + cam[1] * my + cam[2] * mz + cam[9]
    y = cam[3] * mx + cam[4] * my + cam[5] * mz + cam[10]
    z = cam[6] * mx + cam[7] * my + cam[8] * mz + cam[11]
    front = z > NEAR
    if not front:
        z = 1.0
    # J W rows (project.py _screen_covariance), with x/z, y/z clamped to the widened frustum.
    rx, ry = x / z, y / z
    tx, ty = min(max(rx, cam[19]), cam[20]), min(max(ry, cam[21]), cam[22])
    sx, sy = cam[15] / z, cam[16] / z
    for k in range(3):
        jw[0, k] = sx * (cam[k] - tx * cam[6 + k])
        jw[1, k] = sy * (cam[3 + k] - ty * cam[6 + k])
    qw, qx = np.float64(quats[i, 0]), np.float64(quats[i, 1])
    qy, qz = np.float64(quats[i, 2]), np.float64(quats[i, 3])
    qn = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    w, x_, y_, z_ = qw / qn, qx / qn, qy / qn, qz / qn
    rq[0, 0] = 1.0 - 2.0 * (y_ * y_ + z_ * z_)
    rq[0, 1] = 2.0 * (x_ * y_ - w * z_)
    rq[0, 2] = 2.0 * (x_ * z_ + w * y_)
    rq[1, 0] = 2.0 * (x_ * y_ + w * z_)
    rq[1, 1] = 1.0 - 2.0 * (x_ * x_ + z_ * z_)
    rq[1, 2] = 2.0 * (y_ * z_ - w * x_)
    rq[2, 0] = 2.0 * (x_ * z_ - w * y_)
    rq[2, 1] = 2.0 * (y_ * z_ + w * x_)
    rq[2, 2] = 1.0 - 2.0 * (x_ * x_ + y_ * y_)
    # Sigma_2D = T T^T + low-pass, T = J W Rq S (no 3x3 covariance needed).
    for j in range(3):
        s[j] = math.exp(np.float64(log_scales[i, j]))
        for r in range(2):
            a[r, j] = jw[r, 0] * rq[0, j] + jw[r, 1] * rq[1, j] + jw[r, 2] * rq[2, j]
            t[r, j] = a[r, j] * s[j]
    cxx = t[0, 0] * t[0, 0] + t[0, 1] * t[0, 1] + t[0, 2] * t[0, 2] + LOWPASS
    cxy = t[0, 0] * t[1, 0] + t[0, 1] * t[1, 1] + t[0, 2] * t[1, 2]
    cyy = t[1, 0] * t[1, 0] + t[1, 1] * t[1, 1] + t[1, 2] * t[1, 2] + LOWPASS
    inside = (cam[19] <= rx <= cam[20], cam[21] <= ry <= cam[22])
    return x, y, z, front, (w, x_, y_, z_, qn), (tx, ty, inside[0], inside[1]), (cxx, cxy, cyy)


@numba.njit(inline="always", error_model="numpy")
def _direction(i, means, cam):
    """Unit direction from the camera centre to Gaussian i, and the distance."""
    dx = np.float64(means[i, 0]) - cam[12]
    dy = np.float64(means[i, 1]) - cam[13]
    dz = np.float64(means[i, 2]) - cam[14]
    dn = math.sqrt(dx * dx + dy * dy + dz * dz)
    return dx / dn, dy / dn, dz / dn, dn


@numba.njit(**JIT)
def _forward_rows(lo, hi, means, quats, log_scales, logits, sh_dc, sh_rest, cam, degree, outs):
    means2d, conics, opacities, colors, depths, extents = outs
    scratch = np.empty(30 + BASIS)
    rq, jw = scratch[0:9].reshape((3, 3)), scratch[9:15].reshape((2, 3))
    a, t = scratch[15:21].reshape((2, 3)), scratch[21:27].reshape((2, 3))
    s, basis = scratch[27:30], scratch[30 : 30 + BASIS]
    nb = (degree + 1) * (degree + 1)
    for i in range(lo, hi):
        x, y, z, front, _, _, cov = _geometry(i, means, quats, log_scales, cam, rq, jw, a, s, t)
        cxx, cxy, cyy = cov
        det = cxx * cyy - cxy * cxy
        u, v = cam[15] * x / z + cam[17], cam[16] * y / z + cam[18]
        o = 1.0 / (1.0 + math.exp(-np.float64(logits[i])))
        means2d[i, 0], means2d[i, 1] = u, v
        conics[i, 0], conics[i, 1], conics[i, 2] = cyy / det, -cxy / det, cxx / det
        opacities[i], depths[i] = o, z
        # The alpha >= 1/255 box (project.py alpha_extents); -1 when never drawn.
        thr = 2.0 * math.log(o / ALPHA_MIN)
        ex = math.sqrt(max(thr, 0.0) * cxx) * (1.0 + EXTENT_REL_MARGIN) + EXTENT_ABS_MARGIN
        ey = math.sqrt(max(thr, 0.0) * cyy) * (1.0 + EXTENT_REL_MARGIN) + EXTENT_ABS_MARGIN
        seen = front and thr >= 0.0 and u + ex >= 0.5 and u - ex <= cam[23] - 0.5
        seen = seen and v + ey >= 0.5 and v - ey <= cam[24] - 0.5
        colors[i, 0] = colors[i, 1] = colors[i, 2] = 0.0
        if seen:  # colour only for the drawn (most of a capture's room is behind or beside each view)
            ux, uy, uz, _ = _direction(i, means, cam)
            _basis(ux, uy, uz, degree, basis)
            for c in range(3):
                rgb = SH_C0 * np.float64(sh_dc[i, c])
                for k in range(1, nb):
                    rgb += basis[k] * np.float64(sh_rest[i, k - 1, c])
                colors[i, c] = max(rgb + 0.5, 0.0)
        extents[i, 0], extents[i, 1] = (ex, ey) if seen else (-1.0, -1.0)


@numba.njit(**JIT)
def _forward_serial(means, quats, log_scales, logits, sh_dc, sh_rest, cam, degree, outs):
    _forward_rows(0, len(means), means, quats, log_scales, logits, sh_dc, sh_rest, cam, degree, outs)


@numba.njit(parallel=True, **JIT)
def _forward_parallel(means, quats, log_scales, logits, sh_dc, sh_rest, cam, degree, outs):
    n = len(means)
    for c in numba.prange((n + ROWS_PER_TASK - 1) // ROWS_PER_TASK):
        lo, hi = c * ROWS_PER_TASK, min(n, (c + 1) * ROWS_PER_TASK)
        _forward_rows(lo, hi, means, quats, log_scales, logits, sh_dc, sh_rest, cam, degree, outs)


@numba.njit(**JIT)
def _backward_rows(
    rows, lo, hi, means, quats, log_scales, logits, sh_dc, sh_rest, cam, degree, grad_out, grads
):
    """Rows rows[lo:hi] of project_backward, grad_out[r] the gradient of Gaussian rows[r]'s outputs; every
    gradient is linear in it, so the Gaussians not listed (no gradient: the never-drawn) keep the zeros
    project_backward made, as do the culled and the SH coefficients above ``degree``."""
    d_means, d_quats, d_scales, d_logits, d_dc, d_rest = grads
    scratch = np.empty(45 + 2 * BASIS)
    rq, jw = scratch[0:9].reshape((3, 3)), scratch[9:15].reshape((2, 3))
    a, t = scratch[15:21].reshape((2, 3)), scratch[21:27].reshape((2, 3))
    s = scratch[27:30]
    d_rq, d_jw = scratch[30:39].reshape((3, 3)), scratch[39:45].reshape((2, 3))
    basis, d_basis = scratch[45 : 45 + BASIS], scratch[45 + BASIS : 45 + 2 * BASIS]
    nb = (degree + 1) * (degree + 1)
    for r in range(lo, hi):
        i = rows[r]
        g = grad_out[r]  # not all zero (output_gradients keeps only such rows)
        x, y, z, front, quat, clamp, cov = _geometry(i, means, quats, log_scales, cam, rq, jw, a, s, t)
        if not front:  # the culled pass none: their rows stay zero
            continue
        w, qx, qy, qz, qn = quat
        tx, ty, in_x, in_y = clamp
        cxx, cxy, cyy = cov
        det = cxx * cyy - cxy * cxy
        ca, cb, cc = cyy / det, -cxy / det, cxx / det
        # Colour: max(SH + 0.5, 0) passes gradient where SH + 0.5 >= 0; to the coefficients and direction.
        ux, uy, uz, dn = _direction(i, means, cam)
        _basis(ux, uy, uz, degree, basis)
        d_basis[:] = 0.0
        for c in range(3):
            rgb = SH_C0 * np.float64(sh_dc[i, c])
            for k in range(1, nb):
                rgb += basis[k] * np.float64(sh_rest[i, k - 1, c])
            gc = g[6 + c] if rgb + 0.5 >= 0.0 else 0.0
            d_dc[i, c] = SH_C0 * gc
            for k in range(1, nb):
                d_rest[i, k - 1, c] = basis[k] * gc
                d_basis[k] += np.float64(sh_rest[i, k - 1, c]) * gc
        gx, gy, gz = _basis_grad(ux, uy, uz, degree, d_basis)
        dot = gx * ux + gy * uy + gz * uz  # through the normalisation of the direction
        dmx, dmy, dmz = (gx - ux * dot) / dn, (gy - uy * dot) / dn, (gz - uz * dot) / dn
        # Opacity = sigmoid(logit).
        o = 1.0 / (1.0 + math.exp(-np.float64(logits[i])))
        d_logits[i] = g[5] * o * (1.0 - o)
        # Conic = C^-1: dL/dC = -M G M with G = [[ga, gb / 2], [gb / 2, gc]]; cxy is both off-diagonals.
        ga, gb, gcn = g[2], 0.5 * g[3], g[4]
        m00, m01 = ca * ga + cb * gb, ca * gb + cb * gcn
        m10, m11 = cb * ga + cc * gb, cb * gb + cc * gcn
        d_cxx = -(m00 * ca + m01 * cb)
        d_cxy = -2.0 * (m00 * cb + m01 * cc)
        d_cyy = -(m10 * cb + m11 * cc)
        # Covariance = T T^T + low-pass, T = A S with A = J W Rq.
        d_jw[:] = 0.0
        for j in range(3):
            d_t0 = 2.0 * d_cxx * t[0, j] + d_cxy * t[1, j]
            d_t1 = 2.0 * d_cyy * t[1, j] + d_cxy * t[0, j]
            d_scales[i, j] = (d_t0 * a[0, j] + d_t1 * a[1, j]) * s[j]  # d log scale = d scale * scale
            d_a0, d_a1 = d_t0 * s[j], d_t1 * s[j]
            for k in range(3):
                d_jw[0, k] += d_a0 * rq[k, j]
                d_jw[1, k] += d_a1 * rq[k, j]
                d_rq[k, j] = d_a0 * jw[0, k] + d_a1 * jw[1, k]
        # Rotation of the normalised quaternion, then the normalisation.
        dw = 2.0 * (-qz * d_rq[0, 1] + qy * d_rq[0, 2] + qz * d_rq[1, 0] - qx * d_rq[1, 2])
        dw += 2.0 * (-qy * d_rq[2, 0] + qx * d_rq[2, 1])
        dqx = 2.0 * (qy * d_rq[0, 1] + qz * d_rq[0, 2] + qy * d_rq[1, 0] - w * d_rq[1, 2] + qz * d_rq[2, 0])
        dqx += 2.0 * w * d_rq[2, 1] - 4.0 * qx * (d_rq[1, 1] + d_rq[2, 2])
        dqy = 2.0 * (qx * d_rq[0, 1] + w * d_rq[0, 2] + qx * d_rq[1, 0] + qz * d_rq[1, 2] - w * d_rq[2, 0])
        dqy += 2.0 * qz * d_rq[2, 1] - 4.0 * qy * (d_rq[0, 0] + d_rq[2, 2])
        dqz = 2.0 * (-w * d_rq[0, 1] + qx * d_rq[0, 2] + w * d_rq[1, 0] + qy * d_rq[1, 2] + qx * d_rq[2, 0])
        dqz += 2.0 * qy * d_rq[2, 1] - 4.0 * qz * (d_rq[0, 0] + d_rq[1, 1])
        dot = dw * w + dqx * qx + dqy * qy + dqz * qz
        d_quats[i, 0] = (dw - w * dot) / qn
        d_quats[i, 1] = (dqx - qx * dot) / qn
        d_quats[i, 2] = (dqy - qy * dot) / qn
        d_quats[i, 3] = (dqz - qz * dot) / qn
        # J W rows: (fx / z)(W0k - tx W2k) and (fy / z)(W1k - ty W2k), tx, ty the clamped x/z, y/z.
        sx, sy = cam[15] / z, cam[16] / z
        d_sx = d_sy = d_tx = d_ty = 0.0
        for k in range(3):
            d_sx += d_jw[0, k] * (cam[k] - tx * cam[6 + k])
            d_sy += d_jw[1, k] * (cam[3 + k] - ty * cam[6 + k])
            d_tx -= sx * d_jw[0, k] * cam[6 + k]
            d_ty -= sy * d_jw[1, k] * cam[6 + k]
        # u = fx x / z + cx, v = fy y / z + cy, depth = z; the clamp passes gradient only inside its limits.
        d_x = g[0] * sx
        d_y = g[1] * sy
        d_z = g[9] - (d_sx * sx + d_sy * sy) / z - (g[0] * sx * x + g[1] * sy * y) / z
        if in_x:
            d_x += d_tx / z
            d_z -= d_tx * x / (z * z)
        if in_y:
            d_y += d_ty / z
            d_z -= d_ty * y / (z * z)
        # Camera point p = R m + t, plus the colour's direction.
        d_means[i, 0] = dmx + cam[0] * d_x + cam[3] * d_y + cam[6] * d_z
        d_means[i, 1] = dmy + cam[1] * d_x + cam[4] * d_y + cam[7] * d_z
        d_means[i, 2] = dmz + cam[2] * d_x + cam[5] * d_y + cam[8] * d_z


@numba.njit(**JIT)
def _backward_serial(rows, means, quats, log_scales, logits, sh_dc, sh_rest, cam, degree, grad_out, grads):
    n = len(rows)
    _backward_rows(rows, 0, n, means, quats, log_scales, logits, sh_dc, sh_rest, cam, degree, grad_out, grads)


@numba.njit(parallel=True, **JIT)
def _backward_parallel(rows, means, quats, log_scales, logits, sh_dc, sh_rest, cam, degree, grad_out, grads):
    n = len(rows)
    for c in numba.prange((n + ROWS_PER_TASK - 1) // ROWS_PER_TASK):
        lo, hi = c * ROWS_PER_TASK, min(n, (c + 1) * ROWS_PER_TASK)
        _backward_rows(
            rows, lo, hi, means, quats, log_scales, logits, sh_dc, sh_rest, cam, degree, grad_out, grads
        )


def project_forward(arrays: tuple, cam: np.ndarray, degree: int, threads: int) -> tuple[np.ndarray, ...]:
    """(means2d (N, 2), conics (N, 3), opacities (N,), colors (N, 3), depths (N,), extents (N, 2)) in the
    inputs' dtype, for arrays = (means, quats, log_scales, logits, sh_dc, sh_rest) and cam from
    camera_numbers()."""
    n, dt = len(arrays[0]), arrays[0].dtype
    outs = tuple(np.empty(shape, dt) for shape in ((n, 2), (n, 3), n, (n, 3), n, (n, 2)))
    if threads > 1:
        with parallel(threads):
            _forward_parallel(*arrays, cam, degree, outs)
    else:
        _forward_serial(*arrays, cam, degree, outs)
    return outs


def output_gradients(
    g_uv: np.ndarray,
    g_conic: np.ndarray,
    g_opacity: np.ndarray,
    g_color: np.ndarray,
    g_depth: np.ndarray,
    threads: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """(rows, grad_out): the Gaussians whose outputs have a gradient that is not all zero, in row order, and
    those gradients as (len(rows), OUTPUTS) float64 (u, v, conic a, b, c, opacity, r, g, b, depth), from the
    outputs' (N, 2), (N, 3), (N, 1), (N, 3), (N, 1) gradients. A close-up view of a large scene draws few of
    its Gaussians, and the rest need no work at all. On several threads, blocks of rows are counted, then
    gathered, in parallel."""
    grads = (g_uv, g_conic, g_opacity, g_color, g_depth)
    if threads <= 1:
        return _gather_serial(*grads)
    with parallel(threads):
        return _gather_parallel(*grads, block_bounds(len(g_uv), threads))


@numba.njit(**JIT)
def _mark_rows(g_uv, g_conic, g_opacity, g_color, g_depth, i0, i1, keep):
    """keep[i] for rows i0..i1 - 1: whether any output gradient is not zero; returns how many are kept."""
    m = 0
    for i in range(i0, i1):
        nz = g_uv[i, 0] != 0.0 or g_uv[i, 1] != 0.0 or g_opacity[i, 0] != 0.0 or g_depth[i, 0] != 0.0
        for k in range(3):
            nz = nz or g_conic[i, k] != 0.0 or g_color[i, k] != 0.0
        keep[i] = nz
        m += nz
    return m


@numba.njit(**JIT)
def _gather_rows(g_uv, g_conic, g_opacity, g_color, g_depth, i0, i1, keep, r, rows, grad_out):
    """The kept rows of i0..i1 - 1 into rows and grad_out from output row r."""
    for i in range(i0, i1):
        if keep[i]:
            rows[r] = i
            grad_out[r, 0], grad_out[r, 1] = g_uv[i, 0], g_uv[i, 1]
            for k in range(3):
                grad_out[r, 2 + k] = g_conic[i, k]
                grad_out[r, 6 + k] = g_color[i, k]
            grad_out[r, 5], grad_out[r, 9] = g_opacity[i, 0], g_depth[i, 0]
            r += 1


@numba.njit(**JIT)
def _gather_serial(g_uv, g_conic, g_opacity, g_color, g_depth):
    n = len(g_uv)
    keep = np.empty(n, np.bool_)
    m = _mark_rows(g_uv, g_conic, g_opacity, g_color, g_depth, 0, n, keep)
    rows, grad_out = np.empty(m, np.int64), np.empty((m, OUTPUTS))
    _gather_rows(g_uv, g_conic, g_opacity, g_color, g_depth, 0, n, keep, 0, rows, grad_out)
    return rows, grad_out


@numba.njit(parallel=True, **JIT)
def _gather_parallel(g_uv, g_conic, g_opacity, g_color, g_depth, bounds):
    """Over the blocks of rows bounds[b]..bounds[b + 1] - 1 (loops only: see composite_cpu._bin_parallel)."""
    grads, blocks = (g_uv, g_conic, g_opacity, g_color, g_depth), len(bounds) - 1
    keep = np.empty(len(g_uv), np.bool_)
    first = np.empty(blocks + 1, np.int64)  # each block's first output row
    first[0] = 0
    for b in numba.prange(blocks):
        first[b + 1] = _mark_rows(*grads, bounds[b], bounds[b + 1], keep)
    for b in range(blocks):
        first[b + 1] += first[b]
    rows, grad_out = np.empty(first[blocks], np.int64), np.empty((first[blocks], OUTPUTS))
    for b in numba.prange(blocks):
        _gather_rows(*grads, bounds[b], bounds[b + 1], keep, first[b], rows, grad_out)
    return rows, grad_out


def project_backward(
    arrays: tuple, cam: np.ndarray, degree: int, rows: np.ndarray, grad_out: np.ndarray, threads: int
) -> tuple[np.ndarray, ...]:
    """dL/d (means, quats, log_scales, logits, sh_dc, sh_rest), in the inputs' dtype, for the Gaussians
    ``rows`` with their outputs' gradients grad_out (from output_gradients); zero for the rest."""
    grads = tuple(np.zeros(x.shape, x.dtype) for x in arrays)  # zero pages: only the rows' are written
    if threads > 1:
        with parallel(threads):
            _backward_parallel(rows, *arrays, cam, degree, grad_out, grads)
    else:
        _backward_serial(rows, *arrays, cam, degree, grad_out, grads)
    return grads
