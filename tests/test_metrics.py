import math

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from gspc.errors import InputError
from gspc.metrics import mean_psnr, mse, psnr, quantize8, ssim, ssim_map


def _pair(h=24, w=20, dtype=torch.float64, seed=0):
    g = torch.Generator().manual_seed(seed)
    a = torch.rand(h, w, 3, generator=g, dtype=dtype)
    b = (a + 0.1 * torch.randn(h, w, 3, generator=g, dtype=dtype)).clamp(0, 1)
    return a, b


def test_psnr_of_known_mse():
    a = torch.zeros(8, 9, 3)
    assert psnr(a, a + 0.1).item() == pytest.approx(20.0, abs=1e-4)  # MSE 0.01
    assert math.isinf(psnr(a, a).item())
    batch = torch.stack([a + 0.1, a + 0.01])
    assert torch.allclose(psnr(torch.zeros_like(batch), batch), torch.tensor([20.0, 40.0]), atol=1e-3)
    assert mse(a, a + 0.5).item() == pytest.approx(0.25)


def test_quantize8():
    x = torch.tensor([-0.2, 0.0, 0.5 / 255, 0.7 / 255, 0.5, 1.3])
    q = quantize8(x)
    assert torch.equal(q * 255, torch.round(q * 255))
    assert q[0] == 0 and q[-1] == 1 and q[3] * 255 == 1


def test_ssim_identical_is_one_and_batches():
    a, b = _pair()
    assert ssim(a, a).item() == pytest.approx(1.0, abs=1e-12)
    s = ssim(a, b)
    assert s.dim() == 0 and 0 < s.item() < 1
    batch = ssim(torch.stack([a, a]), torch.stack([a, b]))
    assert batch.shape == (2,)
    assert batch[0].item() == pytest.approx(1.0) and batch[1].item() == pytest.approx(s.item(), abs=1e-12)


def _reference_ssim(a: np.ndarray, b: np.ndarray, valid: bool) -> float:
    """Straightforward SSIM with scipy's Gaussian filter: radius 5 taps, zeros outside the image."""
    blur = lambda x: gaussian_filter(x, sigma=1.5, truncate=5 / 1.5, mode="constant", cval=0.0)  # noqa: E731
    maps = []
    for c in range(a.shape[2]):
        x, y = a[..., c], b[..., c]
        mx, my = blur(x), blur(y)
        vx, vy, cxy = blur(x * x) - mx**2, blur(y * y) - my**2, blur(x * y) - mx * my
        m = ((2 * mx * my + 1e-4) * (2 * cxy + 9e-4)) / ((mx**2 + my**2 + 1e-4) * (vx + vy + 9e-4))
        maps.append(m[5:-5, 5:-5] if valid else m)
    return float(np.mean(maps))


@pytest.mark.parametrize("padding", ["same", "valid"])
def test_ssim_matches_independent_reference(padding):
    a, b = _pair(30, 26)
    ref = _reference_ssim(a.numpy(), b.numpy(), valid=padding == "valid")
    assert ssim(a, b, padding=padding).item() == pytest.approx(ref, abs=1e-6)
    # float32 agrees to float32 precision
    assert ssim(a.float(), b.float(), padding=padding).item() == pytest.approx(ref, abs=1e-5)


def test_ssim_gradcheck():
    a, b = _pair(7, 6)
    a.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: ssim(x, b), (a,), eps=1e-6, atol=1e-7)
    assert ssim_map(a, b).shape == (1, 3, 7, 6)


def test_metric_input_errors():
    a, b = _pair()
    with pytest.raises(InputError):
        psnr(a, b[:-1])
    with pytest.raises(InputError):
        ssim(a[..., 0], b[..., 0])
    with pytest.raises(InputError):
        ssim(a, b, padding="reflect")
    with pytest.raises(InputError):
        ssim(a[:8], b[:8], padding="valid")


def test_mean_psnr_quantises_each_pair_to_8_bits():
    a, b = _pair(dtype=torch.float32)
    want = (float(psnr(quantize8(a), quantize8(b))) + float(psnr(quantize8(b), quantize8(b + 0.01)))) / 2
    assert mean_psnr([a, b], [b, b + 0.01]) == pytest.approx(want)


def test_a_capped_mean_counts_identical_views_as_the_closest_a_difference_can_be():
    """The check's score (gspc/encoder/policy.py): a tile's check view may show none of it."""
    a = torch.zeros(3, 4, 5)
    b = a.clone()
    b[0, 0, 0] = 1 / 255
    assert mean_psnr([a], [a]) == math.inf
    assert mean_psnr([a], [a], capped=True) == pytest.approx(mean_psnr([a], [b]), abs=1e-5)
    assert math.isfinite(mean_psnr([a, a], [a, b], capped=True))
