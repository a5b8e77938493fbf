"""--device and the GPU path: the checks and the device's way through encoder and decoder on every machine;
gsplat's probe, fallback and errors with stand-in gsplat modules (every machine); on a CUDA machine, the torch
renderer and SSIM against the CPU's, gsplat against the torch renderer, and the CLI and the attribute codec
on the GPU against the CPU.

The attribute codec runs on the CPU whatever the device (gspc/device.py), so its bytes and decoded attributes
must be identical on every device; renders, the check and refinement may differ by float round-off, and
gsplat 1.5's renders by the bound its alpha cap allows (gspc/render/gsplat_backend.py, spec 10.12).
"""

import dataclasses
import importlib.machinery
import math
import re
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from bench_gpu import NOT_RENDERED
from cli_runs import assert_one_line_error, run
from scenes import coarse_residual_scene, random_scene

import gspc.device as device_module
import gspc.encoder.decisions as decisions
import gspc.encoder.side_decision as side_decision
import gspc.pipeline as pipeline
import gspc.render.api as api
import gspc.render.gsplat_backend as gb
from gspc.cameras import Camera
from gspc.codec.attributes import decode_attributes
from gspc.device import CPU_RENDERER, check_device, float32_math, renderer_info, synchronize
from gspc.encoder.coding import encode_attributes
from gspc.errors import DeviceError
from gspc.format import container
from gspc.format.attribute_section import attribute_chunks
from gspc.io import read_scene, write_ply
from gspc.metrics import ssim
from gspc.pipeline import DecodeOptions, EncodeOptions, decode_bytes, encode, encode_scene
from gspc.presets import DEFAULT_RESTORER, QUALITY
from gspc.render import render
from gspc.render.project import project
from gspc.render.rules import ALPHA_MIN, T_MIN
from gspc.restore.restorer import load_restorer
from gspc.scene import ATTRIBUTE_NAMES, scene_equal

CUDA = torch.cuda.is_available()
needs_cuda = pytest.mark.skipif(not CUDA, reason="needs a CUDA GPU")
needs_gsplat = pytest.mark.skipif(
    not (CUDA and gb.gsplat_status(torch.device("cuda")).usable), reason="needs a CUDA GPU and working gsplat"
)
without_cuda = pytest.mark.skipif(CUDA, reason="checks the no-GPU message")


def small_encode(**kw) -> EncodeOptions:
    """A coarse rate, so that residuals are sent and the check runs when it has iterations."""
    return EncodeOptions(lam=40, synth_views=5, max_side=40, **kw)


# --- every machine ---------------------------------------------------------------------------------------


def test_unknown_device_is_refused_before_any_work(tmp_path):
    with pytest.raises(DeviceError, match="unknown device 'tpu'"):
        check_device("tpu")
    with pytest.raises(DeviceError, match="unknown device"):
        encode(tmp_path / "missing.ply", tmp_path / "o.gspc", opts=EncodeOptions(device="tpu"))
    with pytest.raises(DeviceError, match="unknown device"):
        encode_scene(coarse_residual_scene(), opts=EncodeOptions(device="tpu"))
    with pytest.raises(DeviceError, match="unknown device"):
        decode_bytes(b"not a gspc file", DecodeOptions(device="tpu"))
    assert not (tmp_path / "o.gspc").exists()


@without_cuda
def test_encode_on_cuda_without_gpu_is_refused_before_any_work(tmp_path, monkeypatch):
    # A missing scene file would be an InputError: the device is checked before the scene is read.
    with pytest.raises(DeviceError, match="--device cuda was requested but no CUDA GPU is available"):
        encode(tmp_path / "missing.ply", tmp_path / "o.gspc", opts=EncodeOptions(device="cuda"))
    assert not (tmp_path / "o.gspc").exists()

    def no_work(*args, **kwargs):
        raise AssertionError("the encoder started work before checking its device")

    monkeypatch.setattr(decisions, "encoder_cameras", no_work)
    with pytest.raises(DeviceError, match="no CUDA GPU"):
        encode_scene(coarse_residual_scene(), opts=EncodeOptions(device="cuda"))


@pytest.mark.parametrize(
    ("device", "message"),
    [pytest.param("cuda", "no CUDA GPU", marks=without_cuda), ("tpu", "unknown device")],
)
def test_cli_encode_refuses_a_device_in_one_line(tmp_path, device, message):
    src = tmp_path / "scene.ply"
    write_ply(coarse_residual_scene(), src)
    out = tmp_path / "s.gspc"
    assert_one_line_error(run("encode", src, "-o", out, "--device", device), message)
    assert not out.exists()


