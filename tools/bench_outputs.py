"""The scene files gspc writes (gspc/io: PLY, SPZ versions 2-4, glTF binary): bytes, write time, what a
round trip through gspc's reader and splat-transform's reader gives back, and SPZ bytes against Niantic's own
writer.

    python tools/bench_outputs.py [--npm-dir /tmp/gspc-spz-npm] [--synth 100000] -o bench/outputs.md

Scenes: ../shared/data/donut/fused.ply (a trained scene, SH degree 0) and a seeded synthetic SH-3 scene
inside what SPZ represents. Errors are the largest over all Gaussians, in units of the SPZ field's own step
(positions 2^-fractional bits, alpha 1/255, log scale 1/16, colour 1/(0.15 * 255), SH 1/128): a round trip
within SPZ's quantisation stays at or under 0.5 of a step, plus the bucket Niantic's SH precision rounds to
(band 1: 4 bytes, bands 2-3: 8). Write times: median of three, one torch thread. With --npm-dir (a folder
where `npm install @playcanvas/splat-transform@3.7.0` ran), each SPZ is also read by splat-transform and the
same PLY is written by Niantic's writer (splat-transform's WASM build of nianticlabs/spz) for comparison.
"""

from __future__ import annotations

import gzip
import math
import os
import platform
import statistics
import subprocess
import tempfile
import time
from functools import partial
from pathlib import Path

import torch
import typer
from scenes import spz_range_scene

from gspc.io import read_ply, read_spz, write_glb, write_ply, write_spz

ROOT = Path(__file__).resolve().parents[1]
DONUT = ROOT.parent / "shared" / "data" / "donut" / "fused.ply"


def timed(fn) -> float:
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


ATTRIBUTES = ("means", "quats", "log_scales", "opacities", "sh_dc", "sh_rest")


def steps(src, back, fractional_bits: int) -> dict[str, float]:
    """Largest round-trip error of each attribute in SPZ steps; rotation as an angle in degrees."""

    def worst(a: torch.Tensor, b: torch.Tensor) -> float:
        return float((a.double() - b.double()).abs().max())

    colour = 0.5 / 0.15  # the DC values SPZ's colour bytes reach
    out = {
        "position": worst(back.means, src.means) * 2**fractional_bits,
        "alpha": worst(torch.sigmoid(back.opacities.double()), torch.sigmoid(src.opacities.double())) * 255,
        "log scale": worst(back.log_scales, src.log_scales.clamp(-10, 255 / 16 - 10)) * 16,
        "colour": worst(back.sh_dc, src.sh_dc.clamp(-colour, colour)) * 0.15 * 255,
    }
    if src.sh_degree:
        out["SH band 1"] = worst(back.sh_rest[:, :3], src.sh_rest[:, :3]) * 128
        out["SH bands 2-3"] = worst(back.sh_rest[:, 3:], src.sh_rest[:, 3:]) * 128
    unit = [q.double() / q.double().norm(dim=1, keepdim=True) for q in (src.quats, back.quats)]
    cosine = (unit[0] * unit[1]).sum(1).abs().clamp(max=1)
    out["rotation (deg)"] = math.degrees(2 * math.acos(float(cosine.min())))
    return out


def splat_transform(npm: Path, *args: str | Path) -> None:
    cli = npm / "node_modules" / ".bin" / "splat-transform"
    cmd = [str(cli), "-w", "-g", "cpu", *map(str, args)]
    subprocess.run(cmd, check=True, capture_output=True, timeout=900)


def header_bits(path: Path) -> int:
    data = path.read_bytes()
    head = data[:16] if data[:4] == b"NGSP" else gzip.decompress(data)[:16]
    return head[13]


def writers(scene) -> list[tuple[str, str, object]]:
    return [
        ("PLY", ".ply", partial(write_ply, scene)),
        ("SPZ v2", ".v2.spz", partial(write_spz, scene, version=2)),
        ("SPZ v3 (default)", ".v3.spz", partial(write_spz, scene, version=3)),
        ("SPZ v4", ".v4.spz", partial(write_spz, scene, version=4)),
        (".glb", ".glb", partial(write_glb, scene)),
    ]


