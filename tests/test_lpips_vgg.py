"""tools/lpips_vgg.py: the restorer's training loss, with weights only from disk."""

import pytest
import torch
from lpips_vgg import LPIPS, LPIPS_ENV, lpips

from gspc.errors import GspcError, InputError


def _pair(h=24, w=20, dtype=torch.float32):
    g = torch.Generator().manual_seed(0)
    a = torch.rand(h, w, 3, generator=g, dtype=dtype)
    return a, (a + 0.1 * torch.randn(h, w, 3, generator=g, dtype=dtype)).clamp(0, 1)


def test_lpips_needs_weights(monkeypatch, tmp_path):
    monkeypatch.delenv(LPIPS_ENV, raising=False)
    a, _ = _pair(dtype=torch.float32)
    with pytest.raises(GspcError, match="weights on disk"):
        lpips(a, a)
    with pytest.raises(InputError):
        lpips(a, a, tmp_path / "absent.pth")
    monkeypatch.setenv(LPIPS_ENV, str(tmp_path / "absent.pth"))
    with pytest.raises(InputError):
        lpips(a, a)


@pytest.mark.slow
def test_lpips_random_weights_smoke(monkeypatch, tmp_path):
    torch.manual_seed(0)
    model = LPIPS()
    sd = model.state_dict()
    # Split as the weights come in practice: torchvision's backbone file and lpips' linear layers.
    torch.save({k: v for k, v in sd.items() if k.startswith("features.")}, tmp_path / "vgg16.pth")
    torch.save({k: v for k, v in sd.items() if k.startswith("lin")}, tmp_path / "lin.pth")
    a, b = _pair(32, 36, dtype=torch.float32)
    d = lpips(a, b, tmp_path)
    assert d.dim() == 0 and torch.isfinite(d) and d.item() == pytest.approx(model(a, b).item(), rel=1e-5)
    assert lpips(a, a, tmp_path).item() == 0.0
    monkeypatch.setenv(LPIPS_ENV, str(tmp_path))
    batch = lpips(torch.stack([a, a]), torch.stack([b, a]))
    assert batch.shape == (2,) and batch[1].item() == 0.0
    # a file with only part of the weights names what is missing
    with pytest.raises(InputError, match="lack"):
        lpips(a, b, tmp_path / "lin.pth")
