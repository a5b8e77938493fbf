"""The tile renderer against the dense float64 reference (images and gradients), plus API behaviour."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from functools import partial
from pathlib import Path

import numpy as np
import pytest
import torch
from scenes import random_scene

from gspc.cameras import Camera
from gspc.errors import DeviceError, InputError
from gspc.render import api, composite_cpu, kernels, render
from gspc.render import project as proj
from gspc.render import rasterize as rast
from gspc.render.kernels import pick_kernel
from gspc.render.reference import render_reference
from gspc.render.sh import sh_basis
from gspc.scene import ATTRIBUTE_NAMES, make_scene

F64 = torch.float64
W, H = 32, 24


def camera(angle: float = 0.3, cx: float = W / 2 + 1.3, cy: float = H / 2 - 0.7, f: float = 30.0, dist=3.0):
    """A camera `dist` units from the origin, rotated about y and x, with an off-centre principal point."""
    ry = np.array([[math.cos(angle), 0, -math.sin(angle)], [0, 1, 0], [math.sin(angle), 0, math.cos(angle)]])
    b = 0.5 * angle
    rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
    w2c = np.eye(4)
    w2c[:3, :3] = rx @ ry
    w2c[2, 3] = dist
    return Camera(w2c, np.array([[f, 0, cx], [0, f * 1.1, cy], [0, 0, 1.0]]), W, H)


def axis_camera():
    """Identity rotation: camera z equals world z + 3 exactly, so equal-depth ties are exact."""
    w2c = np.eye(4)
    w2c[2, 3] = 3.0
    return Camera(w2c, np.array([[30.0, 0, W / 2], [0, 30.0, H / 2], [0, 0, 1.0]]), W, H)


# random_scene with wide spreads of size, opacity and colour, in float64 (the reference's precision).
wide_scene = partial(
    random_scene,
    spread=0.6,
    log_scale=-2.0,
    scale_std=0.6,
    opacity_logit=0.0,
    opacity_std=2.0,
    dc_std=0.6,
    rest_std=0.3,
    dtype=F64,
)


def loss_weights(h: int, w: int, seed: int = 7):
    g = torch.Generator().manual_seed(seed)
    return torch.randn(h, w, 3, generator=g, dtype=F64), torch.randn(h, w, 2, generator=g, dtype=F64)


def run(fn, scene, cam, **kw):
    """Render and differentiate a fixed random linear loss of image, alpha and depth."""
    s = scene.detach()
    for t in s.tensors().values():
        t.requires_grad_(True)
    out = fn(s, cam, **kw)
    wi, wad = loss_weights(cam.height, cam.width)
    dt = out.image.dtype
    loss = (out.image * wi.to(dt)).sum() + (out.alpha * wad[..., 0].to(dt)).sum()
    loss = loss + (out.depth * wad[..., 1].to(dt)).sum()
    grads = torch.autograd.grad(loss, [s.tensors()[k] for k in ATTRIBUTE_NAMES], allow_unused=True)
    grads = [
        torch.zeros_like(s.tensors()[k]) if g is None else g
        for k, g in zip(ATTRIBUTE_NAMES, grads, strict=True)
    ]
    return out, dict(zip(ATTRIBUTE_NAMES, grads, strict=True))


def assert_close(a: torch.Tensor, b: torch.Tensor, tol: float, what: str) -> None:
    a, b = a.detach(), b.detach()
    scale = max(1.0, float(b.abs().max())) if b.numel() else 1.0
    err = float((a.to(F64) - b.to(F64)).abs().max()) if b.numel() else 0.0
    assert err <= tol * scale, f"{what}: max error {err:.3g} (scale {scale:.3g})"


@pytest.fixture(params=["compiled", "torch"])
def kernel(request, monkeypatch):
    """Both implementations of projection and compositing: the compiled CPU kernels (the CPU default) and
    the PyTorch code (other devices)."""
    monkeypatch.setattr(api, "project", partial(proj.project, kernel=request.param))
    monkeypatch.setattr(api, "composite", partial(rast.composite, kernel=request.param))
    return request.param


def check_against_reference(scene, cam, tol=1e-10, **kw):
    out, grads = run(render, scene, cam, backend="torch", **kw)
    ref, ref_grads = run(render_reference, scene, cam, **kw)
    for name in ("image", "alpha", "depth"):
        assert_close(getattr(out, name), getattr(ref, name), tol, name)
    for name in ATTRIBUTE_NAMES:
        assert torch.isfinite(grads[name]).all(), f"non-finite gradient of {name}"
        assert_close(grads[name], ref_grads[name], tol, f"d/d {name}")
    return out, ref


@pytest.mark.parametrize("deg", [0, 1, 2, 3])
def test_random_scenes_match_reference(deg, kernel):
    out, _ = check_against_reference(
        wide_scene(120, sh_degree=deg, seed=deg), camera(), background=[0.2, 0.5, 0.9]
    )
    assert 0.2 < float(out.alpha.detach().mean()) < 0.95  # the scene really covers the image


def test_image_size_not_a_multiple_of_the_tile(kernel):
    cam = camera().scaled(0.9)  # 29 x 22: partial tiles on the right and bottom edges
    assert cam.width % 8 and cam.height % 8
    check_against_reference(wide_scene(80, sh_degree=1, seed=12), cam)


def test_lower_sh_degree_matches_reference(kernel):
    check_against_reference(wide_scene(60, sh_degree=3, seed=11), camera(), sh_degree=1)


def test_dense_opaque_scene_hits_transmittance_stop(kernel):
    scene = wide_scene(
        200, sh_degree=1, seed=3, spread=0.3, log_scale=-1.5, opacities=torch.full((200,), 3.0, dtype=F64)
    )
    out, ref = check_against_reference(scene, camera())
    assert float(ref.alpha.detach().max()) > 1 - 2e-4  # some pixels stopped at T < 1e-4


def test_walk_in_small_blocks_and_chunks(monkeypatch):
    monkeypatch.setattr(api, "composite", partial(rast.composite, kernel="torch"))
    # Many steps and chunks, tiles leaving the walk at different times: same result.
    monkeypatch.setattr(rast, "BLOCK", 3)
    monkeypatch.setattr(rast, "CPU_WALK", rast.WalkSizes(64 * 3 * 2, rast.CPU_WALK.scan_loop_from))
    scene = wide_scene(150, sh_degree=2, seed=5, spread=0.4, opacities=torch.full((150,), 2.5, dtype=F64))
    check_against_reference(scene, camera())


def test_walk_with_looped_scans(monkeypatch):
    monkeypatch.setattr(api, "composite", partial(rast.composite, kernel="torch"))
    # The slice-loop transmittance and remaining-sum scans (taken on large steps) give the same result.
    monkeypatch.setattr(rast, "CPU_WALK", rast.WalkSizes(rast.CPU_WALK.step_budget, 0))
    scene = wide_scene(
        150, sh_degree=2, seed=6, spread=0.4, opacities=torch.randn(150, dtype=F64) * 3.0 + 2.0
    )
    check_against_reference(scene, camera())


def test_the_gpu_walk_sizes_give_the_same_result(monkeypatch):
    # A GPU walks every tile of a frame in one chunk with one-kernel scans: the same sums, regrouped. Run
    # here on the CPU as a stand-in (the walk's arithmetic does not depend on the device).
    assert rast.walk_sizes(torch.device("cpu")) is rast.CPU_WALK
    assert rast.walk_sizes(torch.device("cuda")) is rast.GPU_WALK
    assert rast.GPU_WALK.step_budget > rast.CPU_WALK.step_budget
    monkeypatch.setattr(api, "composite", partial(rast.composite, kernel="torch"))
    monkeypatch.setattr(rast, "BLOCK", 3)  # many steps: tiles leave the one chunk at different times
    monkeypatch.setattr(rast, "CPU_WALK", rast.GPU_WALK)
    scene = wide_scene(
        150, sh_degree=2, seed=7, spread=0.4, opacities=torch.randn(150, dtype=F64) * 3.0 + 2.0
    )
    check_against_reference(scene, camera())


def _hard_cases() -> dict[str, tuple]:
    n = 24
    g = torch.Generator().manual_seed(1)

    def r(*s):
        return torch.randn(*s, generator=g, dtype=F64)

    def logit(p):
        return torch.log(p / (1 - p))

    xy = r(n, 2) * 0.5
    cases = {}
    # Centres behind the camera (z_cam < 0) and large enough to cover the view if they were drawn.
    cases["behind_camera"] = dict(means=torch.cat([xy, torch.full((n, 1), -3.5, dtype=F64) + r(n, 1)], 1))
    # Centres just in front of / just behind the near plane (z_cam = 0.01), scales reaching across it.
    z = 0.01 + torch.linspace(-0.008, 0.03, n, dtype=F64) - 3.0
    cases["near_plane"] = dict(means=torch.cat([xy * 0.01, z[:, None]], 1), log_scales=r(n, 3) * 0.3 - 3.0)
    # Off-screen centres (up to 4x the frustum) whose tails may or may not reach the image.
    cases["off_screen"] = dict(
        means=torch.cat([r(n, 2) * 4.0, r(n, 1) * 0.3], 1), log_scales=r(n, 3) * 0.5 - 0.5
    )
    # Needle-thin: one long axis, two tiny ones (the 0.3 low-pass keeps them a pixel wide).
    needle = torch.cat([torch.full((n, 1), -0.5, dtype=F64), torch.full((n, 2), -9.0, dtype=F64)], 1)
    cases["needle"] = dict(log_scales=needle + r(n, 3) * 0.2)
    # Huge Gaussians covering the whole image.
    cases["huge"] = dict(log_scales=r(n, 3) * 0.3 + 1.5, opacities=r(n) - 2.0)
    # Nearly transparent: opacities just above and below 1/255.
    cases["transparent"] = dict(
        opacities=logit(torch.linspace(0.7, 2.0, n, dtype=F64) / 255.0), log_scales=r(n, 3) * 0.3 - 1.0
    )
    # Opacity exactly 1 in float64 (sigmoid(40) rounds to 1): alpha capped at 0.99, pixels stop.
    cases["opaque"] = dict(opacities=torch.full((n,), 40.0, dtype=F64), log_scales=r(n, 3) * 0.3 - 1.8)
    # Equal depths: ties keep index order in both renderers (axis camera makes the z values exact).
    eq = torch.cat([xy * 0.3, torch.full((n, 1), 0.25, dtype=F64)], 1)
    cases["equal_depths"] = dict(
        means=eq, opacities=torch.full((n,), 1.0, dtype=F64), log_scales=r(n, 3) * 0.2 - 1.5
    )
    # Centres on tile borders and corners (the axis camera puts x = -0.8, 0, 0.8 and y = -0.4, 0.4 at
    # z = 0 on pixel 8, 16, 24 column and row edges), thin and rotated, near-opaque: the exact tile lists
    # and each pair's walk of whole tile rows.
    grid = torch.tensor([[x, y, 0.0] for x in (-0.8, 0.0, 0.8) for y in (-0.4, 0.4)], dtype=F64)
    thin = torch.tensor([-0.6, -6.0, -6.0], dtype=F64)
    cases["tile_borders"] = dict(
        means=torch.cat([grid, grid, grid, grid])[:n] + r(n, 3) * torch.tensor([1e-9, 1e-9, 0.05]),
        log_scales=thin + r(n, 3) * 0.3,
        opacities=torch.full((n,), 6.0, dtype=F64) + r(n),
    )
    # Camera inside a Gaussian whose centre is just in front of it, and inside one whose centre is behind.
    inside = torch.tensor([[0.0, 0.0, -2.7], [0.1, 0.0, -3.2]], dtype=F64)
    cases["camera_inside"] = dict(
        means=torch.cat([inside, r(n - 2, 3) * 0.5]),
        log_scales=torch.cat([torch.full((2, 3), 0.5, dtype=F64), r(n - 2, 3) * 0.5 - 2.0]),
        opacities=torch.cat([torch.tensor([0.5, 2.0], dtype=F64), r(n - 2)]),
    )
    return cases


@pytest.mark.parametrize("case", list(_hard_cases()))
def test_hard_cases_match_reference(case, kernel):
    override = _hard_cases()[case]
    n = 24 if "means" not in override else len(override["means"])
    scene = wide_scene(n, sh_degree=3, seed=2, **override)
    axis = case in ("equal_depths", "near_plane", "camera_inside", "tile_borders")
    cam = axis_camera() if axis else camera()
    check_against_reference(scene, cam, background=[0.1, 0.2, 0.3])


def test_point_at_pixel_centre_is_drawn_in_float32(kernel):
    # q rounds slightly negative at the centre; the Gaussian must still be drawn there with alpha = o.
    cam = axis_camera()
    u, v = 10.5, 7.5  # a pixel centre
    means = torch.tensor([[(u - W / 2) / 30.0, (v - H / 2) / 30.0, 0.0]]) * 3.0
    scene = make_scene(means, [[1.0, 0.2, -0.1, 0.3]], [[-9.0, -9.5, -8.0]], [0.0], [[1.0, 0.0, 0.0]])
    out = render(scene, cam, backend="torch")
    assert out.alpha.dtype == torch.float32
    assert abs(float(out.alpha[7, 10]) - 0.5) < 1e-5
    assert abs(float(out.depth[7, 10]) - 0.5 * 3.0) < 1e-5


def test_float32_agrees_with_reference(kernel):
    scene = wide_scene(150, sh_degree=3, seed=4, dtype=torch.float32)
    out, grads = run(render, scene, camera(), backend="torch", background=[0.3, 0.3, 0.3])
    ref, ref_grads = run(render_reference, scene, camera(), background=[0.3, 0.3, 0.3])
    assert out.image.dtype == torch.float32
    for name in ("image", "alpha", "depth"):
        err = (getattr(out, name).double() - getattr(ref, name)).abs().detach()
        assert float(err.mean()) < 1e-6 and float(err.max()) < 1e-4, name
    for name in ATTRIBUTE_NAMES:
        a, b = grads[name].double(), ref_grads[name]
        assert float((a - b).norm() / b.norm()) < 1e-4, name


def test_background_alpha_and_depth(kernel):
    cam = axis_camera()
    bg = torch.tensor([0.25, 0.5, 0.75])
    # Nothing visible (all behind the camera): background everywhere, alpha and depth zero.
    empty = wide_scene(
        10, sh_degree=0, seed=0, dtype=torch.float32, means=torch.tensor([[0.0, 0.0, -5.0]] * 10)
    )
    out = render(empty, cam, background=bg)
    assert torch.equal(out.image, bg.expand(H, W, 3)) and not out.alpha.any() and not out.depth.any()
    # One opaque wall-sized Gaussian at camera depth 2: alpha 0.99, depth = alpha * 2, colour blended.
    wall = make_scene(
        [[0.0, 0.0, -1.0]], [[1.0, 0, 0, 0]], [[3.0, 3.0, -6.0]], [40.0], [[0.0, 0.0, 0.0]], dtype=F64
    )
    out = render(wall, cam, background=bg.double())
    assert torch.allclose(out.alpha, torch.full((H, W), 0.99, dtype=F64))
    assert torch.allclose(out.depth, 0.99 * 2.0 * torch.ones(H, W, dtype=F64))
    assert torch.allclose(out.image, 0.99 * 0.5 + 0.01 * bg.double().expand(H, W, 3))
    # Default background is black.
    assert torch.allclose(render(wall, cam).image, torch.full((H, W, 3), 0.99 * 0.5, dtype=F64))


def test_sh_degree_argument_truncates_bands():
    scene = wide_scene(40, sh_degree=3, seed=8, dtype=torch.float32)
    low = make_scene(
        scene.means, scene.quats, scene.log_scales, scene.opacities, scene.sh_dc, scene.sh_rest[:, :3]
    )
    assert torch.equal(render(scene, camera(), sh_degree=1).image, render(low, camera()).image)
    with pytest.raises(InputError):
        render(low, camera(), sh_degree=2)


def test_backend_choice_and_errors():
    scene = wide_scene(5, sh_degree=0, seed=0, dtype=torch.float32)
    assert torch.equal(render(scene, camera()).image, render(scene, camera(), backend="torch").image)
    with pytest.raises(DeviceError, match="CUDA"):
        render(scene, camera(), backend="gsplat")
    with pytest.raises(InputError, match="backend"):
        render(scene, camera(), backend="opengl")
    with pytest.raises(InputError, match="background"):
        render(scene, camera(), background=[0.0, 1.0])


def test_sh_basis_is_orthonormal_on_the_sphere():
    # Midpoint quadrature in (theta, phi): checks every constant and polynomial of the 16 bands.
    nt, npz = 200, 400
    theta = (torch.arange(nt, dtype=F64) + 0.5) * math.pi / nt
    phi = (torch.arange(npz, dtype=F64) + 0.5) * 2 * math.pi / npz
    t, p = torch.meshgrid(theta, phi, indexing="ij")
    dirs = torch.stack([t.sin() * p.cos(), t.sin() * p.sin(), t.cos()], -1).reshape(-1, 3)
    weight = (t.sin() * (math.pi / nt) * (2 * math.pi / npz)).reshape(-1, 1)
    y = sh_basis(dirs, 3)
    gram = y.T @ (y * weight)
    assert torch.allclose(gram, torch.eye(16, dtype=F64), atol=1e-4)
    # INRIA's sign convention for band 1: Y = (-C1 y, C1 z, -C1 x).
    b = sh_basis(torch.tensor([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], dtype=F64), 1)
    assert b[0, 1] < 0 and b[1, 2] > 0 and b[2, 3] < 0


@pytest.mark.parametrize("log_scale", [-2.0, -0.8])
def test_compiled_kernel_on_several_threads_matches_one(monkeypatch, log_scale):
    # Tiles, blocks of Gaussians and of sort keys in parallel: the image and every gradient are bit-identical
    # (each tile is walked alone, the lists and the order are unique, each Gaussian's gradient is the same
    # sum in the same order). Small blocks, so that 300 Gaussians make several; log scale -0.8: large
    # Gaussians, each in many tiles, whose later pairs' rows are added after the walk.
    monkeypatch.setattr(kernels, "ROWS_PER_TASK", 16)
    scene = wide_scene(300, sh_degree=2, seed=9, spread=0.5, log_scale=log_scale)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one, g_one = run(render, scene, camera())
        torch.set_num_threads(3)
        two, g_two = run(render, scene, camera())
    finally:
        torch.set_num_threads(before)
    assert torch.equal(one.image, two.image) and torch.equal(one.alpha, two.alpha)
    for name in ATTRIBUTE_NAMES:
        assert torch.equal(g_two[name], g_one[name]), f"d/d {name}"


def random_ellipses(n: int, seed: int, spread=(60.0, 40.0), log_scale=(0.0, 1.0)):
    """Screen-space Gaussians as the compositor gets them: means (n, 2), conics (n, 3), opacities (n,) and
    the alpha >= 1/255 boxes' half-sizes (n, 2); some off-image, some thin and rotated, some below 1/255."""
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 2, generator=g, dtype=F64) * torch.tensor(spread, dtype=F64) - 10.0
    sx, sy = (torch.exp(torch.randn(2, n, generator=g, dtype=F64) * log_scale[1] + log_scale[0])).unbind(0)
    rot = torch.rand(n, generator=g, dtype=F64) * math.pi
    c, s = torch.cos(rot), torch.sin(rot)
    cxx, cyy = c * c * sx * sx + s * s * sy * sy + 0.3, s * s * sx * sx + c * c * sy * sy + 0.3
    cxy = c * s * (sx * sx - sy * sy)
    det = cxx * cyy - cxy * cxy
    conics = torch.stack([cyy / det, -cxy / det, cxx / det], 1)
    opacities = torch.rand(n, generator=g, dtype=F64) * 1.05
    extents = proj.alpha_extents(cxx, cyy, opacities)
    return means, conics, opacities, extents


