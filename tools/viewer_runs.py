"""Running the web viewer (web/viewer) in headless Chromium against gspc's own renders: `gspc view` as a
process, the node drivers of web/ (web/test/viewerCheck.mjs, web/tools/compare-renderers.mjs), the OpenCV
cameras they take, and a capture's PSNR against gspc's render of the same decoded Gaussians. Shared by
tests/test_browser.py and tools/bench_web_viewer.py."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.metrics import psnr, quantize8
from gspc.render import render

REPO = Path(__file__).resolve().parent.parent
WEB = REPO / "web"
NODE = shutil.which("node")
CHROMIUM = os.environ.get("GSPC_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")


def gspc_command(*args: str) -> list[str]:
    """The command line of `gspc ARGS` from this checkout."""
    return [sys.executable, "-c", "import sys; from gspc.cli import app; sys.argv[0] = 'gspc'; app()", *args]


class ViewServer:
    """`gspc view FILE` running; ``url`` is the viewer's address, read from its first line."""

    def __init__(self, path: Path) -> None:
        command = gspc_command("view", str(path))
        self.proc = subprocess.Popen(command, stdout=subprocess.PIPE, text=True, cwd=REPO)
        line = self.proc.stdout.readline()
        if " at http://127.0.0.1:" not in line:
            self.close()
            raise RuntimeError(f"gspc view printed {line!r}")
        self.url = line.split(" at ", 1)[1].split(" ", 1)[0]

    def close(self) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=30)

    def __enter__(self) -> ViewServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def run_node(script: Path, job: dict, folder: Path) -> list[dict]:
    """Run a node driver of web/ on ``job`` (written as JSON to ``folder``); its result, one JSON line."""
    spec = folder / f"{script.stem}.json"
    spec.write_text(json.dumps({"chromium": CHROMIUM, **job}))
    res = subprocess.run([NODE, str(script), str(spec)], capture_output=True, text=True, timeout=3600)
    if res.returncode != 0:
        raise RuntimeError(f"{script.name} failed: {res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def drive_viewer(jobs: list[dict], folder: Path) -> list[dict]:
    """web/test/viewerCheck.mjs on ``jobs`` (see its header)."""
    return run_node(WEB / "test" / "viewerCheck.mjs", {"jobs": jobs}, folder)


def camera_job(camera: Camera, png: Path | None = None) -> dict:
    """A camera as the drivers take it: OpenCV world-to-camera (row-major), pinhole, size, capture path."""
    job = {
        "w2c": camera.world_to_cam.reshape(-1).tolist(),
        "fx": camera.fx, "fy": camera.fy, "cx": float(camera.K[0, 2]), "cy": float(camera.K[1, 2]),
        "width": camera.width, "height": camera.height,
    }  # fmt: skip
    if png is not None:
        job["png"] = str(png)
    return job


def capture_psnr(png: Path, scene, camera: Camera, background) -> float:
    """PSNR (dB, 8-bit) of a PNG capture against gspc's render of ``scene`` from ``camera``."""
    import imagecodecs

    shot = imagecodecs.png_decode(Path(png).read_bytes())[..., :3].astype(np.float32) / 255.0
    ref = quantize8(render(scene, camera, background=background).image.detach().cpu().float())
    return float(psnr(torch.from_numpy(shot), ref))
