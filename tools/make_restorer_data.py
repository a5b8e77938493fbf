"""Make training data for gspc's restorer: renders of real scenes before and after coding.

    python tools/make_restorer_data.py /work/restorer_data \
        --scene ../shared/data/statues/angel.sog \
        --scene /work/fits/lego200_20k/point_cloud.ply,cameras=/work/fits/lego200_20k/cameras.json,bg=1 \
        --scene ../shared/data/statues/massa.sog,split=val

For every scene and rate point (attribute lambda, base residual distance) the encoder's own stages
run (gspc/encoder/prepare.py): cameras (loaded, or synthesised as the encoder does), shrunk to at most
400 px, the views in their stored form, visibility mask and attribute coding -> G~, clamped renders I
and I~ on the scene's background, R = clamp(I) - clamp(I~), per-view distances from
plan_residual_rates, residuals coded (at the rate point's residual scale) and decoded with
encode_residual/decode_residual.
Each (scene, rate, view) becomes one ``.npz``: ``degraded`` (I~, float16), ``residual`` (R,
float16) and the decoded side information R~ for the planned distance and a grid of further
distances, stored losslessly as the codec's 8-bit symbols ``q_<k>`` with ``gain_<k>``/``offset_<k>``
(R~ = (q - offset) / gain, as decode_residual computes it; gain 0 means no residual was sent).
``manifest.json`` lists every file; scenes listed by earlier runs into the same folder stay listed.
Existing files are kept, so an interrupted run resumes.

Scene spec: ``PATH[,key=value...]`` with keys ``name``, ``cameras`` (a camera file; else views
are synthesised), ``bg`` (background grey level, default 0), ``split`` (train or val),
``views`` (synthesised view count, default 60), ``fraction`` (share of the views used; default 1
for training scenes and the encoder's 0.4 for validation scenes).
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
import typer

from gspc.atomic import atomic_write, atomic_write_bytes
from gspc.codec import residuals
from gspc.encoder.prepare import (
    code_attributes,
    codec_params,
    encoder_cameras,
    removal_params,
    sample_side_views,
)
from gspc.encoder.side import view_residuals
from gspc.errors import GspcError, InputError
from gspc.io import read_scene
from gspc.io.camera_files import load_cameras
from gspc.options import EncodeOptions
from gspc.presets import QUALITY
from gspc.reconstruct import render_images
from gspc.restore.data import FORMAT, MANIFEST

DEFAULT_RATES = "low,high,3:3"
DEFAULT_DISTANCES = "1.5,3,6"


@dataclass(frozen=True)
class SceneSpec:
    name: str
    path: Path
    cameras: Path | None = None
    background: float = 0.0
    split: str = "train"
    views: int = 60
    fraction: float | None = None


@dataclass(frozen=True)
class RatePoint:
    name: str
    lam: float
    distance: float  # base residual distance handed to plan_residual_rates
    scale: int = 1  # residuals coded at 1/scale resolution, as the preset's residual_scale


def _save_npz_atomic(path: Path, arrays: dict[str, np.ndarray]) -> None:
    atomic_write(path, lambda f: np.savez_compressed(f, **arrays))


def parse_scene(spec: str) -> SceneSpec:
    """``PATH[,key=value...]`` -> SceneSpec (see the module docstring for the keys)."""
    path, *pairs = spec.split(",")
    kw: dict = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise InputError(f"scene spec {spec!r}: {pair!r} is not key=value")
        if key == "name":
            kw["name"] = value
        elif key == "cameras":
            kw["cameras"] = Path(value)
        elif key == "bg":
            kw["background"] = float(value)
        elif key == "split":
            if value not in ("train", "val"):
                raise InputError(f"scene spec {spec!r}: split must be train or val")
            kw["split"] = value
        elif key == "views":
            kw["views"] = int(value)
        elif key == "fraction":
            kw["fraction"] = float(value)
        else:
            raise InputError(f"scene spec {spec!r}: unknown key {key!r}")
    p = Path(path)
    if "name" not in kw:
        # point_cloud.ply files are named after their folder (fit outputs).
        kw["name"] = p.parent.name if p.stem == "point_cloud" else p.name.split(".")[0]
    return SceneSpec(path=p, **kw)


def parse_rates(text: str) -> list[RatePoint]:
    """``low,high,3:3,12:8:2`` -> rate points: preset names, or ``lambda:distance[:scale]``."""
    out = []
    for item in text.split(","):
        if item in QUALITY:
            q = QUALITY[item]
            out.append(RatePoint(item, float(q.attributes.lam), float(q.residual_distance), q.residual_scale))
            continue
        parts = item.split(":")
        if len(parts) not in (2, 3):
            raise InputError(f"rate point {item!r} is neither a preset nor lambda:distance[:scale]")
        lam, dist = float(parts[0]), float(parts[1])
        scale = int(parts[2]) if len(parts) == 3 else 1
        name = f"lam{lam:g}_d{dist:g}" + (f"_s{scale}" if scale != 1 else "")
        out.append(RatePoint(name, lam, dist, scale))
    return out


def side_info_symbols(
    r: np.ndarray, distance: float | None, codec: str = "jxl", scale: int = 1
) -> dict[str, np.ndarray]:
    """R~ for one residual at one distance, as the codec's symbols (at 1/scale resolution) plus
    gain/offset/scale (gain 0: not sent)."""
    if distance is None:
        return {"q": np.zeros(r.shape, np.uint8), "gain": np.float32(0.0), "offset": np.float32(0.0)}
    params = residuals.ResidualParams(codec=codec, distance=float(distance), scale=scale)
    payload, record = residuals.encode_residual(r, params)
    # The symbols, before upsampling: the record of the image at its coded size.
    decoded = residuals.decode_residual(payload, replace(record, full_shape=record.shape, scale=1))
    gain, offset = np.float32(record.gain), np.float32(record.offset)
    # decode_residual returns (q - offset) / gain in float32; q comes back exactly by rounding.
    q = np.rint(decoded * gain + offset)
    if record.bits != 8 or q.min() < 0 or q.max() > 255:
        raise GspcError("restorer data expects 8-bit residual symbols")
    out = {"q": q.astype(np.uint8), "gain": gain, "offset": offset, "bytes": np.int64(len(payload))}
    if scale != 1:
        out["scale"] = np.int64(scale)
    return out


def encode_options(
    spec: SceneSpec, rate: RatePoint | None, max_side: int = EncodeOptions.max_side
) -> EncodeOptions:
    """The encoder's options for a scene at a rate point (the low preset's, with the rate's lambda)."""
    fraction = spec.fraction if spec.fraction is not None else (1.0 if spec.split == "train" else 0.4)
    return EncodeOptions(
        quality="low",
        lam=rate.lam if rate is not None else None,
        views_fraction=fraction,
        synth_views=spec.views,
        max_side=max_side,
        background=(spec.background,) * 3,
    )


