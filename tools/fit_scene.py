"""Fit a 3DGS scene (SH degree up to 3) to posed photos on the CPU.

    python tools/fit_scene.py ../shared/data/lego/transforms_train.json -o out/lego \
        --resolution 200 --gaussians 20000 --iterations 3000
    python tools/fit_scene.py ../shared/data/bird -o out/bird --downscale 4 --gaussians 120000 \
        --iterations 10000

Two kinds of input:
- a NeRF-synthetic ``transforms*.json`` (RGBA photos): a fixed budget of Gaussians initialised inside
  the visual hull carved from the alpha masks;
- a COLMAP capture (a folder with ``sparse/0`` and ``images/``; txt or bin; JPEG or PNG; any aspect
  ratio; no alpha, the background is part of the scene): initialised from the COLMAP points plus a
  sparse shell of points around the cameras (the far field the points miss: walls, sky), then grown
  to the budget by cloning strong Gaussians (the "add" step of 3DGS-MCMC) until half-way.
Both train with Adam on 0.8 L1 + 0.2 (1 - SSIM); every few hundred iterations the Gaussians that
faded out are moved next to strong ones (a relocation step in the spirit of 3DGS-MCMC), which
replaces densification at a fixed count. Every 8th view (sorted by name) is held out.

Writes OUT/point_cloud.ply, OUT/cameras.json (all views, at the fitted resolution),
OUT/test/*.png (held-out photos at that resolution) and OUT/fit.json (metrics, time, settings).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import imagecodecs
import numpy as np
import torch
import torch.nn.functional as F
import typer

from gspc.cameras import Camera
from gspc.cli import one_line_warnings
from gspc.errors import GspcError
from gspc.io import write_ply
from gspc.io.camera_files import load_cameras
from gspc.io.cameras_json import save_cameras_json
from gspc.io.colmap import load_colmap_points
from gspc.metrics import psnr, quantize8, ssim
from gspc.render import render
from gspc.scene import GaussianScene, num_sh_rest
from gspc.views import split_test_views

C0 = 0.28209479177387814


def load_images(
    cameras: list[Camera], root: Path, size: int, background: float
) -> tuple[list[torch.Tensor], list]:
    """Photos resized to size x size (area filter), composited on the background; alpha masks kept."""
    images, masks = [], []
    for cam in cameras:
        stem = cam.name
        path = next((p for p in (root / stem, root / f"{stem}.png") if p.is_file()), None) or next(
            iter(sorted(root.rglob(f"{stem}.png"))), None
        )
        if path is None:
            raise SystemExit(f"image for camera {cam.name!r} not found under {root}")
        a = imagecodecs.png_decode(path.read_bytes()).astype(np.float32) / 255.0
        t = torch.from_numpy(a).permute(2, 0, 1)[None]
        t = F.interpolate(t, size=(size, size), mode="area")[0].permute(1, 2, 0)
        rgb, alpha = (t[..., :3], t[..., 3]) if t.shape[-1] == 4 else (t[..., :3], torch.ones_like(t[..., 0]))
        images.append(rgb * alpha[..., None] + background * (1 - alpha[..., None]))
        masks.append(alpha)
    return images, masks


def visual_hull_points(cameras: list[Camera], masks: list[torch.Tensor], n: int, seed: int) -> np.ndarray:
    """n points inside every view's silhouette, drawn by rejection from the cameras' common bounding box."""
    rng = np.random.default_rng(seed)
    centers = np.stack([c.center for c in cameras])
    lo, hi = np.full(3, -1.0) * np.abs(centers).max() / 2, np.full(3, 1.0) * np.abs(centers).max() / 2
    keep: list[np.ndarray] = []
    total = 0
    for _ in range(200):
        p = rng.uniform(lo, hi, size=(200_000, 3))
        ok = np.ones(len(p), dtype=bool)
        for cam, m in zip(cameras, masks):
            q = p @ cam.world_to_cam[:3, :3].T + cam.world_to_cam[:3, 3]
            u = np.floor(cam.fx * q[:, 0] / q[:, 2] + cam.cx).astype(np.int64)
            v = np.floor(cam.fy * q[:, 1] / q[:, 2] + cam.cy).astype(np.int64)
            inside = (q[:, 2] > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
            mm = m.numpy()
            ok &= inside & (mm[v.clip(0, cam.height - 1), u.clip(0, cam.width - 1)] > 0.3)
        keep.append(p[ok])
        total += int(ok.sum())
        if total >= n:
            break
    pts = np.concatenate(keep)
    if len(pts) < n:
        raise SystemExit(f"visual hull held only {len(pts)} of {n} points; check the cameras and masks")
    return pts[:n]


def init_scene(points: np.ndarray, sh_degree: int) -> GaussianScene:
    n = len(points)
    # Initial scale from the mean spacing of n points in the hull's bounding box.
    extent = points.max(0) - points.min(0)
    spacing = float(np.cbrt(np.prod(extent) / n))
    means = torch.tensor(points, dtype=torch.float32)
    return GaussianScene(
        means=means,
        quats=torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        log_scales=torch.full((n, 3), math.log(spacing * 0.7)),
        opacities=torch.full((n,), -2.0),  # sigmoid -> 0.12
        sh_dc=torch.full((n, 3), 0.0),
        sh_rest=torch.zeros(n, num_sh_rest(sh_degree), 3),
        sh_degree=sh_degree,
    )


def find_image(root: Path, name: str) -> Path:
    """The photo of camera ``name`` under ``root``: the name as given, or its stem with a known suffix."""
    for p in (root / name, *(root / f"{name}{ext}" for ext in (".png", ".jpg", ".jpeg", ".JPG", ".PNG"))):
        if p.is_file():
            return p
    for ext in (".png", ".jpg", ".jpeg", ".JPG", ".PNG"):
        hit = next(iter(sorted(root.rglob(f"{name}{ext}"))), None)
        if hit is not None:
            return hit
    raise SystemExit(f"image for camera {name!r} not found under {root}")


def load_photos(cameras: list[Camera], root: Path) -> list[torch.Tensor]:
    """Opaque photos (JPEG or PNG) resized to each camera's size (area filter), as (H, W, 3) in [0, 1]."""
    images = []
    for cam in cameras:
        path = find_image(root, cam.name)
        data = path.read_bytes()
        a = imagecodecs.png_decode(data) if path.suffix.lower() == ".png" else imagecodecs.jpeg_decode(data)
        if a.ndim == 2:
            a = np.repeat(a[..., None], 3, axis=2)
        a = a[..., :3].astype(np.float32) / (65535.0 if a.dtype == np.uint16 else 255.0)
        t = torch.from_numpy(a).permute(2, 0, 1)[None]
        images.append(F.interpolate(t, size=(cam.height, cam.width), mode="area")[0].permute(1, 2, 0))
    return images