@pytest.mark.parametrize("threads", [1, 3])
@pytest.mark.parametrize("exact", [True, False])
def test_compiled_tile_lists_equal_the_torch_ones(monkeypatch, exact, threads):
    monkeypatch.setattr(kernels, "ROWS_PER_TASK", 16)  # on 3 threads: 12 blocks of Gaussians
    means, conics, opacities, extents = random_ellipses(400, seed=3)
    extents[::7] = -1.0  # never drawn
    a = rast.bin_tiles(means, conics, opacities, extents, 45, 29, exact=exact)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(threads)
        b = rast.bin_tiles(means, conics, opacities, extents, 45, 29, compiled=True, exact=exact)
    finally:
        torch.set_num_threads(before)
    for field in ("gauss", "tile", "start", "count"):
        assert torch.equal(getattr(a, field), getattr(b, field)), field
    assert len(a.gauss) > 400


def test_compiled_row_spans_cover_every_drawn_pixel():
    # The rows a pair walks, and per row the span that walk_counts counts (widened by SPAN_MARGIN), hold
    # every pixel whose alpha reaches 1/255, also for thin, rotated and sub-pixel ellipses.
    g = torch.Generator().manual_seed(4)
    for _ in range(200):
        sx, sy = (torch.rand(2, generator=g, dtype=F64) * 4.0 + 0.3).tolist()
        rot = float(torch.rand(1, generator=g)) * math.pi
        c, s = math.cos(rot), math.sin(rot)
        cov = np.array([[c, -s], [s, c]]) @ np.diag([sx * sx, sy * sy]) @ np.array([[c, s], [-s, c]])
        cov += 0.3 * np.eye(2)
        a, b, cc = np.linalg.inv(cov)[[0, 0, 1], [0, 1, 1]]
        o = float(torch.rand(1, generator=g)) * 0.98 + 0.01
        one = np.ones((1, 1))
        record = composite_cpu.pack(
            np.zeros(1, np.int64), one * [0.0, 0.0], one * [1, 0, 1], one[0] * o, one * [0, 0, 0, 0]
        )
        thr = float(record[0, 6])
        mx, my = (torch.rand(2, generator=g, dtype=F64) * 8.0).tolist()
        ell = composite_cpu._ellipse(np.array([mx, my, a, b, cc, o, thr]))
        row_lo, row_hi = composite_cpu._row_range(ell, 0)
        for row in range(8):
            dy = row + 0.5 - my
            lo, hi = composite_cpu._row_span(ell, dy, 0)
            for col in range(8):
                dx = col + 0.5 - mx
                alpha = o * math.exp(-0.5 * (a * dx * dx + 2 * b * dx * dy + cc * dy * dy))
                if alpha >= rast.ALPHA_MIN:
                    assert row_lo <= row <= row_hi and lo <= col <= hi


