"""What the bench_* tools share: the benchmark scenes and their cameras (a fit's folder, or a scene with
synthesised views; :func:`bench_scene` by name, every eighth camera held out), scoring a decoded scene at
held-out views, one encode-decode point, the peers' writer
(PlayCanvas splat-transform) and bytes at equal PSNR on a rate curve.

The tools run as scripts (``python tools/bench_x.py``), so this module is importable beside them.
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import imagecodecs
import numpy as np
import torch
from scenes import glossy_scene

from gspc.cameras import Camera
from gspc.encoder.prepare import encoder_cameras
from gspc.encoder.significance import evenly_spaced
from gspc.format import container
from gspc.format.chunks import RESI, SIDE
from gspc.format.header import FileHeader
from gspc.format.side_chunk import read_side_views
from gspc.io import read_scene
from gspc.io.camera_files import load_cameras
from gspc.io.cameras_json import save_cameras_json
from gspc.metrics import mean_psnr, mse, quantize8, ssim
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode
from gspc.reconstruct import render_images
from gspc.scene import GaussianScene
from gspc.views import limit_size, sample_views, split_test_views, synthesize_views

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
# splat-transform's install (``npm install --prefix NPM_DIR @playcanvas/splat-transform@3.7.0``) and where the
# scenes it writes for the benches are kept between runs.
NPM_DIR = Path("/tmp/gspc-spz-npm")
MADE = Path("/tmp/gspc-bench-scenes")


@dataclass
class Setup:
    name: str
    scene_path: Path
    train_cams: list[Camera]  # the encoder samples its side-information views from these
    eval_cams: list[Camera]  # never carry side information
    background: tuple[float, float, float]
    photos: list[torch.Tensor] | None = None  # held-out photos at eval_cams (lego)


def fit_setup(folder: Path) -> Setup:
    """A tools/fit_scene.py output: its held-out photos are the ground truth, its background the fit's."""
    fit = json.loads((folder / "fit.json").read_text())
    background = float(fit.get("background", 1.0))
    kind = "capture" if fit.get("source") == "colmap" else "lego"
    cams = load_cameras(folder / "cameras.json")
    train, test = split_test_views(cams, every=8)
    photos = []
    for i in test:
        img = imagecodecs.png_decode((folder / "test" / f"{cams[i].name}.png").read_bytes())
        photos.append(torch.from_numpy(img[..., :3].astype(np.float32) / 255))
    return Setup(
        f"{kind} ({folder.name})",
        folder / "point_cloud.ply",
        [cams[i] for i in train],
        [cams[i] for i in test],
        (background,) * 3,
        photos,
    )


UNSEEN_EXTRA = 7  # a sphere of 67 points shares none with the encoder's 60


def held_out_line(scene, eval_cams: list[Camera]) -> str:
    """The opening of a fit benchmark's description: the scene, its held-out views and the machine."""
    return (
        f"{scene.num_gaussians:,} Gaussians, SH degree {scene.sh_degree}; {len(eval_cams)} held-out views "
        f"({eval_cams[0].width}x{eval_cams[0].height}). Machine: {platform.machine()}, {os.cpu_count()} "
        "vCPUs, one torch thread"
    )


def synth_setup(
    name: str, path: Path, views: int = 60, size: int = 320, n_eval: int = 12, unseen: bool = False
) -> Setup:
    """``views`` synthesised cameras for the encoder; scored at ``n_eval`` of them its side information does
    not cover, or (``unseen``) at :func:`unseen_views`."""
    scene = read_scene(path)
    cams = synthesize_views(scene, views, width=size, height=size)
    return _synthesised(name, path, scene, cams, n_eval, unseen)


def default_encode_setup(name: str, path: Path, n_eval: int = 12, unseen: bool = False) -> Setup:
    """The cameras ``gspc encode`` synthesises for a scene given without cameras (default options), and
    ``n_eval`` of those its side information does not cover, or (``unseen``) :func:`unseen_views`."""
    scene = read_scene(path)
    return _synthesised(name, path, scene, encoder_cameras(scene, None, EncodeOptions()), n_eval, unseen)