def cameras_focus(cameras: list[Camera]) -> tuple[np.ndarray, float]:
    """The point nearest to every camera's optical axis (least squares) and the cameras' mean distance
    from it: the centre and radius of a capture's region of interest."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in cameras:
        f = c.world_to_cam[2, :3]
        M = np.eye(3) - np.outer(f, f)
        A += M
        b += M @ c.center
    centers = np.stack([c.center for c in cameras])
    try:
        focus = np.linalg.solve(A, b)
    except np.linalg.LinAlgError:  # parallel axes (a forward-facing capture): use the centres' mean
        focus = centers.mean(0)
    return focus, float(np.linalg.norm(centers - focus, axis=1).mean())


def shell_points(centre: np.ndarray, radius: float, n: int, seed: int) -> np.ndarray:
    """n points in a thick shell, 1.5-8 camera radii from the capture's centre (log-uniform in radius):
    the far field (walls, sky) that the COLMAP points cover only sparsely."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = radius * np.exp(rng.uniform(math.log(1.5), math.log(8.0), size=(n, 1)))
    return centre + d * r


def nn_spacing(points: np.ndarray, k: int = 3) -> np.ndarray:
    """Mean distance of each point to its k nearest neighbours (chunked brute force)."""
    p = torch.tensor(points, dtype=torch.float32)
    out = torch.empty(len(p))
    for i in range(0, len(p), 2048):
        d = torch.cdist(p[i : i + 2048], p)
        out[i : i + 2048] = d.topk(k + 1, largest=False).values[:, 1:].mean(1)
    return out.clamp_min(1e-7).numpy()