def test_the_device_reaches_the_restorer_and_the_check(monkeypatch):
    # cpu:0 runs on the CPU but compares unequal to plain cpu: where it arrives, the checked device was
    # passed along rather than a default.
    marker = torch.device("cpu", 0)
    assert marker != torch.device("cpu")
    monkeypatch.setattr(pipeline, "check_device", lambda name: marker)
    monkeypatch.setattr(decisions, "load_restorer", lambda *a, **k: spy_restorer(*a, **k))
    restorer_devices, check_devices = [], []

    class Checked(Exception):
        """Stops the encoder at its check (what the check does with the device is not this test's)."""

    def spy_restorer(name, *args, **kwargs):
        restorer_devices.append(kwargs.get("device"))
        return load_restorer(name, *args, **kwargs)

    def spy_check(inp, progress=None):
        check_devices.append(inp.device)
        raise Checked

    monkeypatch.setattr(pipeline, "load_restorer", spy_restorer)
    monkeypatch.setattr(side_decision, "check_side_info", spy_check)
    with pytest.raises(Checked):
        encode_scene(coarse_residual_scene(), opts=small_encode(check_iterations=2, restorer="none"))
    assert check_devices == [marker] and restorer_devices == [marker]
    data, rep = encode_scene(coarse_residual_scene(), opts=small_encode(check_iterations=0, restorer="none"))
    assert rep.info["renderer"] == CPU_RENDERER
    _, rep = decode_bytes(data, DecodeOptions(refine=False))
    assert restorer_devices == [marker] * 2  # a decode that does not refine loads no restorer
    assert "renderer" not in rep.info and "restorer" not in rep.info  # nor names what it did not run


# --- gsplat stand-ins (every machine) ----------------------------------------------------------------------
# A fake `gsplat` module in sys.modules whose rasterization() is missing its kernels, raises, or renders by
# gsplat 1.5's rules on the CPU (emulated below with gspc's own projection). The probe is pointed at the CPU,
# where the stand-in runs, in place of a GPU.

CPU = torch.device("cpu")
NO_KERNELS = AttributeError("'NoneType' object has no attribute 'fully_fused_projection_fwd'")


def emulated_rasterization(cap: float):
    """gsplat 1.5's rasterization(..., render_mode="RGB+D", rasterize_mode="classic") on the CPU, with alpha
    capped at ``cap``: alpha = min(cap, o exp(-sigma)), skipped where sigma < 0 or alpha < 1/255, a pixel
    done before the Gaussian that takes its transmittance to <= 1e-4 (gsplat's RasterizeToPixels3DGSFwd.cu),
    composited densely per pixel. The projection is gspc's (same conventions)."""

    def rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, **kw):
        cam = Camera(viewmats[0].double().numpy(), Ks[0].double().numpy(), width, height)
        p = project(
            means, quats, scales.log(), opacities.logit(), colors[:, 0], colors[:, 1:], cam, kw["sh_degree"]
        )
        ys, xs = torch.meshgrid(torch.arange(height) + 0.5, torch.arange(width) + 0.5, indexing="ij")
        acc = torch.zeros(height, width, 4)
        T = torch.ones(height, width)
        done = torch.zeros(height, width, dtype=torch.bool)
        for i in torch.argsort(p.depths, stable=True).tolist():
            if not bool(p.drawn[i]):
                continue
            a, b, c = p.conics[i]
            dx, dy = p.means2d[i, 0] - xs, p.means2d[i, 1] - ys
            sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
            alpha = torch.clamp(p.opacities[i] * torch.exp(-sigma), max=cap)
            live = ~done & (sigma >= 0) & (alpha >= ALPHA_MIN)
            next_t = T * (1 - alpha)
            done |= live & (next_t <= T_MIN)
            draw = live & ~done
            feature = torch.cat([p.colors[i], p.depths[i, None]])
            acc += torch.where(draw, alpha * T, 0.0)[..., None] * feature
            T = torch.where(draw, next_t, T)
        return acc[None], (1 - T)[None, ..., None], {}

    return rasterization


def raising(error: Exception, after: int = 0, then=None):
    """A rasterization() that works (``then``) for ``after`` calls and raises ``error`` from then on."""
    calls = []

    def rasterization(*args, **kwargs):
        calls.append(1)
        if len(calls) <= after:
            return then(*args, **kwargs)
        raise error

    rasterization.calls = calls
    return rasterization


