import json

import pytest
import torch

from gspc.errors import CodecError, InputError
from gspc.restore.nafnet import NAFNet, count_parameters, pad_to_multiple
from gspc.restore.restorer import load_restorer, save_restorer

SMALL = {"width": 8, "enc_blocks": [1, 1], "middle_blocks": 1, "dec_blocks": [1, 1]}


def _randomised(config=SMALL, seed=0, std=0.1):
    """A small NAFNet whose zero-initialised scales and final conv are made non-zero."""
    torch.manual_seed(seed)
    net = NAFNet(**config)
    with torch.no_grad():
        for name, p in net.named_parameters():
            if name.endswith(("beta", "gamma")) or name.startswith("ending"):
                p.normal_(0, std)
    return net


def _pair(h, w, seed=1):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(h, w, 3, generator=g), 0.05 * torch.randn(h, w, 3, generator=g)


def test_untrained_net_is_side_information_only():
    net = NAFNet(**SMALL)
    x = torch.randn(2, 6, 21, 30)
    assert torch.equal(net(x), x[:, 3:6])
    plain = NAFNet(**SMALL, predict_correction=False)
    assert torch.equal(plain(x), torch.zeros(2, 3, 21, 30))


def test_shapes_with_padding_and_gradients():
    net = _randomised()
    x = torch.randn(1, 6, 13, 17, requires_grad=True)
    y = net(x)
    assert y.shape == (1, 3, 13, 17)
    y.square().mean().backward()
    assert x.grad is not None and torch.isfinite(x.grad).all()
    assert pad_to_multiple(torch.zeros(1, 1, 13, 17), 4).shape == (1, 1, 16, 20)
    assert count_parameters(net) > 0


def test_training_step_moves_off_identity():
    net = NAFNet(**SMALL)
    x = torch.randn(1, 6, 16, 16)
    target = torch.randn(1, 3, 16, 16)
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    before = (net(x) - target).abs().mean()
    for _ in range(3):
        opt.zero_grad()
        (net(x) - target).abs().mean().backward()
        opt.step()
    assert (net(x) - target).abs().mean() < before


def test_none_restorer_adds_residual():
    d, r = _pair(10, 12)
    assert torch.equal(load_restorer("none").restore(d, r), d + r)


def test_save_load_round_trip_and_determinism(tmp_path):
    net = _randomised()
    save_restorer(net, SMALL, "tiny", tmp_path)
    restorer = load_restorer("tiny", weights_dir=tmp_path)
    d, r = _pair(24, 20)
    out = restorer.restore(d, r)
    with torch.no_grad():
        expected = d + net(torch.cat([d, r], -1).permute(2, 0, 1)[None])[0].permute(1, 2, 0)
    assert torch.equal(out, expected)
    assert torch.equal(out, restorer.restore(d, r))


def test_tiled_matches_untiled(tmp_path):
    save_restorer(_randomised(), SMALL, "tiny", tmp_path)
    d, r = _pair(150, 131)
    full = load_restorer("tiny", tmp_path, tile=4096).restore(d, r)
    tiled = load_restorer("tiny", tmp_path, tile=96, overlap=32).restore(d, r)
    correction = (full - d - r).abs().mean()
    diff = (tiled - full).abs()
    # Differences come only from tile borders and per-tile channel-attention means.
    assert diff.mean() < 0.01 * correction
    assert diff.max() < 0.2 * correction


def test_missing_or_altered_weights_raise_codec_error(tmp_path):
    with pytest.raises(CodecError, match="tiny"):
        load_restorer("tiny", weights_dir=tmp_path)  # no manifest
    path = save_restorer(NAFNet(**SMALL), SMALL, "tiny", tmp_path)
    with pytest.raises(CodecError, match="other"):
        load_restorer("other", weights_dir=tmp_path)
    data = bytearray(path.read_bytes())
    data[-10] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(CodecError, match="SHA-256"):
        load_restorer("tiny", weights_dir=tmp_path)
    path.unlink()
    with pytest.raises(CodecError, match="missing"):
        load_restorer("tiny", weights_dir=tmp_path)


def test_config_mismatch_raises_codec_error(tmp_path):
    save_restorer(NAFNet(**SMALL), SMALL, "tiny", tmp_path)
    manifest = json.loads((tmp_path / "MANIFEST.json").read_text())
    manifest["tiny"]["config"]["width"] = 12
    (tmp_path / "MANIFEST.json").write_text(json.dumps(manifest))
    with pytest.raises(CodecError, match="do not load"):
        load_restorer("tiny", weights_dir=tmp_path)


def test_restore_rejects_mismatched_inputs():
    with pytest.raises(InputError):
        load_restorer("none").restore(torch.zeros(4, 4, 3), torch.zeros(4, 5, 3))


def test_restorer_registry_names_the_architecture(tmp_path):
    import json

    import pytest

    from gspc.errors import CodecError
    from gspc.restore.architectures import ARCHITECTURES
    from gspc.restore.nafnet import NAFNet
    from gspc.restore.restorer import load_restorer, save_restorer

    config = {"width": 8, "enc_blocks": [1], "dec_blocks": [1], "middle_blocks": 1}
    save_restorer(NAFNet(**config), config, "tiny", tmp_path)
    manifest = json.loads((tmp_path / "MANIFEST.json").read_text())
    assert manifest["tiny"]["architecture"] == "nafnet" and "nafnet" in ARCHITECTURES
    assert load_restorer("tiny", tmp_path).model is not None
    manifest["tiny"]["architecture"] = "unet-9000"
    (tmp_path / "MANIFEST.json").write_text(json.dumps(manifest))
    with pytest.raises(CodecError, match="unet-9000"):
        load_restorer("tiny", tmp_path)
