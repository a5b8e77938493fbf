"""gsplat's CUDA rasteriser behind gspc's render() convention (imported lazily: CUDA machines only).

Same conventions as the torch backend (OpenCV camera, the low-pass and near plane of rules.py, SH from the
camera centre, pixel centres at +0.5, classic 3DGS compositing). gsplat's kernels are float32: other dtypes
are cast there and back (gradients flow through the casts).

Where gsplat 1.5.x departs from the file's renderer rules (spec 10.12, rules.py), and what it costs:
- it caps alpha at 0.999, not 0.99. Only pixels where a Gaussian reaches the cap differ, by at most
  ``cap_miss_bound(0.999)`` = 0.1 of the colour range: the larger cap also stops a pixel earlier (a pixel
  stops before the Gaussian that would take its transmittance below 1e-4), so a capped Gaussian behind
  others that left a transmittance of up to 0.1 is drawn by one renderer and not by the other;
- it skips a Gaussian at a pixel where its q = d^T conic d rounds below zero (only within round-off of the
  centre of a Gaussian whose 2D covariance is extremely elongated);
- it stops at transmittance <= 1e-4 rather than < 1e-4 (a tie: nothing measurable).
1.4.x culls tiles at 3 sigma, not at the 1/255 contour; versions outside SUPPORTED are not used.

gsplat imports without its CUDA code: it loads a prebuilt extension, or compiles one with nvcc at its first
kernel call (minutes), or, with neither, sets its extension to None and fails at that call. So whether it
works is learned by running it: ``gsplat_status`` renders one Gaussian, once per process and device, and
reports why gsplat cannot be used (api.py then renders with the torch renderer on the same device).
"""

from __future__ import annotations

import importlib.util
import re
import time
from dataclasses import dataclass

import numpy as np
import torch

from gspc.cameras import Camera
from gspc.errors import DeviceError
from gspc.progress import Progress
from gspc.render.result import RenderResult
from gspc.render.rules import ALPHA_MAX, LOWPASS, NEAR, T_MIN
from gspc.scene import GaussianScene

# gsplat versions gspc renders with: [first, end) as (major, minor); pyproject.toml's [cuda] extra says the
# same. 1.4 culls tiles at 3 sigma; 1.6 needs torch >= 2.7 and no GPU run has checked it yet.
SUPPORTED = ((1, 5), (1, 6))
INSTALL = "pip install 'gspc[cuda]' (gsplat>=1.5,<1.6)"
KERNELS_HINT = "gsplat needs its kernels prebuilt for this GPU, or the CUDA toolkit (nvcc) to build them"
COMPILE_STAGE = "gsplat kernels (a first run compiles them with nvcc: minutes)"


def cap_miss_bound(cap: float) -> float:
    """How far (a fraction of the range of the colours and background) a pixel of a renderer that caps alpha
    at ``cap`` may differ from the rules' render (cap ALPHA_MAX), everything else equal.

    The renders agree up to the first Gaussian g, in depth order, whose alpha reaches a cap; let T be the
    transmittance in front of it. If both draw g, what lies behind it has weight T (1 - alpha) <= 1 - the
    smaller cap in each. If one stops before g (T (1 - cap) < T_MIN) and the other draws it, they differ by
    at most T < T_MIN / (1 - the larger cap). If both stop they agree.
    """
    lo, hi = min(cap, ALPHA_MAX), max(cap, ALPHA_MAX)
    if lo == hi:
        return 0.0
    return max(1.0 - lo, T_MIN / (1.0 - hi))


@dataclass(frozen=True)
class GsplatStatus:
    """What the probe learned about gsplat on one device."""

    usable: bool
    reason: str  # why gsplat is not used ("" when usable)
    version: str | None = None
    alpha_cap: float | None = None  # measured: one opaque Gaussian's alpha at its centre
    jit_seconds: float | None = None  # the probe's time when gsplat had no prebuilt kernels (built or cached)

    def describe(self) -> str:
        """gsplat's version, its alpha cap against the rules' and, after a JIT build, its time."""
        text = f"gsplat {self.version}"
        if self.alpha_cap is not None and self.alpha_cap != ALPHA_MAX:
            text += (
                f" (alpha cap {self.alpha_cap:g}, the file's rules {ALPHA_MAX:g}: pixels at capped Gaussians "
                f"may differ by up to {cap_miss_bound(self.alpha_cap):.2g} of the colour range, spec 10.12)"
            )
        if self.jit_seconds is not None:
            text += f" (no prebuilt kernels: its first call built or loaded them in {self.jit_seconds:.0f} s)"
        return text


# Once per process and device: a failing gsplat is not retried at every render, and a JIT build happens
# once. Keyed by str(device); tests replace the dict.
_STATUS: dict[str, GsplatStatus] = {}


def gsplat_status(device: torch.device, progress: Progress | None = None) -> GsplatStatus:
    """Whether gsplat renders on ``device`` (probed by a real render on the first call, then cached).

    ``progress`` (the pipeline's) hears of the probe as a stage when gsplat has no prebuilt kernels, since
    its first call may then compile them for minutes."""
    if device.type == "cuda" and device.index is None:  # "cuda" and "cuda:0" are one device, probed once
        device = torch.device("cuda", torch.cuda.current_device())
    key = str(device)
    if key not in _STATUS:
        _STATUS[key] = _probe(device, progress)
    return _STATUS[key]