@pytest.fixture
def fake_gsplat(monkeypatch):
    """Install a stand-in gsplat: fake_gsplat(rasterization, version, prebuilt) -> the module; the probe's
    cache starts empty and renderer_info's probe runs on the CPU."""
    monkeypatch.setattr(gb, "_STATUS", {})
    cpu_probe = gb.gsplat_status
    monkeypatch.setattr(
        device_module, "gsplat_status", lambda device, progress=None: cpu_probe(CPU, progress)
    )
    monkeypatch.setattr(api, "gsplat_status", lambda device, progress=None: cpu_probe(CPU, progress))

    def install(rasterization, version="1.5.3", prebuilt=True):
        module = types.ModuleType("gsplat")
        module.__version__, module.rasterization = version, rasterization
        monkeypatch.setitem(sys.modules, "gsplat", module)
        if prebuilt:
            csrc = types.ModuleType("gsplat.csrc")
            csrc.__spec__ = importlib.machinery.ModuleSpec("gsplat.csrc", None)
            monkeypatch.setitem(sys.modules, "gsplat.csrc", csrc)
        else:
            monkeypatch.delitem(sys.modules, "gsplat.csrc", raising=False)
        return module

    return install


def test_gsplat_without_kernels_falls_back_to_torch_on_the_gpu_with_the_reason(fake_gsplat):
    # gsplat imports without a CUDA toolkit but fails at its first kernel call: probed once, not retried.
    rasterization = raising(NO_KERNELS)
    fake_gsplat(rasterization)
    cuda = torch.device("cuda")  # a name only: the stand-in's probe runs on the CPU
    info = renderer_info(cuda)
    assert info.startswith("torch on cuda (gsplat not used: gsplat 1.5.3's CUDA kernels do not run here")
    assert "AttributeError" in info and "\n" not in info
    assert api.backend_for(cuda) == "torch"
    renderer_info(cuda, encoder=True)
    assert len(rasterization.calls) == 1


def test_gsplat_raising_at_its_first_call_falls_back(fake_gsplat):
    error = RuntimeError(
        "CUDA error: no kernel image is available for execution on the device\nCUDA kernel ..."
    )
    fake_gsplat(raising(error))
    status = gb.gsplat_status(CPU)
    assert not status.usable and status.version == "1.5.3"
    assert "RuntimeError: CUDA error: no kernel image is available" in status.reason
    assert "\n" not in status.reason and "kernel ..." not in status.reason


@pytest.mark.parametrize("version", ["1.4.0", "1.6.0", "2.0.1"])
def test_gsplat_versions_outside_the_rules_are_not_used(fake_gsplat, version):
    rasterization = raising(AssertionError("a version outside SUPPORTED was run"))
    fake_gsplat(rasterization, version=version)
    status = gb.gsplat_status(CPU)
    assert not status.usable and f"gsplat {version} is not a version gspc renders with" in status.reason
    assert "gsplat>=1.5,<1.6" in status.reason and not rasterization.calls


def test_gsplat_not_installed(fake_gsplat, monkeypatch):
    monkeypatch.setitem(sys.modules, "gsplat", None)  # import gsplat raises ImportError
    reason = "gsplat is not installed: pip install 'gspc[cuda]' (gsplat>=1.5,<1.6)"
    assert renderer_info(torch.device("cuda")) == f"torch on cuda (gsplat not used: {reason})"


@pytest.mark.parametrize("prebuilt", [True, False])
def test_working_gsplat_is_named_with_its_version_and_measured_cap(fake_gsplat, prebuilt):
    fake_gsplat(emulated_rasterization(0.999), prebuilt=prebuilt)
    stages = []
    status = gb.gsplat_status(CPU, lambda stage, done, total: stages.append((stage, done)))
    assert status.usable and status.version == "1.5.3" and status.alpha_cap == 0.999
    # Without prebuilt kernels gsplat's first call compiles them: the run hears of it as a stage, and the
    # summary gives the time it took.
    assert stages == ([] if prebuilt else [(gb.COMPILE_STAGE, 0), (gb.COMPILE_STAGE, 1)])
    assert (status.jit_seconds is None) == prebuilt
    info = renderer_info(torch.device("cuda"))
    assert info.startswith(
        "gsplat 1.5.3 (alpha cap 0.999, the file's rules 0.99: pixels at capped Gaussians may differ by up "
        "to 0.1 of the colour range, spec 10.12)"
    )
    assert info.endswith(" on cuda") and ("first call built or loaded them" in info) != prebuilt
    assert renderer_info(torch.device("cuda"), encoder=True).endswith(
        "; residuals rendered by the torch renderer (the file's rules)"
    )
    assert api.backend_for(torch.device("cuda")) == "gsplat"