def test_kernel_choice_and_errors():
    with pytest.raises(ValueError, match="kernel"):
        pick_kernel("opencl", torch.zeros(1))
    assert pick_kernel("auto", torch.zeros(1)) == "compiled"
    assert pick_kernel("torch", torch.zeros(1)) == "torch"
    assert pick_kernel("auto", torch.zeros(1, device="meta")) == "torch"
    with pytest.raises(ValueError, match="CPU"):
        pick_kernel("compiled", torch.zeros(1, device="meta"))


def projected_and_grads(scene, cam, deg: int, kernel: str):
    """project()'s outputs and the gradients of a fixed random linear loss of every differentiable one."""
    s = scene.detach()
    params = [s.tensors()[k].requires_grad_(True) for k in ATTRIBUTE_NAMES]
    p = proj.project(*params, cam, deg, kernel=kernel)
    g = torch.Generator().manual_seed(5)
    drawn = p.drawn.to(p.means2d.dtype)
    # Weights drawn per scene row (a projection may cover a subset of them: p.index).
    loss = sum(
        (
            t
            * torch.randn((len(s.means), *t.shape[1:]), generator=g, dtype=F64)[p.index].to(t.dtype)
            * drawn.reshape(-1, *[1] * (t.dim() - 1))
        ).sum()
        for t in (p.means2d, p.conics, p.opacities, p.colors, p.depths)
    )
    return p, torch.autograd.grad(loss, params)