def scene_cameras(spec: SceneSpec, scene, max_side: int) -> tuple[list, list]:
    """(every camera, the ones rendered), by the encoder's own stages: its visibility mask uses them all,
    and the rendered ones are in their stored form, as the decoder reads them."""
    opts = encode_options(spec, None, max_side)
    cams = encoder_cameras(scene, load_cameras(spec.cameras) if spec.cameras is not None else None, opts)
    return cams, sample_side_views(cams, opts)[1]


def make_scene_rate(
    spec: SceneSpec,
    scene,
    all_cams: list,
    cams: list,
    rate: RatePoint,
    distances: list[float],
    out_dir: Path,
    progress,
) -> list[dict]:
    """Write one scene's files at one rate point; returns their manifest entries."""
    sub = out_dir / spec.name / rate.name
    sub.mkdir(parents=True, exist_ok=True)
    files = [sub / f"{k:04d}_{c.name}.npz" for k, c in enumerate(cams)]
    entries = []
    todo = [i for i, f in enumerate(files) if not f.is_file()]
    if todo:
        # The plan depends on every view's residual, so a partial set is redone as a whole.
        # The encoder's own stages (gspc/encoder/prepare.py, gspc/encoder/side.py), so the restorer learns
        # from what the encoder sends.
        opts = encode_options(spec, rate)
        removal = removal_params(opts)
        attrs = code_attributes(scene, all_cams, codec_params(opts), None, opts.background, None, removal)
        enc = attrs.encoded
        bg = opts.background
        res, degr = [], []
        for i, cam in enumerate(cams):
            original = render_images(scene, [cam], bg)[0]
            coded = render_images(enc.decoded, [cam], bg)[0]
            res += view_residuals([original], [coded])
            degr.append(coded.numpy())
            progress(f"{spec.name}/{rate.name} render", i + 1, len(cams))
        plan = residuals.plan_residual_rates(res, rate.distance)
        for i in todo:
            arrays = {"degraded": degr[i].astype(np.float16), "residual": res[i].astype(np.float16)}
            grid = [plan[i], *distances]
            for k, d in enumerate(grid):
                sym = side_info_symbols(res[i], d, scale=rate.scale)
                arrays[f"q_{k}"], arrays[f"gain_{k}"], arrays[f"offset_{k}"] = (
                    sym["q"],
                    sym["gain"],
                    sym["offset"],
                )
                arrays[f"bytes_{k}"] = sym.get("bytes", np.int64(0))
                if "scale" in sym:
                    arrays[f"scale_{k}"] = sym["scale"]
            arrays["distances"] = np.array([-1.0 if d is None else d for d in grid], np.float32)
            _save_npz_atomic(files[i], arrays)
            progress(f"{spec.name}/{rate.name} code", i + 1, len(cams))
    for i, (f, cam) in enumerate(zip(files, cams)):
        with np.load(f) as data:
            dist = [float(v) for v in data["distances"]]
            sent = [int(data[f"bytes_{k}"]) for k in range(len(dist))]
        entries.append(
            {
                "file": str(f.relative_to(out_dir)),
                "scene": spec.name,
                "split": spec.split,
                "rate": rate.name,
                "lam": rate.lam,
                "base_distance": rate.distance,
                "scale": rate.scale,
                "view": i,
                "camera": cam.name,
                "height": cam.height,
                "width": cam.width,
                "background": spec.background,
                "distances": dist,  # index 0: the encoder's planned distance (-1: view skipped)
                "bytes": sent,
            }
        )
    return entries