def _synthesised(name: str, path: Path, scene, cams: list[Camera], n_eval: int, unseen: bool) -> Setup:
    """A setup of synthesised encoder cameras on a black background, scored at ``n_eval`` of them without
    side information or (``unseen``) between them."""
    scoring = unseen_views(scene, cams, n_eval) if unseen else held_out_views(cams, n_eval)
    return Setup(name, path, cams, scoring, (0.0, 0.0, 0.0))


def unseen_views(scene, cams: list[Camera], n_eval: int) -> list[Camera]:
    """``n_eval`` evenly spaced views of a Fibonacci sphere of UNSEEN_EXTRA more views than ``cams``
    (synthesised ones, whose size and field of view they keep): views between the encoder's, none of them one
    it measures (the encoder measures every camera at 1x: a scoring view among them flatters its choice)."""
    c = cams[0]
    fov = float(np.degrees(2 * np.arctan(0.5 * c.width / c.fx)))
    other = synthesize_views(scene, len(cams) + UNSEEN_EXTRA, width=c.width, height=c.height, fov_deg=fov)
    return evenly_spaced(other, n_eval)


def held_out_views(cams: list[Camera], n_eval: int) -> list[Camera]:
    """``n_eval`` evenly spaced views the encoder will not sample: the complement of sample_views(0.4)."""
    side = set(sample_views(cams, 0.4))
    rest = [i for i in range(len(cams)) if i not in side]
    return [cams[rest[int(j)]] for j in np.linspace(0, len(rest) - 1, n_eval).round()]


def bytes_at(curve: list[tuple[int, float]], target: float) -> float | None:
    """Bytes of the codec curve (bytes, PSNR) at ``target`` PSNR, log-linear between neighbours."""
    pts = sorted(curve, key=lambda t: t[1])
    for (b0, p0), (b1, p1) in zip(pts, pts[1:]):
        if p0 <= target <= p1 and p1 > p0:
            w = (target - p0) / (p1 - p0)
            return float(np.exp((1 - w) * np.log(b0) + w * np.log(b1)))
    return None


def splat_transform(
    npm_dir: Path, src: Path, dst: Path, *args: str
) -> tuple[subprocess.CompletedProcess, float]:
    """PlayCanvas splat-transform (``npm install --prefix NPM_DIR @playcanvas/splat-transform@3.7.0``) writing
    ``dst`` (its format from the suffix: .spz is SPZ v4 through Niantic's C++ in WASM) from ``src``, with
    ``args`` before the paths: (the finished process, wall seconds)."""
    tool = npm_dir / "node_modules" / ".bin" / "splat-transform"
    t0 = time.perf_counter()
    res = subprocess.run([str(tool), "-w", *args, str(src), str(dst)], capture_output=True, text=True)
    return res, time.perf_counter() - t0


def made_sog(src: Path, dst: Path) -> Path:
    """``dst``: ``src`` written as SOG v2 by splat-transform (k-means on the CPU, 2 iterations: its default
    did not finish on the bird in 2 h, bench/peers.md), once."""
    if not dst.exists():
        dst.parent.mkdir(parents=True, exist_ok=True)
        res, _ = splat_transform(NPM_DIR, src, dst, "-g", "cpu", "-i", "2")
        if res.returncode != 0:
            raise RuntimeError(f"splat-transform failed on {src}: {res.stderr.strip()[-200:]}")
    return dst


def splat_transform_version(npm_dir: Path) -> str:
    """The installed splat-transform's version, from its package.json."""
    doc = npm_dir / "node_modules" / "@playcanvas" / "splat-transform" / "package.json"
    return str(json.loads(doc.read_text())["version"])


def score(scene_path: Path, s: Setup, reference: list[torch.Tensor]) -> dict[str, float]:
    imgs = render_images(read_scene(scene_path), s.eval_cams, s.background)
    out = {
        "psnr": mean_psnr(imgs, reference),
        "ssim": float(np.mean([ssim(quantize8(a), quantize8(b)) for a, b in zip(imgs, reference)])),
    }
    if s.photos is not None:
        out["psnr_photo"] = mean_psnr(imgs, s.photos)
        out["ssim_photo"] = float(np.mean([ssim(quantize8(a), quantize8(b)) for a, b in zip(imgs, s.photos)]))
    return out