def file_rows(scene, tmp: Path, npm_dir: Path | None) -> list[str]:
    """One table row per format: bytes, write time, SPZ round trips through gspc and splat-transform."""
    n = scene.num_gaussians
    rows = [
        "| file | bytes | B/Gaussian | write s | round trip, in SPZ steps | splat-transform reads |",
        "|---|---|---|---|---|---|",
    ]
    for label, suffix, write in writers(scene):
        path = tmp / f"out{suffix}"
        seconds = timed(lambda: write(path))  # noqa: B023
        size = path.stat().st_size
        trip = theirs = ""
        if suffix.endswith(".spz"):
            back = read_spz(path)
            trip = ", ".join(f"{k} {v:.3g}" for k, v in steps(scene, back, header_bits(path)).items())
            if npm_dir:
                splat_transform(npm_dir, path, tmp / "st.ply")
                st = read_ply(tmp / "st.ply")
                diffs = [(getattr(st, k) - getattr(back, k)).abs() for k in ATTRIBUTES]
                diff = max(float(d.max()) for d in diffs if d.numel())
                theirs = f"as gspc reads it (largest difference {diff:.2g})"
        rows.append(f"| {label} | {size:,} | {size / n:.2f} | {seconds:.2f} | {trip} | {theirs} |")
    return rows


def niantic_rows(source: Path, tmp: Path, npm_dir: Path) -> list[str]:
    """gspc's SPZ against Niantic's writer on one PLY: bytes, and the Gaussians that decode differently."""
    rows = ["", "Niantic's writer (splat-transform 3.7.0, `-g cpu`) on the same PLY:", ""]
    for version in (3, 4):
        theirs, ours = tmp / f"niantic.v{version}.spz", tmp / f"ours.v{version}.spz"
        splat_transform(npm_dir, *([] if version == 4 else ["--spz-version", "3"]), source, theirs)
        write_spz(read_ply(source), ours, version=version)
        if ours.read_bytes() == theirs.read_bytes():
            verdict = "byte-identical to gspc's"
        else:
            a, b = read_spz(ours), read_spz(theirs)
            n = a.num_gaussians
            differ = torch.zeros(n, dtype=torch.bool)
            for k in ATTRIBUTES:
                differ |= (getattr(a, k) != getattr(b, k)).reshape(n, -1).any(1)
            worst = steps(b, a, header_bits(ours))
            rotation = worst.pop("rotation (deg)")
            verdict = (
                f"gspc's {ours.stat().st_size:,}; {int(differ.sum())} of {n:,} Gaussians decode differently, "
                f"by at most {max(worst.values()):.2g} step ({rotation:.2g} degrees of rotation)"
            )
        rows.append(f"- v{version}: {theirs.stat().st_size:,} bytes; {verdict}")
    return rows


def main(
    npm_dir: Path | None = typer.Option(None, help="folder with node_modules/@playcanvas/splat-transform"),
    synth: int = typer.Option(100_000, help="Gaussians in the synthetic SH-3 scene"),
    out: Path | None = typer.Option(None, "-o", help="Markdown to write"),
) -> None:
    torch.set_num_threads(1)
    scenes = {"synthetic SH-3": spz_range_scene(synth, 3, seed=21)}
    if DONUT.is_file():
        scenes = {"donut (fused.ply)": read_ply(DONUT), **scenes}
    npm = f" --npm-dir {npm_dir}" if npm_dir else ""
    lines = [
        f"Command: `python tools/bench_outputs.py{npm} --synth {synth}`",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} CPUs, one torch thread; other jobs were running.",
        "",
    ]
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        for name, scene in scenes.items():
            lines += [f"### {name}: {scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}", ""]
            lines += file_rows(scene, tmp, npm_dir)
            if npm_dir:
                write_ply(scene, tmp / "source.ply")
                lines += niantic_rows(tmp / "source.ply", tmp, npm_dir)
            lines.append("")
    text = "\n".join(lines)
    print(text)
    if out:
        out.write_text(text)


if __name__ == "__main__":
    typer.run(main)