@pytest.mark.parametrize("behind", [3, 40])  # few behind the camera (projected, marked) and many (subset)
@pytest.mark.parametrize("dtype", [F64, torch.float32])
def test_compiled_projection_matches_pytorch(behind, dtype):
    # Every output and gradient of the compiled projection against autograd through the PyTorch code: to
    # round-off in float64, to float32's in float32 (the kernels compute in float64 from float32 inputs).
    # Degree 1 of a degree-3 scene: the unused coefficients get zero gradients. Some Gaussians lie behind
    # the camera, some off-screen, some below 1/255 opaque.
    scene = wide_scene(200, sh_degree=3, seed=11, spread=1.2, dtype=dtype)
    scene.means[:behind, 2] = -4.0  # camera() sits 3 units away along -z
    scene.opacities[-5:] = -8.0
    tol = 1e-12 if dtype == F64 else 2e-5
    a, ga = projected_and_grads(scene, camera(), 1, "torch")
    b, gb = projected_and_grads(scene, camera(), 1, "compiled")
    # The PyTorch code copies out the rows in front of the camera when many are behind; the compiled kernels
    # take every row (a.index is a subset of b.index = all rows).
    assert torch.equal(b.index, torch.arange(len(scene.means)))
    assert not b.drawn[~torch.isin(b.index, a.index)].any()
    assert torch.equal(a.drawn, b.drawn[a.index]) and b.means2d.dtype == dtype
    assert (~b.drawn).sum() > behind and (len(a.index) < len(b.index)) == (behind == 40)
    for name in ("means2d", "conics", "opacities", "depths", "extents"):
        assert_close(getattr(b, name)[a.index], getattr(a, name), tol, name)
    assert_close(b.colors[b.drawn], a.colors[a.drawn], tol, "colors")  # (the never-drawn: 0, unread)
    assert not b.colors[~b.drawn].any()
    for name, x, y in zip(ATTRIBUTE_NAMES, gb, ga, strict=True):
        assert x.dtype == dtype and torch.isfinite(x).all(), name
        assert_close(x, y, tol, f"d/d {name}")
    assert not gb[5][:, 3:].any() and not gb[0][:behind].any()