def init_from_points(points: np.ndarray, colours: np.ndarray, sh_degree: int) -> GaussianScene:
    """Isotropic Gaussians at the points, sized by their neighbours' spacing, opacity 0.1 (as 3DGS)."""
    n = len(points)
    return GaussianScene(
        means=torch.tensor(points, dtype=torch.float32),
        quats=torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        log_scales=torch.tensor(np.log(nn_spacing(points)), dtype=torch.float32)[:, None].repeat(1, 3),
        opacities=torch.full((n,), math.log(0.1 / 0.9)),
        sh_dc=torch.tensor((colours / 255.0 - 0.5) / C0, dtype=torch.float32),
        sh_rest=torch.zeros(n, num_sh_rest(sh_degree), 3),
        sh_degree=sh_degree,
    )


def grow(
    params: dict[str, torch.Tensor], optim: torch.optim.Adam, count: int, gen: torch.Generator
) -> tuple[dict[str, torch.Tensor], torch.optim.Adam]:
    """Add ``count`` Gaussians cloned from strong ones (sampled by opacity); each pair splits the
    source's opacity as relocation does. Returns new leaf parameters and an Adam that keeps the old
    Gaussians' moments (zero for the new ones)."""
    with torch.no_grad():
        op = torch.sigmoid(params["opacities"])
        src = torch.multinomial(op.clamp_min(1e-6), count, replacement=True, generator=gen)
        new_op = (1 - torch.sqrt((1 - op[src]).clamp_min(1e-6))).clamp(1e-4, 1 - 1e-4)
        logit = torch.log(new_op / (1 - new_op))
        jitter = torch.randn(count, 3, generator=gen) * torch.exp(params["log_scales"][src]) * 0.5
        added = {k: v[src].clone() for k, v in params.items()}
        added["means"] += jitter
        added["opacities"] = logit
        old_op = params["opacities"].clone()
        old_op[src] = logit
        merged = {k: torch.cat([v if k != "opacities" else old_op, added[k]]) for k, v in params.items()}
    new_params = {k: v.requires_grad_(True) for k, v in merged.items()}
    new_optim = torch.optim.Adam(
        [{"params": [new_params[g["name"]]], "lr": g["lr"], "name": g["name"]} for g in optim.param_groups],
        eps=1e-15,
    )
    for g_old, g_new in zip(optim.param_groups, new_optim.param_groups, strict=True):
        st = optim.state.get(g_old["params"][0])
        if st:
            pad = lambda t: torch.cat([t, torch.zeros((count, *t.shape[1:]), dtype=t.dtype)])  # noqa: E731
            new_optim.state[g_new["params"][0]] = {
                "step": st["step"].clone(),
                "exp_avg": pad(st["exp_avg"]),
                "exp_avg_sq": pad(st["exp_avg_sq"]),
            }
    return new_params, new_optim


def relocate(
    params: dict[str, torch.Tensor], optim: torch.optim.Adam, threshold: float, gen: torch.Generator
) -> int:
    """Move faded Gaussians (opacity < threshold) onto strong ones sampled by opacity; the pair splits it."""
    with torch.no_grad():
        op = torch.sigmoid(params["opacities"])
        dead = torch.nonzero(op < threshold).squeeze(1)
        if len(dead) == 0:
            return 0
        src = torch.multinomial(op.clamp_min(1e-6), len(dead), replacement=True, generator=gen)
        # The two copies share the source's coverage: 1 - (1 - a)^2 = a_old keeps the look.
        new_op = 1 - torch.sqrt((1 - op[src]).clamp_min(1e-6))
        logit = torch.log(new_op.clamp(1e-4, 1 - 1e-4) / (1 - new_op.clamp(1e-4, 1 - 1e-4)))
        jitter = torch.randn(len(dead), 3, generator=gen) * torch.exp(params["log_scales"][src]) * 0.5
        for p in params.values():
            p[dead] = p[src]
        params["means"][dead] += jitter
        params["opacities"][dead] = logit
        params["opacities"][src] = logit
        for p in params.values():  # reset Adam's moments of the moved Gaussians
            st = optim.state.get(p)
            if st:
                st["exp_avg"][dead] = 0
                st["exp_avg_sq"][dead] = 0
        return len(dead)