def test_gsplat_failing_at_render_time_is_one_line_device_error(fake_gsplat):
    fake_gsplat(
        raising(
            RuntimeError("CUDA out of memory. Tried to allocate 2.00 GiB\nmore"),
            1,
            emulated_rasterization(0.999),
        )
    )
    s = coarse_residual_scene()
    with pytest.raises(DeviceError) as e:
        gb.render_gsplat(s, _camera(), torch.zeros(3), s.sh_degree)
    assert str(e.value).startswith("gsplat 1.5.3 failed on cpu (RuntimeError: CUDA out of memory.")
    assert "\n" not in str(e.value) and "--device cpu" in str(e.value)


def test_gsplat_unavailable_is_one_line_device_error(fake_gsplat):
    fake_gsplat(raising(NO_KERNELS))
    s = coarse_residual_scene()
    with pytest.raises(
        DeviceError, match="render backend 'gsplat' is unavailable: gsplat 1.5.3's CUDA kernels"
    ):
        gb.render_gsplat(s, _camera(), torch.zeros(3), s.sh_degree)


def test_alpha_cap_miss_is_bounded_on_opaque_gaussians(fake_gsplat):
    # Opacity logits N(5, 1): two thirds of the Gaussians reach gspc's 0.99 cap (logit 4.6) near their
    # centres, and many overlap, translucent ones among them. The caps differ only within 0.14 sigma of a
    # capped Gaussian's centre (where o exp(-q/2) > 0.99), so few pixels differ, by at most the bound.
    fake_gsplat(emulated_rasterization(0.999))
    s = random_scene(300, sh_degree=1, seed=4, log_scale=-1.6, opacity_logit=5.0, dc_std=0.8)
    cam, bg = _camera(), torch.tensor([0.2, 0.3, 0.4])
    with torch.no_grad():
        ours = render(s, cam, background=bg, backend="torch").image
        theirs = gb.render_gsplat(s, cam, bg, s.sh_degree).image
        p = project(s.means, s.quats, s.log_scales, s.opacities, s.sh_dc, s.sh_rest, cam, s.sh_degree)
    colours = torch.cat([p.colors[p.drawn].reshape(-1), bg])
    spread = float(colours.max() - colours.min())  # every pixel mixes these colours and the background
    miss = (ours - theirs).abs()
    assert gb.cap_miss_bound(0.999) == pytest.approx(0.1)
    assert 1e-3 < float(miss.max()) <= gb.cap_miss_bound(0.999) * spread, (float(miss.max()), spread)
    assert float(miss.mean()) < 1e-4


def test_alpha_cap_miss_bound_is_reached_behind_a_translucent_gaussian(fake_gsplat):
    # A Gaussian of alpha 0.92 leaves transmittance 0.08 in front of an opaque one: gsplat 1.5 (cap 0.999)
    # stops before the opaque one (0.08 x 0.001 <= 1e-4), the rules draw it (0.08 x 0.01 > 1e-4).
    fake_gsplat(emulated_rasterization(0.999))
    s = dataclasses.replace(
        coarse_residual_scene(),
        means=torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5]]),
        quats=torch.tensor([[1.0, 0, 0, 0]] * 2),
        log_scales=torch.full((2, 3), -1.0),
        opacities=torch.logit(torch.tensor([0.92, 1.0 - 1e-6])),
        sh_dc=torch.tensor([[0.0, 0.0, 0.0], [1.7, 1.7, 1.7]]),  # colours 0.5 and 1.0
        sh_rest=torch.zeros(2, 0, 3),
        sh_degree=0,
    )
    w2c = np.eye(4)
    w2c[2, 3] = (
        3.0  # the translucent Gaussian at depth 3, the opaque one at 3.5, both on pixel (8, 8)'s centre
    )
    cam = Camera(w2c, np.array([[40.0, 0, 8.5], [0, 40.0, 8.5], [0, 0, 1]]), 17, 17)
    bg = torch.zeros(3)
    with torch.no_grad():
        ours = render(s, cam, background=bg, backend="torch").image[8, 8]
        theirs = gb.render_gsplat(s, cam, bg, 0).image[8, 8]
    assert float((ours - theirs).abs().max()) == pytest.approx(0.08 * 0.99 * 0.98, rel=0.05)


def test_a_stand_in_with_the_rules_cap_agrees_with_the_torch_renderer(fake_gsplat):
    # The emulation itself is right: with gspc's cap it matches the torch renderer to round-off.
    fake_gsplat(emulated_rasterization(0.99))
    s = random_scene(300, sh_degree=1, seed=4, log_scale=-1.6, opacity_logit=5.0, dc_std=0.8)
    cam, bg = _camera(), torch.tensor([0.2, 0.3, 0.4])
    assert gb.gsplat_status(CPU).alpha_cap == 0.99 and gb.cap_miss_bound(0.99) == 0
    with torch.no_grad():
        ours = render(s, cam, background=bg, backend="torch").image
        theirs = gb.render_gsplat(s, cam, bg, s.sh_degree).image
    assert float((ours - theirs).abs().max()) < 1e-4