@pytest.mark.parametrize("threads", [1, 3])
def test_only_gaussians_with_a_gradient_are_differentiated(monkeypatch, threads):
    # The compiled backward walks the Gaussians whose outputs have any gradient (output_gradients), each
    # with its own row; every other Gaussian's gradients are zero. One output's gradient is enough, a NaN
    # counts as one, and the gradients are read in float64 from either dtype. On 3 threads: blocks of 2.
    from gspc.render import project_cpu as kern

    monkeypatch.setattr(kernels, "ROWS_PER_TASK", 2)
    n = 9
    outs = [np.zeros((n, k), np.float32) for k in (2, 3, 1, 3, 1)]
    outs[0][1, 1] = 2.0
    outs[4][4, 0] = -1.5  # depth only
    outs[3][7, 2] = np.nan
    outs[1][7, 0] = 0.25
    rows, grad_out = kern.output_gradients(*outs, threads)
    assert rows.tolist() == [1, 4, 7] and grad_out.dtype == np.float64 and grad_out.shape == (3, kern.OUTPUTS)
    assert grad_out[0].tolist() == [0, 2.0, 0, 0, 0, 0, 0, 0, 0, 0]
    assert grad_out[1].tolist() == [0, 0, 0, 0, 0, 0, 0, 0, 0, -1.5]
    assert grad_out[2, 2] == 0.25 and np.isnan(grad_out[2, 8])
    assert kern.output_gradients(*[np.zeros((n, k)) for k in (2, 3, 1, 3, 1)], threads)[0].size == 0
    # Through the projection: a loss on one drawn Gaussian's colour moves that Gaussian alone.
    scene = wide_scene(50, sh_degree=2, seed=4, spread=0.6)
    params = [scene.tensors()[name].requires_grad_(True) for name in ATTRIBUTE_NAMES]
    p = proj.project(*params, camera(), 2, kernel="compiled")
    k = int(torch.nonzero(p.drawn)[0])
    grads = torch.autograd.grad(p.colors[k].sum(), params)
    for g in grads:
        others = torch.cat([g[:k], g[k + 1 :]])
        assert not others.any() and torch.isfinite(g).all()
    assert grads[4][k].abs().sum() > 0  # the DC colour's