def _probe(device: torch.device, progress: Progress | None) -> GsplatStatus:
    try:
        import gsplat
    except ImportError:
        return GsplatStatus(False, f"gsplat is not installed: {INSTALL}")
    except Exception as e:  # gsplat's own import-time failures (e.g. `packaging` missing in 1.5.x)
        return GsplatStatus(False, f"gsplat does not import ({_one_line(e)}): {INSTALL}")
    version = str(getattr(gsplat, "__version__", "unknown"))
    if not _supported(version):
        return GsplatStatus(False, f"gsplat {version} is not a version gspc renders with: {INSTALL}", version)
    jit = not _has_prebuilt_kernels()
    if jit and progress:
        progress(COMPILE_STAGE, 0, 1)
    t0 = time.perf_counter()
    try:
        alpha = _centre_alpha(gsplat, device)
    except Exception as e:  # no kernels (extension None), a build failure, a driver too old, ...
        why = f"gsplat {version}'s CUDA kernels do not run here ({_one_line(e)}); {KERNELS_HINT}"
        return GsplatStatus(False, why, version)
    finally:
        if jit and progress:
            progress(COMPILE_STAGE, 1, 1)
    seconds = time.perf_counter() - t0
    if not 0.5 < alpha <= 1.0:  # NaN included
        return GsplatStatus(False, f"gsplat {version} draws a test Gaussian wrongly (alpha {alpha})", version)
    return GsplatStatus(True, "", version, round(alpha, 4), seconds if jit else None)


def _supported(version: str) -> bool:
    m = re.match(r"(\d+)\.(\d+)", version)
    return m is not None and SUPPORTED[0] <= (int(m[1]), int(m[2])) < SUPPORTED[1]


def _has_prebuilt_kernels() -> bool:
    """gsplat ships its kernels as the extension module gsplat.csrc when built at install; without it, its
    first kernel call compiles them (or loads an earlier JIT build)."""
    try:
        return importlib.util.find_spec("gsplat.csrc") is not None
    except (ImportError, ValueError):
        return False


def _centre_alpha(gsplat, device: torch.device) -> float:
    """Render one Gaussian of opacity 1 centred on a pixel centre: its alpha there is the backend's cap."""
    f32 = torch.float32
    scene = GaussianScene(
        means=torch.tensor([[0.0, 0.0, 1.0]], dtype=f32, device=device),
        quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=f32, device=device),
        log_scales=torch.full((1, 3), -2.0, dtype=f32, device=device),
        opacities=torch.full((1,), 40.0, dtype=f32, device=device),  # sigmoid: 1.0 in float32
        sh_dc=torch.zeros(1, 3, dtype=f32, device=device),
        sh_rest=torch.zeros(1, 0, 3, dtype=f32, device=device),
    )
    camera = Camera(np.eye(4), np.array([[16.0, 0, 8.5], [0, 16.0, 8.5], [0, 0, 1]]), 17, 17)
    with torch.no_grad():
        out = _rasterize(gsplat.rasterization, scene, camera, torch.zeros(3, dtype=f32, device=device), 0)
    return float(out.alpha[8, 8])


def render_gsplat(scene, camera: Camera, background: torch.Tensor, sh_degree: int) -> RenderResult:
    """Render with gsplat.rasterization; returns a RenderResult in the scene's dtype. api.py has checked that
    the scene is on a CUDA device; gsplat's failures become one-line DeviceErrors."""
    status = gsplat_status(scene.means.device)
    if not status.usable:
        raise DeviceError(f"render backend 'gsplat' is unavailable: {status.reason}")
    from gsplat import rasterization  # imported by the probe already

    try:
        return _rasterize(rasterization, scene, camera, background, sh_degree)
    except Exception as e:  # CUDA out of memory, a kernel launch failure, ...
        raise DeviceError(
            f"gsplat {status.version} failed on {scene.means.device} ({_one_line(e)}); "
            "--device cpu renders without it"
        ) from None


def _rasterize(rasterization, scene, camera: Camera, background: torch.Tensor, sh_degree: int):
    dev, dt, f32 = scene.means.device, scene.means.dtype, torch.float32
    k = (sh_degree + 1) ** 2
    coeffs = torch.cat([scene.sh_dc[:, None, :], scene.sh_rest[:, : k - 1, :]], 1).to(f32)
    colors, alphas, _ = rasterization(
        scene.means.to(f32),
        scene.quats.to(f32),
        torch.exp(scene.log_scales).to(f32),
        torch.sigmoid(scene.opacities).to(f32),
        coeffs,
        torch.as_tensor(camera.world_to_cam, dtype=f32, device=dev)[None],
        torch.as_tensor(camera.K, dtype=f32, device=dev)[None],
        camera.width,
        camera.height,
        near_plane=NEAR,
        eps2d=LOWPASS,
        sh_degree=sh_degree,
        packed=False,
        render_mode="RGB+D",  # accumulated depth sum_i w_i z_i, as the torch backend
        rasterize_mode="classic",
    )
    acc, alpha = colors[0].to(dt), alphas[0, ..., 0].to(dt)
    image = acc[..., :3] + (1 - alpha)[..., None] * background
    return RenderResult(image=image, alpha=alpha, depth=acc[..., 3])


def _one_line(e: BaseException) -> str:
    """An exception as one short line (CUDA and build errors span many)."""
    first = str(e).strip().splitlines()[0] if str(e).strip() else ""
    text = f"{type(e).__name__}: {first}" if first else type(e).__name__
    return text if len(text) <= 200 else text[:197] + "..."
