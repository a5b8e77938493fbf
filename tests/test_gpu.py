"""--device: the checks and the device's way through encoder and decoder on every machine; on a CUDA machine,
gsplat against the torch renderer, and the attribute codec's bytes and decode against the CPU's.

The attribute codec runs on the CPU whatever the device (gspc/device.py), so its bytes and decoded attributes
must be identical on every device; renders, the check and refinement may differ by float round-off.
"""

import dataclasses
import math

import numpy as np
import pytest
import torch
from cli_runs import assert_one_line_error, run
from scenes import random_scene

import gspc.pipeline as pipeline
from gspc.cameras import Camera
from gspc.codec.attributes import attribute_chunks, decode_attributes, encode_attributes
from gspc.device import check_device, renderer_info
from gspc.errors import DeviceError
from gspc.format import container
from gspc.io import write_ply
from gspc.pipeline import DecodeOptions, EncodeOptions, decode_bytes, encode, encode_scene
from gspc.presets import DEFAULT_RESTORER, QUALITY
from gspc.render import render
from gspc.render.gsplat_backend import gsplat_available
from gspc.restore.restorer import load_restorer
from gspc.scene import ATTRIBUTE_NAMES, scene_equal

CUDA = torch.cuda.is_available()
needs_cuda = pytest.mark.skipif(not CUDA, reason="needs a CUDA GPU")
needs_gsplat = pytest.mark.skipif(not (CUDA and gsplat_available()), reason="needs a CUDA GPU and gsplat")
without_cuda = pytest.mark.skipif(CUDA, reason="checks the no-GPU message")


def scene(seed=1):
    return random_scene(
        200, sh_degree=2, seed=seed, log_scale=-2.8, opacity_logit=1.5, dc_std=0.6, rest_std=0.2
    )


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
        encode_scene(scene(), opts=EncodeOptions(device="tpu"))
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

    monkeypatch.setattr(pipeline, "encoder_cameras", no_work)
    with pytest.raises(DeviceError, match="no CUDA GPU"):
        encode_scene(scene(), opts=EncodeOptions(device="cuda"))


@pytest.mark.parametrize(
    ("device", "message"),
    [pytest.param("cuda", "no CUDA GPU", marks=without_cuda), ("tpu", "unknown device")],
)
def test_cli_encode_refuses_a_device_in_one_line(tmp_path, device, message):
    src = tmp_path / "scene.ply"
    write_ply(scene(), src)
    out = tmp_path / "s.gspc"
    assert_one_line_error(run("encode", src, "-o", out, "--device", device), message)
    assert not out.exists()


def test_renderer_is_reported(monkeypatch):
    import gspc.render.api as api

    cuda = torch.device("cuda")  # a name only: nothing is allocated there
    monkeypatch.setattr(api, "gsplat_available", lambda: True)
    assert renderer_info(cuda) == "gsplat on cuda"
    assert renderer_info(torch.device("cpu")) == "torch on cpu"
    monkeypatch.setattr(api, "gsplat_available", lambda: False)
    assert renderer_info(cuda).startswith("torch on cuda") and "gsplat" in renderer_info(cuda)
    assert renderer_info(torch.device("cpu")) == "torch on cpu"


def test_the_device_reaches_the_restorer_and_the_check(monkeypatch):
    # cpu:0 runs on the CPU but compares unequal to plain cpu: where it arrives, the checked device was
    # passed along rather than a default.
    marker = torch.device("cpu", 0)
    assert marker != torch.device("cpu")
    monkeypatch.setattr(pipeline, "check_device", lambda name: marker)
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
    monkeypatch.setattr(pipeline, "check_side_info", spy_check)
    with pytest.raises(Checked):
        encode_scene(scene(), opts=small_encode(check_iterations=2, restorer="none"))
    assert check_devices == [marker] and restorer_devices == [marker]
    data, rep = encode_scene(scene(), opts=small_encode(check_iterations=0, restorer="none"))
    assert rep.info["renderer"] == "torch on cpu"
    _, rep = decode_bytes(data, DecodeOptions(refine=False))
    assert restorer_devices == [marker] * 3
    assert rep.info["renderer"] == "torch on cpu"


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