def run_point(
    s: Setup,
    tmp: Path,
    ref,
    quality="low",
    lam=None,
    side_info=True,
    iterations=None,
    restorer="none",
    restore=True,
    refine=True,
    check=True,
    cells=True,
    residual_scale=None,
    target_size=None,
    precision=True,
    tag="",
) -> dict:
    cams_file = tmp / f"{s.name.split()[0]}_train_cameras.json"
    if not cams_file.exists():
        save_cameras_json(s.train_cams, cams_file)
    knobs = f"{quality}_{lam}_{side_info}_{check}_{residual_scale}_{target_size}_{precision}"
    gfile = tmp / f"{s.name.split()[0]}_{knobs}.gspc"
    max_side = max(max(c.width, c.height) for c in s.train_cams)
    t0 = time.perf_counter()
    if not gfile.exists():
        encode(
            s.scene_path,
            gfile,
            cams_file,
            EncodeOptions(
                quality=quality,
                lam=lam,
                side_info=side_info,
                max_side=max_side,
                background=s.background,
                check_iterations=None if check else 0,
                residual_scale=residual_scale,
                target_size=target_size,
                precision=precision,
            ),
        )
    enc_s = time.perf_counter() - t0
    out_ply = tmp / f"out_{tag}.ply"
    t0 = time.perf_counter()
    rep = decode(
        gfile,
        out_ply,
        DecodeOptions(
            iterations=iterations, restorer=restorer, restore=restore, refine=refine, in_cells=cells
        ),
    )
    dec_s = time.perf_counter() - t0
    res = score(out_ply, s, ref)
    res.update(
        bytes=gfile.stat().st_size,
        n=rep.num_gaussians_out,
        encode_s=enc_s,
        decode_s=dec_s,
        side=sum(v for k, v in rep.bytes.items() if k in (RESI, SIDE)),
        refine=rep.info.get("refine", "none"),
        scale=_residual_scale(gfile),
    )
    return res


def _residual_scale(path: Path) -> int | None:
    """The resolution divisor of the file's residuals (None: no side information)."""
    c = container.read(path)
    legacy = FileHeader.from_dict(c.header).side_info.legacy_views
    side = read_side_views(legacy, c.chunks, path.stat().st_size)
    scales = {v.residual.scale for v in side.views if v.residual is not None}
    return scales.pop() if len(scales) == 1 else None


def bench_scene(name: str) -> tuple[GaussianScene, list[Camera], tuple[float, float, float]]:
    """(scene, cameras, background) of ``name``: "lego", "lego-sog" (lego through SOG v2, its SH rest from a
    palette, as SOG files hold it), "glossy", "glossy-faint" (its Gaussians mostly faint), "donut" or a
    statue of ../shared/data/statues."""
    if name in ("lego", "lego-sog"):
        d = Path(__file__).resolve().parents[1] / "examples" / "lego"
        cams = limit_size(load_cameras(d / "cameras.json"), 400)
        path = d / "point_cloud.ply" if name == "lego" else made_sog(d / "point_cloud.ply", MADE / "lego.sog")
        return read_scene(path), cams, (1, 1, 1)
    if name == "glossy":
        s = glossy_scene()
    elif name == "glossy-faint":
        s = glossy_scene(opacity=-1.0)
    elif name == "donut":
        s = read_scene(SHARED / "donut" / "fused.ply")
    else:
        s = read_scene(SHARED / "statues" / f"{name}.sog")
    return s, synthesize_views(s, 64, 320, 320), (0, 0, 0)


def held_out(cams: Sequence[Camera]) -> tuple[list[Camera], list[Camera]]:
    """(the encoder's cameras, the held-out ones): every eighth in the cameras' order (not by name, as
    split_test_views does) is held out."""
    return [c for i, c in enumerate(cams) if i % 8], list(cams[::8])


def float_psnr(images: Sequence[torch.Tensor], refs: Sequence[torch.Tensor]) -> float:
    """Mean PSNR in float (no 8-bit rounding: at high fidelity it hides most of the error)."""
    return float(np.mean([-10 * math.log10(max(float(mse(a, b)), 1e-12)) for a, b in zip(images, refs)]))