def test_float32_math_is_local_and_synchronize_is_free_on_cpu():
    before = torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32
    with float32_math():
        assert not torch.backends.cudnn.allow_tf32 and not torch.backends.cuda.matmul.allow_tf32
    assert (torch.backends.cudnn.allow_tf32, torch.backends.cuda.matmul.allow_tf32) == before
    synchronize(CPU)
    synchronize()


def test_pyproject_pins_what_the_code_needs():
    # The fused Adam kernel on CPU tensors (gspc/adam.py) needs torch 2.4; the [cuda] extra takes exactly the
    # gsplat versions gsplat_backend.SUPPORTED renders with.
    text = (Path(__file__).resolve().parent.parent / "pyproject.toml").read_text()
    floor = re.search(r'"torch>=(\d+)\.(\d+)', text)
    assert floor and (int(floor[1]), int(floor[2])) >= (2, 4)
    (lo_major, lo_minor), (hi_major, hi_minor) = gb.SUPPORTED
    assert f'"gsplat>={lo_major}.{lo_minor},<{hi_major}.{hi_minor}"' in text


def test_stage_timers_wait_for_the_gpu(monkeypatch):
    calls = []
    from gspc import stages

    monkeypatch.setattr(stages, "synchronize", lambda device=None: calls.append(device))
    rep = pipeline.Report()
    with rep.stages(None, None).stage("render"):
        pass
    assert len(calls) == 2 and "render" in rep.seconds


@without_cuda
def test_gpu_bench_measures_nothing_without_a_gpu(tmp_path):
    out = tmp_path / "scale_gpu.md"
    tool = Path(__file__).resolve().parent.parent / "tools" / "bench_gpu.py"
    proc = subprocess.run([sys.executable, str(tool), "--out", str(out)], capture_output=True, text=True)
    assert proc.returncode != 0 and "no CUDA GPU here: nothing measured, nothing written" in proc.stderr
    assert not out.exists()


def _one_copy_scale_scene(folder: Path, n: int = 400) -> None:
    """A one-copy "scale scene" (tools/make_scale_scenes.py's layout) of ``n`` random Gaussians."""
    import json

    folder.mkdir()
    write_ply(random_scene(n, sh_degree=1, seed=2, log_scale=-3.5), folder / "point_cloud.ply")
    copy = {"asset": "random", "gaussians": n, "centre": [0.0, 0.0], "yaw": 0.0}
    (folder / "scene.json").write_text(json.dumps({"gaussians": n, "copies": [copy]}))


@pytest.mark.slow
def test_walk_bench_measures_nothing_without_a_gpu_and_runs_on_the_cpu(tmp_path):
    # tools/bench_gpu_walk.py: refused without CUDA; its dry run (--device cpu) times every configuration.
    tool = Path(__file__).resolve().parent.parent / "tools" / "bench_gpu_walk.py"
    _one_copy_scale_scene(tmp_path / "scale_400")
    out = tmp_path / "walk.md"
    base = [sys.executable, str(tool), "--scene", str(tmp_path / "scale_400"), "--out", str(out)]
    if not CUDA:
        proc = subprocess.run(base, capture_output=True, text=True)
        assert proc.returncode != 0 and "no CUDA GPU here: nothing measured, nothing written" in proc.stderr
        assert not out.exists()
    args = ["--device", "cpu", "--views", "1", "--repeats", "1", "--budgets", "19,21"]
    proc = subprocess.run([*base, *args], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]
    table = out.read_text()
    assert "| CPU_WALK (2^19, looped scans) |" in table and "| 2^21, one-kernel scans = GPU_WALK |" in table