def is_colmap_capture(source: Path) -> bool:
    return source.is_dir() and any(
        (d / f"points3D{e}").is_file() for d in (source, source / "sparse" / "0") for e in (".bin", ".txt")
    )


def fit(
    source: Path,
    out: Path,
    resolution: int,
    gaussians: int,
    iterations: int,
    sh_degree: int,
    background: float,
    seed: int,
    downscale: int = 4,
    log_every: int = 100,
) -> dict:
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    cams_full = load_cameras(source)
    colmap = is_colmap_capture(source)
    if colmap:
        # Real captures: every camera at 1/downscale of its own size (any aspect ratio), the photos opaque.
        cams = [c.scaled(1.0 / downscale) for c in cams_full]
        root = next((d for d in (source / "images", source) if d.is_dir()), source)
        images = load_photos(cams, root)
    else:
        cams = [c.scaled(resolution / c.width) for c in cams_full]
        images, masks = load_images(cams, source.parent, resolution, background)
    train_idx, test_idx = split_test_views(cams, every=8)
    t0 = time.perf_counter()
    grow_steps: list[int] = []
    if colmap:
        xyz, rgb = load_colmap_points(source)
        focus, cam_radius = cameras_focus([cams[i] for i in train_idx])
        n_shell = max(1000, gaussians // 20)
        pts = np.concatenate([xyz, shell_points(focus, cam_radius, n_shell, seed)])
        cols = np.concatenate([rgb, np.full((n_shell, 3), 128, dtype=np.uint8)])
        scene = init_from_points(pts, cols, sh_degree)
        # 3DGS's spatial learning rate scales with the cameras' extent, not the Gaussians' (far ones).
        extent = 1.1 * cam_radius
        mean_lr = 1.6e-4 * extent
        # Grow geometrically from the initial count to the budget every 100 iterations until half-way.
        grow_steps = list(range(500, max(501, iterations // 2), 100))
    else:
        pts = visual_hull_points([cams[i] for i in train_idx], [masks[i] for i in train_idx], gaussians, seed)
        scene = init_scene(pts, sh_degree)
        extent = float(np.linalg.norm(pts.max(0) - pts.min(0)))
        mean_lr = 1.6e-4 * extent * 10
    n_start = scene.num_gaussians
    params = {k: v.clone().requires_grad_(True) for k, v in scene.tensors().items()}
    lrs = {
        "means": mean_lr,
        "quats": 1e-3,
        "log_scales": 5e-3,
        "opacities": 5e-2,
        "sh_dc": 2.5e-3,
        "sh_rest": 2.5e-3 / 20,
    }
    optim = torch.optim.Adam([{"params": [params[k]], "lr": lrs[k], "name": k} for k in params], eps=1e-15)
    bg = torch.full((3,), background)
    order = torch.randperm(len(train_idx), generator=gen)
    for it in range(1, iterations + 1):
        # Means' learning rate decays 100x over the run, as in 3DGS.
        frac = it / iterations
        for g in optim.param_groups:
            if g["name"] == "means":
                g["lr"] = lrs["means"] * (0.01**frac)
        # Raise the active SH degree gradually, as 3DGS does, so colour settles before detail.
        deg = min(sh_degree, (it * (sh_degree + 1)) // max(iterations // 2, 1))
        k = train_idx[int(order[it % len(order)])]
        if it % len(order) == 0:
            order = torch.randperm(len(train_idx), generator=gen)
        s = GaussianScene(**params, sh_degree=sh_degree)
        img = render(s, cams[k], background=bg, sh_degree=deg).image
        loss = 0.8 * (img - images[k]).abs().mean() + 0.2 * (1 - ssim(img, images[k]))
        optim.zero_grad(set_to_none=True)
        loss.backward()
        optim.step()
        if it % 250 == 0 and it < iterations * 0.8:
            moved = relocate(params, optim, 0.01, gen)
        else:
            moved = 0
        if it in grow_steps:
            n = params["means"].shape[0]
            left = len(grow_steps) - grow_steps.index(it)
            target = round(n * (gaussians / n) ** (1.0 / left)) if n < gaussians else n
            if target > n:
                params, optim = grow(params, optim, target - n, gen)
        if it % log_every == 0:
            print(
                f"it {it:5d}  loss {loss.item():.4f}  deg {deg}  moved {moved}  "
                f"n {params['means'].shape[0]}  {time.perf_counter() - t0:.0f}s",
                flush=True,
            )
    fit_seconds = time.perf_counter() - t0
    final = GaussianScene(**{k: v.detach() for k, v in params.items()}, sh_degree=sh_degree)

    out.mkdir(parents=True, exist_ok=True)
    (out / "test").mkdir(exist_ok=True)
    ps, ss = [], []
    with torch.no_grad():
        for i in test_idx:
            img = render(final, cams[i], background=bg).image
            a, b = quantize8(img), quantize8(images[i])
            ps.append(float(psnr(a, b)))
            ss.append(float(ssim(a, b)))
            png = np.ascontiguousarray((images[i].numpy() * 255 + 0.5).clip(0, 255).astype(np.uint8))
            (out / "test" / f"{cams[i].name}.png").write_bytes(imagecodecs.png_encode(png))
    write_ply(final, out / "point_cloud.ply")
    save_cameras_json(cams, out / "cameras.json")
    report = {
        "source": "colmap" if colmap else "nerf-synthetic",
        "resolution": f"{cams[0].width}x{cams[0].height}" if colmap else resolution,
        "gaussians": final.num_gaussians,
        "initial_gaussians": n_start,
        "iterations": iterations,
        "sh_degree": sh_degree,
        "background": background,
        "seed": seed,
        "train_views": len(train_idx),
        "test_views": len(test_idx),
        "test_names": [cams[i].name for i in test_idx],
        "test_psnr": float(np.mean(ps)),
        "test_ssim": float(np.mean(ss)),
        "fit_seconds": fit_seconds,
        "ply_bytes": os.path.getsize(out / "point_cloud.ply"),
        "command": " ".join(["python", *sys.argv]),
    }
    (out / "fit.json").write_text(json.dumps(report, indent=1))
    return report


def main(
    source: Path = typer.Argument(
        ...,
        help="transforms_train.json of a NeRF-synthetic scene, or a COLMAP capture (sparse/0, images/)",
    ),
    out: Path = typer.Option(..., "-o", "--out", help="output folder"),
    resolution: int = typer.Option(200, help="square image side used for fitting (NeRF-synthetic)"),
    downscale: int = typer.Option(4, help="photos fitted at 1/downscale of their size (COLMAP captures)"),
    gaussians: int = typer.Option(20000, help="budget of Gaussians (fixed; a COLMAP fit grows to it)"),
    iterations: int = typer.Option(3000),
    sh_degree: int = typer.Option(3),
    background: float = typer.Option(
        1.0,
        help="background grey level the photos are composited on (0 suits captures: their photos are opaque)",
    ),
    seed: int = typer.Option(0),
) -> None:
    torch.set_num_threads(1)
    # Bad input (a photo that does not decode, a malformed points3D.bin) ends as one line, as in gspc's CLI.
    try:
        with one_line_warnings(lambda line: print(f"fit_scene: {line}", file=sys.stderr)):
            rep = fit(source, out, resolution, gaussians, iterations, sh_degree, background, seed, downscale)
    except (GspcError, OSError, RuntimeError, ValueError) as e:  # imagecodecs' errors are RuntimeErrors
        raise SystemExit(f"fit_scene: error: {e}") from None
    print(json.dumps({k: v for k, v in rep.items() if k != "test_names"}, indent=1))


if __name__ == "__main__":
    typer.run(main)
