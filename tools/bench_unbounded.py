"""Bounded objects given an unbounded world: a background shell and far floaters, coded with positions on the
plain grid (format 1.1) and on the contracted grid (gspc/codec/positions.py), scored at the object's views.

    python tools/bench_unbounded.py -o bench/unbounded.md
    python tools/bench_unbounded.py --bound                            # the shell's position bound
    python tools/bench_unbounded.py --capture /work/fits/bird_q4_100k  # a capture's room as the shell

The generator (``add_background``): the object's Gaussians stay as they are; ``fraction`` of their count is
added as a background shell (copies of random object Gaussians, placed in random directions at
``shell_radius`` times the object's radius, 0.9-1.1 of it, scaled up with their distance so they keep their
angular size, like the walls or sky a capture's background holds), and ``floaters`` copies far out at
``floater_radius`` times the radius (scaled up 30x). Views are the object's own synthesised views (cameras
about 3 radii from its centre, inside the shell): the background shows behind the object.

Scores: PSNR of the coded scene's renders against the same scene's original renders at those views, codec
alone (no side information, no refinement), with bytes, and bytes per object Gaussian and per added one.
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass, replace
from pathlib import Path
from unittest import mock

import numpy as np
import torch
import typer
from bench_setups import fit_setup

from gspc.cameras import Camera
from gspc.codec import positions
from gspc.encoder.coding import EncodedAttributes, encode_attributes
from gspc.io import read_scene
from gspc.metrics import psnr, quantize8
from gspc.presets import QUALITY
from gspc.render import render
from gspc.scene import GaussianScene
from gspc.views import robust_bounds, synthesize_views

FLOATERS = 20


def add_background(
    scene: GaussianScene,
    fraction: float,
    shell_radius: float,
    floaters: int = FLOATERS,
    floater_radius: float = 300.0,
    seed: int = 0,
) -> GaussianScene:
    """The scene with a background shell of ``fraction`` x its count and ``floaters`` far Gaussians added."""
    g = np.random.default_rng(seed)
    lo, hi = robust_bounds(scene)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2)
    n = scene.num_gaussians

    def copies(count: int, dist: float, jitter: float, grow: float) -> dict[str, torch.Tensor]:
        src = torch.from_numpy(g.integers(0, n, count))
        d = g.normal(size=(count, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        r = radius * dist * g.uniform(1 - jitter, 1 + jitter, (count, 1))
        out = {k: v[src].clone() for k, v in scene.tensors().items()}
        out["means"] = torch.from_numpy((centre + d * r).astype(np.float32))
        out["log_scales"] = out["log_scales"] + float(np.log(grow))
        return out

    shell = copies(round(fraction * n), shell_radius, 0.1, shell_radius / 3)
    far = copies(floaters, floater_radius, 0.0, 30.0)
    merged = {k: torch.cat([v, shell[k], far[k]]) for k, v in scene.tensors().items()}
    return GaussianScene(**merged, sh_degree=scene.sh_degree)


@dataclass
class Score:
    bytes: int
    position_bytes: int
    psnr: float
    object_psnr: float
    seconds: float
    encoded: EncodedAttributes


def masked_psnr(a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor) -> float:
    mse = float(((a - b) ** 2)[mask].mean())
    return 10 * float(np.log10(1.0 / max(mse, 1e-12)))


def code(
    scene: GaussianScene,
    lam: float,
    cams: list[Camera],
    reference: list[torch.Tensor],
    masks: list[torch.Tensor],
    plain: bool,
    background: torch.Tensor | None = None,
) -> Score:
    params = QUALITY["low"].attributes.with_lambda(lam)
    t0 = time.perf_counter()
    if plain:  # format 1.1's grid: one box over every Gaussian
        with mock.patch.object(positions, "region_of_interest", lambda means: None):
            enc = encode_attributes(scene, params)
    else:
        enc = encode_attributes(scene, params)
    seconds = time.perf_counter() - t0
    with torch.no_grad():
        imgs = [quantize8(render(enc.decoded, c, background=background).image.clamp(0, 1)) for c in cams]
    p = float(np.mean([float(psnr(a, r)) for a, r in zip(imgs, reference)]))
    q = float(np.mean([masked_psnr(a, r, m) for a, r, m in zip(imgs, reference, masks)]))
    return Score(enc.num_bytes, len(enc.chunks["POSN"]), p, q, seconds, enc)


def per_added(world: Score, alone: Score, added: int) -> str:
    positions = (world.position_bytes - alone.position_bytes) / added
    return f"{(world.bytes - alone.bytes) / added:.2f} ({positions:.2f})"


def shell_position_bound(scene: GaussianScene, world: GaussianScene, lam: float) -> tuple:
    """(shell Gaussians, bytes per shell Gaussian that any lossless coder needs for their voxels, bytes per
    shell Gaussian of gspc's position coder on the shell alone, median size / voxel of the object's and of
    the shell's Gaussians), on the grid the codec picks for ``world``.

    The bound: m points spread uniformly over V voxels (the shell's volume in grid space) form a set of
    C(V, m) possibilities, log2 C(V, m) ~ m (log2(V / m) + log2 e) bits for V >> m. Size / voxel: each
    Gaussian's median scale over the voxel's world size across the line of sight from the region of interest
    (grid step x R x |u| / |y|, the contraction's tangential stretch).
    """
    n, m = scene.num_gaussians, world.num_gaussians - scene.num_gaussians - FLOATERS
    bits = QUALITY["low"].attributes.with_lambda(lam).position_precision
    grid = positions.curve_order(world.means.numpy(), bits)[2]
    centre, radius = grid.contraction.centre, grid.contraction.radius
    y = positions.contract(world.means.numpy()[n : n + m], centre, radius)
    rho = np.sqrt((y * y).sum(1))
    volume = 4.0 / 3.0 * np.pi * (rho.max() ** 3 - rho.min() ** 3) / float(np.prod(grid.step))
    bound = (np.log2(volume / m) + np.log2(np.e)) / 8.0
    v = positions.voxelise(y, grid.lo, grid.step, grid.bits)
    v = v[np.argsort(positions.morton_encode(v, grid.bits), kind="stable")]
    coded = len(positions.encode_positions(v, replace(grid, far=None))) / m
    means = world.means.numpy().astype(np.float64)
    r = np.sqrt(((means - centre) ** 2).sum(1)) / radius
    y_all = positions.contract(means, centre, radius)
    stretch = np.where(r > 1.0, r / np.maximum(np.sqrt((y_all * y_all).sum(1)), 1e-12), 1.0)
    voxel = max(grid.step) * radius * stretch
    size = np.exp(np.median(world.log_scales.numpy().astype(np.float64), 1)) / voxel
    return m, float(bound), coded, float(np.median(size[:n])), float(np.median(size[n : n + m]))


def bound_table(scenes: list[str], lam: float, shells: list[float], fractions: list[float]) -> str:
    lines = [
        "| scene | lambda | shell | fraction | shell Gaussians | bound B/G "
        "| gspc's coder, shell alone, B/G | size / voxel, object | size / voxel, shell |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for path in scenes:
        obj = read_scene(path)
        for shell in shells:
            for frac in fractions:
                m, bound, coded, size_obj, size_shell = shell_position_bound(
                    obj, add_background(obj, frac, shell), lam
                )
                lines.append(
                    f"| {Path(path).name} | {lam:g} | {shell:g} | {frac:.0%} | {m:,} | {bound:.2f} "
                    f"| {coded:.2f} | {size_obj:.2f} | {size_shell:.2f} |"
                )
                print(lines[-1], flush=True)
    return "\n".join(lines) + "\n"


def capture_table(fit: Path, lams: list[float], splits: list[float]) -> str:
    """A real capture split in two at ``split`` x the radius of the region of interest the codec picks for it:
    the Gaussians inside are the object, the rest (its room, floaters) the added ones. The same scores as the
    generator's table, at the fit's held-out views."""
    setup = fit_setup(fit)
    world = read_scene(setup.scene_path)
    means = world.means.numpy().astype(np.float64)
    centre, radius = positions.region_of_interest(means)
    dist = np.sqrt(((means - centre) ** 2).sum(1)) / radius
    cams, bg = setup.eval_cams, torch.tensor(setup.background)
    with torch.no_grad():
        ref = [quantize8(render(world, c, background=bg).image.clamp(0, 1)) for c in cams]
    lines = [
        "| split (x R) | lambda | object Gaussians | added Gaussians | object alone dB | contracted dB "
        "| contracted vs alone, object pixels | object's Gaussians coded in the whole, rendered alone dB "
        "| object B/G | contracted B per added G |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for split in splits:
        obj = world.subset(np.flatnonzero(dist <= split))
        with torch.no_grad():
            renders = [render(obj, c, background=bg) for c in cams]
        ref_obj = [quantize8(r.image.clamp(0, 1)) for r in renders]
        masks = [(r.alpha > 0.5)[..., None].expand(-1, -1, 3) for r in renders]
        n, added = obj.num_gaussians, world.num_gaussians - obj.num_gaussians
        for lam in lams:
            alone = code(obj, lam, cams, ref_obj, masks, plain=False, background=bg)
            whole = code(world, lam, cams, ref, masks, plain=False, background=bg)
            # the object's own Gaussians as the whole scene coded them, rendered without the room
            part = whole.encoded.decoded.subset(np.flatnonzero(dist[whole.encoded.kept] <= split))
            with torch.no_grad():
                imgs = [quantize8(render(part, c, background=bg).image.clamp(0, 1)) for c in cams]
            within = float(np.mean([float(psnr(a, r)) for a, r in zip(imgs, ref_obj)]))
            cells = [
                f"{split:g}",
                f"{lam:g}",
                f"{n:,}",
                f"{added:,}",
                f"{alone.psnr:.2f} / {alone.object_psnr:.2f}",
                f"{whole.psnr:.2f} / {whole.object_psnr:.2f}",
                f"{whole.object_psnr - alone.object_psnr:+.2f}",
                f"{within:.2f} ({within - alone.psnr:+.2f})",
                f"{alone.bytes / n:.2f} ({alone.position_bytes / n:.2f})",
                per_added(whole, alone, added),
            ]
            lines.append("| " + " | ".join(cells) + " |")
            print(lines[-1], flush=True)
    return "\n".join(lines) + "\n"


SCENES = [
    "../shared/data/statues/massa.sog",
    "../shared/data/donut/fused.ply",
    "examples/lego/point_cloud.ply",
]


def main(
    scenes: list[str] = typer.Option(SCENES, "--scene", help="bounded objects to surround"),
    fractions: str = typer.Option("0.02,0.05,0.2"),
    shells: str = typer.Option("10,30,100"),
    lams: str = typer.Option("1,8", help="high and low presets' lambdas"),
    views: int = typer.Option(16),
    size: int = typer.Option(256),
    out: Path = typer.Option(Path("bench/unbounded.md"), "-o"),
    bound: bool = typer.Option(False, help="only the shell's position bound at the low preset (to stdout)"),
    capture: Path | None = typer.Option(
        None,
        help="only a real capture (a tools/fit_scene.py folder) split at its region of interest (to stdout)",
    ),
    splits: str = typer.Option("1,4", help="with --capture: object = Gaussians within these multiples of R"),
) -> None:
    torch.set_num_threads(1)
    if capture is not None:
        capture_table(capture, [float(x) for x in lams.split(",")], [float(x) for x in splits.split(",")])
        return
    if bound:
        floats = [float(x) for x in shells.split(",")], [float(x) for x in fractions.split(",")]
        bound_table(scenes, float(lams.split(",")[-1]), *floats)
        return
    rows = []
    for path in scenes:
        obj = read_scene(path)
        n = obj.num_gaussians
        cams = synthesize_views(obj, views, size, size)
        with torch.no_grad():
            renders = [render(obj, c) for c in cams]
        ref_obj = [quantize8(r.image.clamp(0, 1)) for r in renders]
        masks = [(r.alpha > 0.5)[..., None].expand(-1, -1, 3) for r in renders]
        for lam in [float(x) for x in lams.split(",")]:
            alone = code(obj, lam, cams, ref_obj, masks, plain=True)
            for shell in [float(x) for x in shells.split(",")]:
                for frac in [float(x) for x in fractions.split(",")]:
                    world = add_background(obj, frac, shell)
                    with torch.no_grad():
                        ref = [quantize8(render(world, c).image.clamp(0, 1)) for c in cams]
                    old = code(world, lam, cams, ref, masks, plain=True)
                    new = code(world, lam, cams, ref, masks, plain=False)
                    added = world.num_gaussians - n
                    cells = [
                        Path(path).name,
                        f"{lam:g}",
                        f"{shell:g}",
                        f"{frac:.0%}",
                        f"{alone.psnr:.2f} / {alone.object_psnr:.2f}",
                        f"{old.psnr:.2f} / {old.object_psnr:.2f}",
                        f"{new.psnr:.2f} / {new.object_psnr:.2f}",
                        f"{new.object_psnr - alone.object_psnr:+.2f}",
                        f"{alone.bytes / n:.2f} ({alone.position_bytes / n:.2f})",
                        per_added(old, alone, added),
                        per_added(new, alone, added),
                        f"{old.seconds:.1f} / {new.seconds:.1f}",
                    ]
                    rows.append("| " + " | ".join(cells) + " |")
                    print(rows[-1], flush=True)
    text = "\n".join(
        [
            "# Positions in unbounded scenes: plain grid (1.1) vs contracted grid",
            "",
            f"Command: `python tools/bench_unbounded.py --fractions {fractions} --shells {shells} "
            f"--lams {lams} --views {views} --size {size}`",
            f"(scenes: {', '.join(Path(s).name for s in scenes)})",
            "",
            f"Machine: {platform.machine()}, {os.cpu_count()} vCPUs, torch {torch.__version__}, one thread, "
            "other jobs running. Codec alone (no side information, no refinement), lambda 1 = high preset, "
            f"8 = low. PSNR at {views} synthesised views ({size}x{size}) around the object, against the same "
            "scene's original renders. Each world adds a shell of `fraction` x the object's count at "
            "`shell` x its radius plus 20 floaters at 300 x (tools/bench_unbounded.py, `add_background`).",
            "dB columns: whole frame / the object's pixels. Bytes per Gaussian: all chunks (positions).",
            "",
            "| scene | lambda | shell | fraction | object alone dB | plain grid dB | contracted dB "
            "| contracted vs alone, object pixels | object B/G | plain B per added G "
            "| contracted B per added G | encode s plain / contracted |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
            *rows,
            "",
        ]
    )
    out.write_text(text)


if __name__ == "__main__":
    typer.run(main)