@pytest.mark.slow
def test_gpu_bench_runs_its_steps_on_the_cpu(tmp_path):
    # The tool's dry run (--device cpu): every step of a GPU session, so that a lent GPU's scarce minutes
    # are not lost to the tool itself. A one-copy "scale scene" of 400 Gaussians, four close-ups, kept file.
    import json

    folder = tmp_path / "scale_400"
    _one_copy_scale_scene(folder)
    tool = Path(__file__).resolve().parent.parent / "tools" / "bench_gpu.py"
    out, logs, keep = tmp_path / "gpu.md", tmp_path / "logs", tmp_path / "keep" / "files"  # made by the tool
    args = [
        "--device",
        "cpu",
        "--scenes",
        str(tmp_path),
        "--sizes",
        "400",
        "--per-copy",
        "4",
        "--tests",
        "none",
    ]
    proc = subprocess.run(
        [sys.executable, str(tool), *args, "--decoders", "torch,cpu", "--keep", str(keep),
         "--logs", str(logs), "--out", str(out), "--threads", "1"],
        capture_output=True,
        text=True,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = [json.loads(line) for line in (logs / "rows.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == ["encode", "decode", "decode"]
    assert rows[0]["bytes"] == (keep / "scale_400.gspc").stat().st_size > 0
    assert all(math.isfinite(r["psnr"]) and r["renderer"] in (CPU_RENDERER, NOT_RENDERED) for r in rows[1:])
    assert "| 400 | encode | cpu |" in out.read_text()
    # The deadline stops a command still running, and its row says so (here at once: a deadline of 0).
    import bench_gpu

    stopped = bench_gpu.measure(
        ["info", str(folder / "point_cloud.ply")], bench_gpu.child_env(1, None), bench_gpu.Clock(0.0),
        tmp_path / "stopped.log",
    )  # fmt: skip
    assert stopped["stopped"]
    assert "stopped at the deadline" in bench_gpu.table([{**rows[1], **stopped, "psnr": math.nan}])[-1]


# --- CUDA machines -----------------------------------------------------------------------------------------


def _camera(w: int = 64, h: int = 48) -> Camera:
    a = 0.4
    w2c = np.eye(4)
    w2c[:3, :3] = [[math.cos(a), 0, -math.sin(a)], [0, 1, 0], [math.sin(a), 0, math.cos(a)]]
    w2c[2, 3] = 3.0
    return Camera(w2c, np.array([[60.0, 0, w / 2 + 0.7], [0, 62.0, h / 2 - 0.4], [0, 0, 1.0]]), w, h)


def _image_and_grads(s, cam, weights, backend):
    s = s.detach()
    for name in ATTRIBUTE_NAMES:
        getattr(s, name).requires_grad_(True)
    image = render(s, cam, background=[0.2, 0.3, 0.4], backend=backend).image
    (image * weights).sum().backward()
    return image.detach(), {name: getattr(s, name).grad for name in ATTRIBUTE_NAMES}


def _agree(a, ga, b, gb_, image_max: float = 1e-2, grad_rel: float = 1e-2) -> None:
    """Float32 renders by the same rules: pixels agree to round-off (mean under 1e-5); one pixel may differ
    by more where a Gaussian's alpha lands within round-off of the 1/255 cut-off and is drawn by one and
    skipped by the other, a jump of at most 1/255 times the larger of its colour and what lies behind it
    (colours here stay under 2, so under 1e-2). Gradients: the same sums in another order (float atomics on
    the GPU) plus the same rare cut-off switches; a convention mismatch (low-pass, SH, cap) is larger."""
    diff = (a.cpu() - b.cpu()).abs()
    assert float(diff.mean()) < 1e-5, float(diff.mean())
    assert float(diff.max()) < image_max, float(diff.max())
    for name in ATTRIBUTE_NAMES:
        x, y = ga[name].cpu(), gb_[name].cpu()
        rel = float((x - y).norm() / x.norm().clamp_min(1e-12))
        assert rel < grad_rel, (name, rel)


def _cuda_scene_and_weights(opacity_max: float | None = 4.0):
    s = random_scene(300, sh_degree=3, seed=3, log_scale=-3.0, opacity_logit=1.0, rest_std=0.2)
    if opacity_max is not None:
        s = dataclasses.replace(s, opacities=s.opacities.clamp(max=opacity_max))
    cam = _camera()
    weights = torch.rand(cam.height, cam.width, 3, generator=torch.Generator().manual_seed(5))
    return s, cam, weights


@needs_cuda
def test_torch_renderer_agrees_on_cpu_and_cuda():
    # No gsplat needed: the torch renderer's walk on the GPU against its compiled CPU kernels, opaque
    # Gaussians included (both follow the rules' 0.99 cap).
    s, cam, weights = _cuda_scene_and_weights(opacity_max=None)
    s = dataclasses.replace(s, opacities=s.opacities + 3.0)
    a, ga = _image_and_grads(s, cam, weights, "torch")
    b, gb_ = _image_and_grads(s.to("cuda"), cam, weights.to("cuda"), "torch")
    assert b.is_cuda
    _agree(a, ga, b, gb_)


@needs_cuda
def test_ssim_agrees_on_cpu_and_cuda_even_with_tf32_enabled(monkeypatch):
    # TF32 convolutions (cuDNN's default on Ampere and later) moved SSIM's variances by ~1e-4: ssim pins
    # float32 locally (gspc/device.py float32_math), whatever the process's flags.
    monkeypatch.setattr(torch.backends.cudnn, "allow_tf32", True)
    g = torch.Generator().manual_seed(2)
    a, b = torch.rand(2, 96, 128, 3, generator=g).unbind(0)
    b = (0.7 * a + 0.3 * b).requires_grad_(True)
    ref = ssim(a.double(), b.detach().double())
    on_cpu = ssim(a, b)
    (grad_cpu,) = torch.autograd.grad(on_cpu, b)
    bc = b.detach().cuda().requires_grad_(True)
    on_gpu = ssim(a.cuda(), bc)
    (grad_gpu,) = torch.autograd.grad(on_gpu, bc)
    assert torch.backends.cudnn.allow_tf32  # restored
    assert abs(float(on_gpu.detach()) - float(ref)) < 1e-6 and abs(float(on_cpu.detach()) - float(ref)) < 1e-6
    assert float((grad_gpu.cpu() - grad_cpu).abs().max()) < 1e-4 * float(grad_cpu.abs().max())


@needs_gsplat
def test_gsplat_and_torch_renderer_agree():
    # Opacity logits under 4 (alpha < 0.982): no Gaussian reaches either cap, so gsplat 1.5 follows the
    # rules and only round-off separates them.
    s, cam, weights = _cuda_scene_and_weights()
    s, weights = s.to("cuda"), weights.to("cuda")
    a, ga = _image_and_grads(s, cam, weights, "torch")
    b, gb_ = _image_and_grads(s, cam, weights, "gsplat")
    _agree(a, ga, b, gb_)


@needs_gsplat
def test_gsplat_misses_the_rules_by_at_most_its_cap_bound_on_opaque_gaussians():
    # Alpha > 0.99 near the centres of most Gaussians: gsplat 1.5 caps at 0.999 (its probe measured it),
    # and its pixels differ from the rules' by at most cap_miss_bound of the colour range.
    status = gb.gsplat_status(torch.device("cuda"))
    s = random_scene(300, sh_degree=1, seed=4, log_scale=-1.6, opacity_logit=5.0, dc_std=0.8).to("cuda")
    cam, bg = _camera(), torch.tensor([0.2, 0.3, 0.4], device="cuda")
    with torch.no_grad():
        ours = render(s, cam, background=bg, backend="torch").image
        theirs = render(s, cam, background=bg, backend="gsplat").image
        p = project(s.means, s.quats, s.log_scales, s.opacities, s.sh_dc, s.sh_rest, cam, s.sh_degree)
    colours = torch.cat([p.colors[p.drawn].reshape(-1), bg])
    spread = float(colours.max() - colours.min())
    miss = (ours - theirs).abs()
    assert float(miss.max()) <= gb.cap_miss_bound(status.alpha_cap) * spread + 1e-2  # + the cut-off jump
    assert float(miss.mean()) < 1e-4


@needs_cuda
@pytest.mark.slow
def test_cli_encode_and_decode_on_cuda(tmp_path):
    src, enc, dec = tmp_path / "scene.ply", tmp_path / "s.gspc", tmp_path / "out.ply"
    write_ply(coarse_residual_scene(), src)
    args = ["--lambda", 40, "--views", 5, "--max-side", 40, "--check-iterations", 2]
    res = run("encode", src, "-o", enc, "--device", "cuda", *args)
    assert res.exit_code == 0, res.output
    assert "renderer: " in res.output and " on cuda" in res.output
    res = run("decode", enc, "-o", dec, "--device", "cuda", "--iterations", 3)
    assert res.exit_code == 0, res.output
    out = read_scene(dec)
    assert out.num_gaussians > 0 and all(torch.isfinite(t).all() for t in out.tensors().values())


@needs_cuda
def test_attribute_decode_is_bit_identical_on_gpu(tmp_path):
    enc = encode_attributes(coarse_residual_scene(), QUALITY["low"].attributes)
    cpu = decode_attributes(enc.chunks, enc.section)
    assert scene_equal(cpu.to("cuda").to("cpu"), cpu)

    data, _ = encode_scene(coarse_residual_scene(), opts=small_encode(check_iterations=0))
    on_cpu, _ = decode_bytes(data, DecodeOptions(refine=False))
    on_gpu, rep = decode_bytes(data, DecodeOptions(refine=False, device="cuda"))
    assert on_gpu.means.is_cuda and "cuda" in str(rep.info["renderer"])
    assert scene_equal(on_gpu.to("cpu"), on_cpu)
    a, b = tmp_path / "cpu.ply", tmp_path / "gpu.ply"
    write_ply(on_cpu, a)
    write_ply(on_gpu.to("cpu"), b)
    assert a.read_bytes() == b.read_bytes()


@needs_cuda
def test_encode_on_gpu_codes_the_same_attribute_bytes_and_decodes_on_cpu():
    # No check: with one, the choice between side information and attributes may tip on render round-off.
    cpu_data, _ = encode_scene(coarse_residual_scene(), opts=small_encode(check_iterations=0))
    gpu_data, rep = encode_scene(
        coarse_residual_scene(), opts=small_encode(check_iterations=0, device="cuda")
    )
    assert "cuda" in str(rep.info["renderer"])
    cpu_c, gpu_c = container.unpack(cpu_data), container.unpack(gpu_data)
    assert attribute_chunks(gpu_c.chunks) == attribute_chunks(cpu_c.chunks)
    assert gpu_c.header["attributes"] == cpu_c.header["attributes"]
    # The GPU's file on the CPU: the same decoded attributes, the same views, and a refinement that runs.
    from_cpu, rep_cpu = decode_bytes(cpu_data, DecodeOptions(refine=False))
    from_gpu, rep_gpu = decode_bytes(gpu_data, DecodeOptions(refine=False))
    assert scene_equal(from_gpu, from_cpu)
    counts = [(r.num_views, r.num_views_with_residual) for r in (rep_gpu, rep_cpu)]
    assert counts[0] == counts[1]
    refined, _ = decode_bytes(gpu_data, DecodeOptions(iterations=3))
    assert all(torch.isfinite(t).all() for t in refined.tensors().values())


@needs_cuda
def test_encode_without_side_info_tunes_to_the_cpu_bytes():
    # A file without side information has its coded values tuned (gspc/encoder/tuning.py), which renders
    # on the CPU whatever the run's device: a GPU encode tunes to the CPU's bytes.
    cpu_data, _ = encode_scene(coarse_residual_scene(), opts=small_encode(side_info=False))
    gpu_data, rep = encode_scene(coarse_residual_scene(), opts=small_encode(side_info=False, device="cuda"))
    assert "cuda" in str(rep.info["renderer"]) and "iterations" in rep.info["tuning"]
    cpu_c, gpu_c = container.unpack(cpu_data), container.unpack(gpu_data)
    assert attribute_chunks(gpu_c.chunks) == attribute_chunks(cpu_c.chunks)


@needs_cuda
@pytest.mark.slow  # the check's rivals run the attribute codec (CPU) several times
def test_check_restorer_and_refinement_run_on_gpu():
    restorer = load_restorer(DEFAULT_RESTORER, device="cuda")
    assert next(restorer.model.parameters()).is_cuda
    img = torch.rand(40, 30, 3, device="cuda")
    assert restorer.restore(img, torch.zeros_like(img)).is_cuda

    data, rep = encode_scene(coarse_residual_scene(), opts=small_encode(check_iterations=3, device="cuda"))
    assert rep.side_info is not None  # the check ran on the GPU
    out, rep = decode_bytes(data, DecodeOptions(iterations=3, device="cuda"))
    assert out.means.is_cuda and all(torch.isfinite(t).all() for t in out.tensors().values())


@needs_cuda
@pytest.mark.slow
def test_the_decoders_work_limits_on_the_gpu(tmp_path):
    """Issue 50 on CUDA: every crafted work file (tools/amplification_cases.py work_files) decoded with
    --device cuda ends as on the CPU (refused in one line before it renders, or decoded within its budget),
    and a render past 2^30 pairs is refused before its tile lists are built."""
    import amplification_cases as amp

    from gspc.errors import GspcError
    from gspc.pipeline import decode
    from gspc.render.rasterize import bin_tiles

    write_ply(random_scene(300, sh_degree=1, seed=0), tmp_path / "s.ply")
    opts = EncodeOptions(
        lam=200, synth_views=6, max_side=48, check_iterations=0, precision=False, device="cuda"
    )
    encode(tmp_path / "s.ply", tmp_path / "b.gspc", opts=opts)
    header = container.read(tmp_path / "b.gspc").header
    for name, path, ok in amp.work_files(header, tmp_path):
        try:
            decode(path, tmp_path / "o.ply", DecodeOptions(device="cuda"))
            assert ok, name
        except GspcError as e:
            assert not ok and "spec 10.8" in str(e), (name, str(e))
    n, dev = 70_000, "cuda"
    with pytest.raises(GspcError, match="Gaussian-tile pairs"):
        bin_tiles(
            torch.full((n, 2), 1024.0, device=dev),
            torch.tensor([[1.0, 0.0, 1.0]], device=dev).repeat(n, 1),
            torch.full((n,), 0.9, device=dev),
            torch.full((n, 2), 5000.0, device=dev),
            2048,
            2048,
        )
