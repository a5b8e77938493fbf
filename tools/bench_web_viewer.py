"""The web viewer against gspc's own render, and the splat renderers it was chosen from (bench/web.md).

    npm install --prefix /tmp/renderers playcanvas@2.23.3    # the other renderer compared (not a dependency)
    python tools/bench_viewer.py --npm /tmp/renderers --cameras examples/lego/cameras.json \\
        --views 0,12,25,37 --background 1 1 1 lego_tiled.gspc lego.gspc

Per file: gspc's decode (no restoration or refinement) to a PLY; the viewer (``gspc view``, web/viewer, its
default one stream) in headless Chromium with a software WebGL (SwiftShader): seconds from the viewer's
script starting to the first tile drawn and to the last (and from opening the page to the last), and the
PSNR of its captures against gspc's render of the same decoded Gaussians from the same cameras; then each
renderer configuration of web/tools/compare-renderers.mjs on that PLY: ms to load it, ms per frame while
the camera turns, PSNR. Spark and three come from web/'s own node_modules, PlayCanvas from ``--npm``;
without it only Spark is measured.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import tempfile
import time
from pathlib import Path

from viewer_runs import CHROMIUM, WEB, ViewServer, camera_job, capture_psnr, drive_viewer, run_node

from gspc.io import read_scene
from gspc.io.camera_files import load_cameras
from gspc.options import DecodeOptions
from gspc.pipeline import decode

# The viewer's Spark settings (web/viewer/splats.mjs, RULES), Spark's defaults, and PlayCanvas's defaults and
# its most faithful settings (32-bit work buffer, no culling of small or faint splats, colours updated
# every frame).
SPARK_RULES = {
    "preBlurAmount": 0.3,
    "blurAmount": 0,
    "minAlpha": 1 / 255,
    "sortRadial": False,
    "maxStdDev": math.sqrt(2 * math.log(255)),
}
PLAYCANVAS_FAITHFUL = {"dataFormat": "large", "minPixelSize": 0, "minContribution": 0, "colorUpdateAngle": 0}


def configs(npm: Path | None) -> list[dict]:
    spark = {"page": "spark", "npm": str(WEB)}
    out = [
        {**spark, "name": "Spark 2.2.0, gspc's rules (the viewer)", "options": SPARK_RULES},
        {**spark, "name": "Spark 2.2.0, its defaults", "options": {}},
    ]
    if npm is not None:
        out += [
            {"name": "PlayCanvas 2.23.3, its defaults", "page": "playcanvas", "npm": str(npm), "options": {}},
            {
                "name": "PlayCanvas 2.23.3, large work buffer, no culling",
                "page": "playcanvas",
                "npm": str(npm),
                "options": PLAYCANVAS_FAITHFUL,
            },
        ]
    return out


def psnrs(pngs, scene, cams, background) -> str:
    values = [capture_psnr(Path(p), scene, c, background) for p, c in zip(pngs, cams)]
    return f"{sum(values) / len(values):.2f} ({min(values):.2f})"


def bench_file(path: Path, cams, background, npm: Path | None, folder: Path) -> list[str]:
    ply = folder / f"{path.stem}.ply"
    decode(path, ply, DecodeOptions(refine=False, restore=False))
    scene = read_scene(ply)
    rows = []
    jobs = [camera_job(c, folder / f"{path.stem}_viewer_{k}.png") for k, c in enumerate(cams)]
    with ViewServer(path) as viewer:
        [result] = drive_viewer([{"url": viewer.url, "cameras": jobs}], folder)
    if not result.get("shown"):
        raise RuntimeError(f"the viewer did not show {path}: {result}")
    s = result["shown"]
    shown = (
        f"first of {s['tiles']} tiles drawn at {s['firstSeconds']:.1f} s, the last at {s['seconds']:.1f} s "
        f"({result['seconds']:.1f} s from opening the page)"
    )
    db = psnrs([j["png"] for j in jobs], scene, cams, background)
    rows.append(f"| {path.name} | the viewer (gspc view, web/viewer) | {shown} | | {db} |")
    plain = [camera_job(c) for c in cams]
    configured = [{**c, "out": str(folder / f"{path.stem}_{k}")} for k, c in enumerate(configs(npm))]
    job = {"ply": str(ply), "background": list(background), "cameras": plain, "configs": configured}
    for r in run_node(WEB / "tools" / "compare-renderers.mjs", job, folder):
        db = psnrs(r["captured"], scene, cams, background)
        rows.append(f"| {path.name} | {r['name']} | {r['loadMs']:.0f} ms | {r['frameMs']:.0f} | {db} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", type=Path)
    ap.add_argument("--cameras", type=Path, required=True, help="the scenes' camera file")
    ap.add_argument("--views", default="0,12,25,37", help="indices of the cameras to capture from")
    ap.add_argument("--background", nargs=3, type=float, default=(0.0, 0.0, 0.0))
    ap.add_argument("--npm", type=Path, default=None, help="a folder where playcanvas@2.23.3 is installed")
    args = ap.parse_args()
    if CHROMIUM is None:
        raise SystemExit("no Chromium: apt-get install chromium, or set GSPC_CHROMIUM")
    every = load_cameras(args.cameras)
    cams = [every[int(i)] for i in args.views.split(",")]
    load = os.getloadavg()
    print(f"{platform.machine()}, {os.cpu_count()} CPUs, load average {load[0]:.1f} at the start")
    size = f"{cams[0].width}x{cams[0].height}"
    print(f"{len(cams)} views of {args.cameras} at {size}, background {tuple(args.background)}")
    print("| file | renderer | load | ms per frame | PSNR vs gspc's render, mean (lowest) dB |")
    print("|---|---|---:|---:|---|")
    start = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        for path in args.files:
            for row in bench_file(path, cams, tuple(args.background), args.npm, Path(tmp)):
                print(row, flush=True)
    print(f"({time.time() - start:.0f} s; load average {os.getloadavg()[0]:.1f} at the end)")


if __name__ == "__main__":
    main()
