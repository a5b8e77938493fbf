"""Refinement per tile against shared views, against one global refinement, at equal bytes (issue 52,
item 2).

    GSPC_THREADS=1 python tools/bench_regional.py --scene examples/lego --tile-size 8192 -o F
    GSPC_THREADS=1 python tools/bench_regional.py --scene /work/fits/bird_q4_100k --tile-size 32768 --every 8
    GSPC_THREADS=1 python tools/bench_regional.py --scene /work/scale/scale_1000000 --closeups 8 \
        --tile-size 262144 --lam 20 --variants global,frozen

A question about the decoder alone, so every variant refines the same bytes: the scene is coded in tiles
without side information (`gspc encode --no-side-info --tile-size`), the residuals of the whole scene's
render (every tile drawn) are made at the side views as the encoder makes them (the low preset's image
codec, distance and resolution; views with too little to send skipped) and restored as the decoder
restores them (gspc/reconstruct.py); then the decoded Gaussians are refined inside their cells
(the decoder's schedule, ``--iterations`` steps a run):

- global: every tile at once against every view (what one block's decoder does);
- frozen: each tile alone against the views that see it, every other tile drawn as
  decoded and never refined (the tiles could run side by side on separate workers);
- second: the same again with the other tiles drawn as the first round refined them;
- in-turn: ``--turns`` rounds of ``--iterations / --turns`` steps, the tiles one after another, each beside
  the others as last refined.

Each is scored at held-out views (every ``--every``-th camera; the side views are the other cameras, at most
``--views`` of them evenly) against the original's renders (gspc/metrics.py mean_psnr). CPU seconds are the
refinement's and its scoring's, on one thread.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from gspc.cameras import Camera
from gspc.codec import residuals
from gspc.codec.cells import quantisation_cells, span_cells
from gspc.codec.quantisers import Box
from gspc.codec.tiles import TileDecodeJob, decode_tile_section
from gspc.encoder.side import side_candidate, view_residuals
from gspc.format.file import FileReader
from gspc.io import read_scene
from gspc.io.camera_files import load_cameras
from gspc.io.cameras_json import save_cameras_json
from gspc.metrics import mean_psnr
from gspc.presets import QUALITY
from gspc.reconstruct import decoder_refinement, render_images, restored_targets
from gspc.render.work import view_pairs
from gspc.restore.restorer import load_restorer
from gspc.scene import GaussianScene

BACKGROUND = (0.0, 0.0, 0.0)


def refined(
    scene: GaussianScene,
    cams: list[Camera],
    targets: list[torch.Tensor],
    cells: dict[str, Box],
    drawn: GaussianScene | None,
    iterations: int,
) -> GaussianScene:
    """The decoder's refinement (gspc/reconstruct.py decoder_refinement) of ``scene`` inside ``cells``,
    ``drawn`` rendered beside it and never refined."""
    run = decoder_refinement(scene, None, cams, targets, iterations, BACKGROUND, drawn=drawn, cells=cells)
    run.run()
    return run.result().scene


def tile_refined(
    k: int,
    scenes: list[GaussianScene],
    cells: dict[str, Box],
    cams: list[Camera],
    targets: list[torch.Tensor],
    iterations: int,
) -> GaussianScene:
    """Tile ``k`` of ``scenes`` refined against the views that see it, the other tiles drawn as they are
    in ``scenes``."""
    tile = scenes[k]
    seen = [v for v, c in enumerate(cams) if view_pairs(tile, c) > 0]
    if not seen:
        return tile
    others = GaussianScene.concat([s for j, s in enumerate(scenes) if j != k])
    return refined(tile, [cams[v] for v in seen], [targets[v] for v in seen], cells, others, iterations)


def tile_rounds(
    scenes: list[GaussianScene],
    cells: list[dict[str, Box]],
    cams: list[Camera],
    targets: list[torch.Tensor],
    iterations: int,
    in_turn: bool,
    rounds: int = 1,
) -> list[GaussianScene]:
    """``rounds`` rounds in which every tile is refined once: beside the others as the round found them
    (the tiles could run side by side), or ``in_turn``, one after another, each beside the others as last
    refined."""
    for _ in range(rounds):
        current = list(scenes)
        for k in range(len(scenes)):
            current[k] = tile_refined(k, current if in_turn else scenes, cells[k], cams, targets, iterations)
        scenes = current
    return scenes


def run_scene(args: argparse.Namespace, work: Path) -> list[str]:
    if args.closeups:
        from bench_scale_pipeline import closeup_cameras

        cams = closeup_cameras(json.loads((args.scene / "scene.json").read_text()), args.closeups)
    else:
        cams = load_cameras(args.scene / "cameras.json")
    held = [c for i, c in enumerate(cams) if i % args.every == 0]
    given = [c for i, c in enumerate(cams) if i % args.every != 0]
    save_cameras_json(given, work / "given.json")
    original = read_scene(args.scene / "point_cloud.ply")
    reference = render_images(original, held, BACKGROUND)

    coded = work / "tiled.gspc"
    ply, given_json = str(args.scene / "point_cloud.ply"), str(work / "given.json")
    options = f"--lambda {args.lam} --tile-size {args.tile_size} --no-side-info --workers 1".split()
    encode = [sys.executable, "-m", "gspc.cli", "encode", ply, "-o", str(coded), "--cameras", given_json]
    subprocess.run(encode + options, check=True, capture_output=True)
    with FileReader(coded) as reader:
        if reader.tiles is None:
            raise SystemExit(f"{args.scene}: one block at --tile-size {args.tile_size}; give a smaller one")
        total = sum(reader.tile_bytes())
        jobs = [
            TileDecodeJob(k, reader.tile(k), t.section, t.box, total)
            for k, t in enumerate(reader.tiles.tiles)
        ]
    decoded = [decode_tile_section(j) for j in jobs]
    tiles = [d.scene for d in decoded]
    parts = [(d.scene, j.section, d.precision) for d, j in zip(decoded, jobs)]
    cells = [quantisation_cells(*part) for part in parts]
    whole = GaussianScene.concat(tiles)

    preset = QUALITY["low"]
    side_cams = given[:: max(1, -(-len(given) // args.views))]
    coded_side = render_images(whole, side_cams, BACKGROUND)
    res = view_residuals(render_images(original, side_cams, BACKGROUND), coded_side)
    distances = residuals.plan_residual_rates(res, preset.residual_distance)
    side = side_candidate(side_cams, res, distances, preset.residual_codec, preset.residual_scale)
    targets = restored_targets(coded_side, side.records, side.images, load_restorer(args.restorer))
    del coded_side, res, original

    def score(scene: GaussianScene) -> str:
        return f"{mean_psnr(render_images(scene, held, BACKGROUND), reference):.2f}"

    rows = [("the tiles as decoded (no refinement)", score(whole), "-")]

    def timed(label: str, run) -> list[GaussianScene]:
        t0 = time.process_time()
        out = run()
        rows.append((label, score(GaussianScene.concat(out)), f"{time.process_time() - t0:.0f}"))
        return out

    variants = args.variants.split(",")
    if "global" in variants:
        timed(
            "global: every tile at once, every view",
            lambda: [refined(whole, side_cams, targets, span_cells(parts), None, args.iterations)],
        )
    if "frozen" in variants:
        first = timed(
            "per tile, neighbours frozen as decoded",
            lambda: tile_rounds(tiles, cells, side_cams, targets, args.iterations, in_turn=False),
        )
        if "second" in variants:
            timed(
                "per tile, a second round beside the first round's",
                lambda: tile_rounds(first, cells, side_cams, targets, args.iterations, in_turn=False),
            )
    if "in-turn" in variants:
        timed(
            f"per tile in turn: {args.turns} rounds of {args.iterations // args.turns} steps, each tile "
            "beside the others as last refined",
            lambda: tile_rounds(
                tiles, cells, side_cams, targets, args.iterations // args.turns, True, args.turns
            ),
        )
    sizes = ", ".join(f"{t.num_gaussians:,}" for t in tiles)
    lines = [
        f"### {args.scene.name}: {len(tiles)} tiles ({sizes} Gaussians), lambda {args.lam:g}",
        "",
        f"{len(given)} cameras given to the encoder, {len(held)} held out "
        f"({held[0].width}x{held[0].height}); {len(side_cams)} side views, {len(side.images)} with a "
        f"residual: {len(side.payload or b''):,} B of side information beside the tiles' "
        f"{coded.stat().st_size:,} B. "
        f"{args.iterations} iterations a refinement.",
        "",
        "| refinement | held-out PSNR dB | CPU s |",
        "|---|---:|---:|",
        *[f"| {a} | {b} | {c} |" for a, b, c in rows],
        "",
    ]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, required=True, help="a folder: point_cloud.ply, cameras.json")
    ap.add_argument("--closeups", type=int, default=0, help="a scale scene: close-up cameras a copy")
    ap.add_argument("--every", type=int, default=4, help="every N-th camera held out")
    ap.add_argument("--lam", type=float, default=8.0)
    ap.add_argument("--tile-size", type=int, default=32768)
    ap.add_argument("--views", type=int, default=64, help="side views, evenly among the given cameras")
    ap.add_argument("--iterations", type=int, default=300)
    ap.add_argument(
        "--variants",
        default="global,frozen,second",
        help="of global, frozen, second, in-turn (comma-separated)",
    )
    ap.add_argument("--turns", type=int, default=3, help="in-turn: rounds, each of iterations/turns steps")
    ap.add_argument("--restorer", default="nafnet-s16-v3")
    ap.add_argument("-o", "--out", type=Path, default=None, help="append the report here (default: print)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        lines = run_scene(args, Path(tmp))
    machine = f"{platform.node()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at the end"
    text = "\n".join(lines + [f"Machine: {machine}; torch {torch.__version__}.", ""])
    print(text)
    if args.out:  # appended, so that runs of several scenes make one report
        with open(args.out, "a") as report:
            print("\n" + text, file=report)


if __name__ == "__main__":
    main()