def write_manifest(out_dir: Path, entries: list[dict], settings: dict) -> None:
    doc = {"format": FORMAT, "settings": settings, "entries": entries}
    atomic_write_bytes(out_dir / MANIFEST, (json.dumps(doc, indent=1) + "\n").encode())


def make_data(
    out_dir: Path,
    specs: list[SceneSpec],
    rates: list[RatePoint],
    distances: list[float],
    max_side: int = 400,
    progress=None,
) -> dict:
    """Generate (or complete) the data set in ``out_dir``; returns the manifest document."""
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        raise InputError(f"scene names must be unique, got {names}")
    out_dir.mkdir(parents=True, exist_ok=True)
    progress = progress or (lambda stage, done, total: None)
    settings = {
        "scenes": [
            {"name": s.name, "path": str(s.path), "split": s.split, "background": s.background} for s in specs
        ],
        "rates": [r.__dict__ for r in rates],
        "distances": distances,
        "max_side": max_side,
    }
    # Scenes made by earlier runs into the same folder stay listed, so data can grow scene by scene.
    entries: list[dict] = []
    old = out_dir / MANIFEST
    if old.is_file():
        prev = json.loads(old.read_text())
        kept = [s for s in prev["settings"]["scenes"] if s["name"] not in names]
        settings["scenes"] = kept + settings["scenes"]
        entries = [e for e in prev["entries"] if e["scene"] not in names]
    for spec in specs:
        if not spec.path.is_file():
            raise InputError(f"scene {spec.path} does not exist")
        scene = read_scene(spec.path)
        all_cams, cams = scene_cameras(spec, scene, max_side)
        for rate in rates:
            entries += make_scene_rate(spec, scene, all_cams, cams, rate, distances, out_dir, progress)
            write_manifest(out_dir, entries, settings)
    write_manifest(out_dir, entries, settings)
    return {"format": FORMAT, "settings": settings, "entries": entries}


def main(
    out_dir: Path = typer.Argument(..., help="output folder (created; existing files are kept)"),
    scene: list[str] = typer.Option(
        ..., "--scene", help="PATH[,name=..,cameras=..,bg=..,split=val,views=..]"
    ),
    rates: str = typer.Option(DEFAULT_RATES, help="rate points: preset names or lambda:distance[:scale]"),
    distances: str = typer.Option(DEFAULT_DISTANCES, help="extra JPEG XL distances stored per view"),
    max_side: int = typer.Option(EncodeOptions.max_side, help="views are shrunk to at most this many px"),
    quiet: bool = typer.Option(False, help="no progress bar"),
) -> None:
    torch.set_num_threads(1)
    try:
        specs = [parse_scene(s) for s in scene]
        rate_points = parse_rates(rates)
        grid = [float(d) for d in distances.split(",") if d]
    except (ValueError, GspcError) as e:
        raise typer.BadParameter(str(e)) from None
    t0 = time.perf_counter()
    try:
        if quiet:
            doc = make_data(out_dir, specs, rate_points, grid, max_side)
        else:
            from rich.progress import Progress

            with Progress() as bar:
                task = bar.add_task("start", total=1)

                def report(stage: str, done: int, total: int) -> None:
                    bar.update(task, description=stage, completed=done, total=total)

                doc = make_data(out_dir, specs, rate_points, grid, max_side, report)
    except GspcError as e:
        print(f"error: {e}", file=sys.stderr)
        raise typer.Exit(1) from None
    size = sum(f.stat().st_size for f in out_dir.rglob("*.npz"))
    n_val = sum(e["split"] == "val" for e in doc["entries"])
    print(
        f"{len(doc['entries'])} views ({n_val} validation), {size / 1e6:.1f} MB in {out_dir}, "
        f"{time.perf_counter() - t0:.0f} s"
    )


if __name__ == "__main__":
    typer.run(main)