@needs_gsplat
def test_gsplat_and_torch_renderer_agree():
    # Opacity logits under 4 (alpha < 0.982): gsplat caps alpha at 0.999 where gspc's rules cap it at 0.99
    # (gspc/render/rules.py ALPHA_MAX), so more opaque Gaussians would differ by design, not by error.
    s = random_scene(300, sh_degree=3, seed=3, log_scale=-3.0, opacity_logit=1.0, rest_std=0.2)
    s = dataclasses.replace(s, opacities=s.opacities.clamp(max=4.0)).to("cuda")
    cam = _camera()
    weights = torch.rand(cam.height, cam.width, 3, generator=torch.Generator().manual_seed(5)).to("cuda")
    a, ga = _image_and_grads(s, cam, weights, "torch")
    b, gb = _image_and_grads(s, cam, weights, "gsplat")
    diff = (a - b).abs()
    # Both are float32 with the same rules, so pixels agree to round-off (mean under 1e-5). One pixel may
    # differ by more: a Gaussian whose alpha lands within round-off of the 1/255 cut-off is drawn by one
    # renderer and skipped by the other, a jump of at most 1/255 times the larger of its colour and what lies
    # behind it (colours here stay under 2, so under 1e-2).
    assert float(diff.mean()) < 1e-5, float(diff.mean())
    assert float(diff.max()) < 1e-2, float(diff.max())
    # Gradients: the same sums in another order (float32 atomics in gsplat) plus the same rare cut-off
    # switches, a relative error far under 1e-2; a convention mismatch (low-pass, SH direction, alpha cap)
    # is larger.
    for name in ATTRIBUTE_NAMES:
        rel = float((ga[name] - gb[name]).norm() / ga[name].norm().clamp_min(1e-12))
        assert rel < 1e-2, (name, rel)


@needs_cuda
def test_attribute_decode_is_bit_identical_on_gpu(tmp_path):
    enc = encode_attributes(scene(), QUALITY["low"].attributes)
    cpu = decode_attributes(enc.chunks, enc.section)
    assert scene_equal(cpu.to("cuda").to("cpu"), cpu)

    data, _ = encode_scene(scene(), opts=small_encode(check_iterations=0))
    on_cpu, _ = decode_bytes(data, DecodeOptions(refine=False))
    on_gpu, rep = decode_bytes(data, DecodeOptions(refine=False, device="cuda"))
    assert on_gpu.means.is_cuda and "cuda" in str(rep.info["renderer"])
    assert scene_equal(on_gpu.to("cpu"), on_cpu)
    a, b = tmp_path / "cpu.ply", tmp_path / "gpu.ply"
    write_ply(on_cpu, a)
    write_ply(on_gpu.to("cpu"), b)
    assert a.read_bytes() == b.read_bytes()


@needs_cuda
def test_encode_on_gpu_codes_the_same_attribute_bytes():
    # No check: with one, the choice between side information and attributes may tip on render round-off.
    cpu_data, _ = encode_scene(scene(), opts=small_encode(check_iterations=0))
    gpu_data, rep = encode_scene(scene(), opts=small_encode(check_iterations=0, device="cuda"))
    assert "cuda" in str(rep.info["renderer"])
    cpu_c, gpu_c = container.unpack(cpu_data), container.unpack(gpu_data)
    assert attribute_chunks(gpu_c.chunks) == attribute_chunks(cpu_c.chunks)
    assert gpu_c.header["attributes"] == cpu_c.header["attributes"]


@needs_cuda
@pytest.mark.slow  # the check's rivals run the attribute codec (CPU) several times
def test_check_restorer_and_refinement_run_on_gpu():
    restorer = load_restorer(DEFAULT_RESTORER, device="cuda")
    assert next(restorer.model.parameters()).is_cuda
    img = torch.rand(40, 30, 3, device="cuda")
    assert restorer.restore(img, torch.zeros_like(img)).is_cuda

    data, rep = encode_scene(scene(), opts=small_encode(check_iterations=3, device="cuda"))
    assert rep.side_info is not None  # the check ran on the GPU
    out, rep = decode_bytes(data, DecodeOptions(iterations=3, device="cuda"))
    assert out.means.is_cuda and all(torch.isfinite(t).all() for t in out.tensors().values())
