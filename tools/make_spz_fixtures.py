"""Write the SPZ fixtures in tests/data/spz/ with real SPZ writers (not gspc's own code).

Two small source scenes, written with gspc.io.write_ply:
  donut256.ply   every 178th Gaussian of ../shared/data/donut/fused.ply (a trained scene, SH degree 0)
  synth_sh3.ply  128 seeded random Gaussians at SH degree 3, with a few opacity logits at +-30 and +-8

Each becomes SPZ versions 2, 3 and 4, and each SPZ goes back to PLY through splat-transform's own reader
(``*.st.ply``), which tests/test_spz.py compares with gspc's. The SH-3 scene is also written by gsply, a
Python writer that keeps all 8 bits of SH (the others keep 5 bits of band 1 and 4 of the rest). The writers,
installed into folders outside the repository (Node 20 or later; splat-transform asks for Node 22 but runs on
20; gsply into a --target folder so the system Python is left alone):

  npm install --prefix NPM_DIR @playcanvas/splat-transform@3.7.0 spz-js@1.2.5
  npx --prefix NPM_DIR splat-transform -w -g cpu SRC.ply NAME.v4.spz              # v4: Niantic's C++, WASM
  npx --prefix NPM_DIR splat-transform -w -g cpu --spz-version 3 SRC.ply NAME.v3.spz
  node tools/spz_js_write.mjs NPM_DIR SRC.ply NAME.v2.spz                         # v2: spz-js
  npx --prefix NPM_DIR splat-transform -w -g cpu NAME.vK.spz NAME.vK.st.ply       # their decoding
  pip install --target PY_DIR 'gsply[spz]==0.4.6'
  PYTHONPATH=PY_DIR python -c 'gsply.spz.write_spz(OUT, gsply.plyread(SRC), version=K)'  # K = 3, 4

Run from the repository root (about twenty seconds; with the writers' versions above a rerun rewrites the
same bytes, except the time stamp in the gzip header of gsply's version-3 file):

  python tools/make_spz_fixtures.py [--npm-dir /tmp/gspc-spz-npm] [--py-dir /tmp/gspc-spz-py]
                                    [--out tests/data/spz]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from gspc.io import read_ply, write_ply
from gspc.scene import make_scene

ROOT = Path(__file__).resolve().parents[1]

NPM_PACKAGES = ("@playcanvas/splat-transform@3.7.0", "spz-js@1.2.5")
PY_PACKAGE = "gsply[spz]==0.4.6"
GSPLY_WRITE = (
    "import sys, gsply, gsply.spz; "
    "gsply.spz.write_spz(sys.argv[2], gsply.plyread(sys.argv[1]), version=int(sys.argv[3]))"
)
DONUT = ROOT.parent / "shared" / "data" / "donut" / "fused.ply"
DONUT_COUNT = 256
SYNTH_COUNT = 128


def donut_subset(out: Path) -> None:
    scene = read_ply(DONUT)
    step = scene.num_gaussians // DONUT_COUNT
    write_ply(scene.subset(np.arange(0, step * DONUT_COUNT, step)), out)


def synthetic_sh3(out: Path) -> None:
    """Values inside what SPZ represents (log scales in [-10, 6), SH rest in [-1, 1]) plus extreme alphas."""
    rng = np.random.default_rng(15)
    n = SYNTH_COUNT
    opacity = rng.uniform(-5.0, 5.0, n)
    opacity[:4] = [-30.0, 30.0, -8.0, 8.0]
    falloff = np.linspace(1.0, 0.3, 15)[None, :, None]  # higher bands weaker, as in trained scenes
    scene = make_scene(
        means=rng.uniform(-3.0, 3.0, (n, 3)),
        quats=rng.normal(size=(n, 4)),
        log_scales=rng.uniform(-8.0, 1.0, (n, 3)),
        opacities=opacity,
        sh_dc=rng.uniform(-2.5, 2.5, (n, 3)),
        sh_rest=rng.uniform(-0.9, 0.9, (n, 15, 3)) * falloff,
        sh_degree=3,
    )
    write_ply(scene, out)


def run(*cmd: str | Path) -> None:
    subprocess.run([str(c) for c in cmd], check=True, stdout=subprocess.DEVNULL)


def ensure_npm(npm_dir: Path) -> None:
    if not (npm_dir / "node_modules" / "spz-js").is_dir():
        npm_dir.mkdir(parents=True, exist_ok=True)
        run("npm", "install", "--prefix", npm_dir, "--no-audit", "--no-fund", *NPM_PACKAGES)


def ensure_gsply(py_dir: Path) -> None:
    if not (py_dir / "gsply").is_dir():
        run(sys.executable, "-m", "pip", "install", "-q", "--target", py_dir, PY_PACKAGE)


def write_gsply(py_dir: Path, source: Path, name: str, out: Path) -> list[Path]:
    env = {**os.environ, "PYTHONPATH": str(py_dir)}
    files = [out / f"{name}.gsply.v{version}.spz" for version in (3, 4)]
    for version, path in zip((3, 4), files):
        cmd = [sys.executable, "-c", GSPLY_WRITE, str(source), str(path), str(version)]
        subprocess.run(cmd, check=True, env=env)
    return files


def write_spz(npm_dir: Path, source: Path, name: str, out: Path) -> list[Path]:
    splat_transform = ("npx", "--prefix", npm_dir, "splat-transform", "-w", "-q", "-g", "cpu")
    files = {version: out / f"{name}.v{version}.spz" for version in (2, 3, 4)}
    run(*splat_transform, source, files[4])
    run(*splat_transform, "--spz-version", "3", source, files[3])
    run("node", ROOT / "tools" / "spz_js_write.mjs", npm_dir, source, files[2])
    for spz in files.values():
        run(*splat_transform, spz, spz.with_suffix(".st.ply"))
    return [*files.values(), *(f.with_suffix(".st.ply") for f in files.values())]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--npm-dir", type=Path, default=Path("/tmp/gspc-spz-npm"))
    ap.add_argument("--py-dir", type=Path, default=Path("/tmp/gspc-spz-py"))
    ap.add_argument("--out", type=Path, default=ROOT / "tests" / "data" / "spz")
    args = ap.parse_args()
    if not DONUT.is_file():
        sys.exit(f"{DONUT} is missing (see ../shared/data/README.md)")
    ensure_npm(args.npm_dir.resolve())
    ensure_gsply(args.py_dir.resolve())
    args.out.mkdir(parents=True, exist_ok=True)
    sources = {"donut256": donut_subset, "synth_sh3": synthetic_sh3}
    for name, make in sources.items():
        source = args.out / f"{name}.ply"
        make(source)
        written = write_spz(args.npm_dir.resolve(), source, name, args.out)
        if name == "synth_sh3":
            written += write_gsply(args.py_dir.resolve(), source, name, args.out)
        for path in [source, *written]:
            print(f"{path}: {path.stat().st_size:,} bytes")


if __name__ == "__main__":
    main()