@pytest.mark.parametrize("threads", [1, 3])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_depth_order_is_torchs_stable_sort(monkeypatch, dtype, threads):
    monkeypatch.setattr(kernels, "ROWS_PER_TASK", 16)  # on 3 threads: 12 blocks of keys
    g = np.random.default_rng(0)
    depths = np.concatenate([g.normal(size=500) * 3, np.repeat([0.5, 2.0, -1.0, 1e-3, 1e6], 40)]).astype(
        dtype
    )
    g.shuffle(depths)
    expected = torch.sort(torch.from_numpy(depths), stable=True).indices.numpy()
    assert np.array_equal(composite_cpu.depth_order(depths, threads), expected)
    assert len(composite_cpu.depth_order(depths[:0], threads)) == 0


def _listed(bins: rast.TileBins) -> set[tuple[int, int]]:
    return set(zip(bins.tile.tolist(), bins.gauss.tolist(), strict=True))


@pytest.mark.parametrize(
    "case",
    ["mixed", "thin_rotated", "huge", "near_opaque", "on_tile_borders"],
)
def test_exact_tile_lists_hold_every_drawn_pixel_and_are_in_the_box(case):
    # Every (tile, Gaussian) whose alpha reaches 1/255 at one of the tile's pixel centres is listed (checked
    # pixel by pixel in float64), and no pair outside the alpha >= 1/255 box is.
    width, height = 45, 29
    n, log_scale = (40, (3.5, 0.5)) if case == "huge" else (300, (0.0, 1.0))
    means, conics, opacities, extents = random_ellipses(n, seed=5, log_scale=log_scale)
    if case == "thin_rotated":  # one long axis, the other at the low-pass floor
        g = torch.Generator().manual_seed(6)
        rot = torch.rand(n, generator=g, dtype=F64) * math.pi
        long = torch.exp(torch.rand(n, generator=g, dtype=F64) * 3.0)
        c, s = torch.cos(rot), torch.sin(rot)
        cxx, cyy, cxy = c * c * long**2 + 0.3, s * s * long**2 + 0.3, c * s * long**2
        det = cxx * cyy - cxy * cxy
        conics = torch.stack([cyy / det, -cxy / det, cxx / det], 1)
        extents = proj.alpha_extents(cxx, cyy, opacities)
    if case == "near_opaque":
        opacities = 1.0 - torch.rand(n, dtype=F64, generator=torch.Generator().manual_seed(7)) * 1e-3
        cov = torch.linalg.inv(torch.stack([conics[:, [0, 1]], conics[:, [1, 2]]], 1))
        extents = proj.alpha_extents(cov[:, 0, 0], cov[:, 1, 1], opacities)
    if case == "on_tile_borders":  # centres on tile borders and pixel centres
        means = torch.round(means / 4.0) * 4.0 + torch.tensor([0.0, 0.5], dtype=F64)
    exact = rast.bin_tiles(means, conics, opacities, extents, width, height, compiled=True)
    box = rast.bin_tiles(means, conics, opacities, extents, width, height, compiled=True, exact=False)
    listed, in_box = _listed(exact), _listed(box)
    assert listed <= in_box
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=F64) + 0.5, torch.arange(width, dtype=F64) + 0.5, indexing="ij"
    )
    tile = (ys.long() // rast.TILE) * exact.tiles_x + xs.long() // rast.TILE
    needed = set()
    for i in range(n):
        a, b, c = conics[i].tolist()
        dx, dy = xs - means[i, 0], ys - means[i, 1]
        alpha = opacities[i] * torch.exp(-0.5 * (a * dx * dx + 2 * b * dx * dy + c * dy * dy))
        needed |= {(t, i) for t in tile[alpha >= rast.ALPHA_MIN * (1 - 1e-9)].unique().tolist()}
    assert needed and needed <= listed
    if case in ("mixed", "thin_rotated"):
        assert len(listed) < 0.9 * len(in_box)  # the corners of boxes go (thin rotated ones: most tiles)


def test_row_walk_values_stay_exact_over_whole_tile_rows():
    # A pair's walk multiplies its way across every pixel of the tile rows its ellipse reaches, however far
    # from the ellipse (composite_cpu._row_start): thin, rotated, opaque ellipses that only graze a tile's
    # corner, and large faint ones. Every value must match o exp(-q / 2) evaluated directly, to round-off,
    # and never under- or overflow.
    g = np.random.default_rng(8)
    checked = 0
    for _ in range(1000):
        sx, sy = np.exp(g.normal(0.0, 1.5, 2))
        rot = g.uniform(0, math.pi)
        c, s = math.cos(rot), math.sin(rot)
        cov = np.array([[c, -s], [s, c]]) @ np.diag([sx * sx, sy * sy]) @ np.array([[c, s], [-s, c]])
        cov += 0.3 * np.eye(2)
        a, b, cc = np.linalg.inv(cov)[[0, 0, 1], [0, 1, 1]]
        o = float(g.choice([0.99, 1.0, g.uniform(0.005, 1.0)]))
        one = np.ones((1, 1))
        record = composite_cpu.pack(
            np.zeros(1, np.int64), one * [0.0, 0.0], one * [1, 0, 1], one[0] * o, one * [0, 0, 0, 0]
        )
        thr = float(record[0, 6])
        mx, my = g.uniform(-20.0, 28.0, 2)
        ell = composite_cpu._ellipse(np.array([mx, my, a, b, cc, o, thr]))
        # Only tiles whose pixel centres the ellipse reaches are walked (the exact tile lists).
        px, py = np.meshgrid(np.arange(8) + 0.5, np.arange(8) + 0.5)
        dx, dy = px - mx, py - my
        q = a * dx * dx + 2 * b * dx * dy + cc * dy * dy
        if not (q <= thr).any():
            continue
        checked += 1
        row_lo, row_hi = composite_cpu._row_range(ell, 0)
        er, vr = np.empty(8), np.empty(8)
        ec = composite_cpu._row_start(ell, row_lo, 0, 0, er, vr)
        for row in range(row_lo, row_hi + 1):
            expected = o * np.exp(-0.5 * q[row])
            assert np.all(np.isfinite(er)) and np.all(er > 1e-200), (row, er)
            np.testing.assert_allclose(er, expected, rtol=1e-12, atol=0)
            er, vr = er * vr, vr * ec
    assert checked > 150


def test_colour_only_loss_on_black_matches_reference():
    # A loss of the colour image alone on a black background (refinement's, on most scenes) leaves depth's
    # and alpha's gradients all zero, and the compiled backward then leaves their terms out of its walk.
    scene = wide_scene(150, sh_degree=2, seed=21, spread=0.6)
    grads = {}
    for name, fn in (("compiled", partial(render, backend="torch")), ("reference", render_reference)):
        s = scene.detach()
        params = [s.tensors()[k].requires_grad_(True) for k in ATTRIBUTE_NAMES]
        out = fn(s, camera(), background=[0.0, 0.0, 0.0])
        wi, _ = loss_weights(H, W)
        grads[name] = torch.autograd.grad((out.image * wi).sum(), params)
    for name, a, b in zip(ATTRIBUTE_NAMES, grads["compiled"], grads["reference"], strict=True):
        assert_close(a, b, 1e-10, f"d/d {name}")


def test_compiled_kernels_keep_torchs_thread_count():
    # numba's OpenMP pool, started by its first parallel loop, set the OpenMP thread count torch reads to
    # the pool's size: GSPC_THREADS=2 on a larger machine became every core after the first render. A fresh
    # process, so that this render starts the pool; a pool of 3 is more than the 1 and 2 threads asked for.
    lego = Path(__file__).resolve().parents[1] / "examples" / "lego"
    code = (
        "import sys, torch\n"
        "from gspc.io import read_scene\n"
        "from gspc.io.camera_files import load_cameras\n"
        "from gspc.render import render\n"
        "scene, cam = read_scene(sys.argv[1]), load_cameras(sys.argv[2])[0]\n"
        "for n in (1, 2):\n"
        "    torch.set_num_threads(n)\n"
        "    torch.get_num_threads()\n"
        "    render(scene, cam)\n"
        "    assert torch.get_num_threads() == n, (n, torch.get_num_threads())\n"
    )
    env = dict(os.environ, NUMBA_NUM_THREADS="3")
    args = [sys.executable, "-c", code, str(lego / "point_cloud.ply"), str(lego / "cameras.json")]
    proc = subprocess.run(args, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
