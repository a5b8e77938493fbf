"""Quantisation cells: the original lies in them, the decoded scene is their centre, clamp_into stays put."""

import pytest
import torch
from scenes import front_cameras as _cameras
from scenes import front_scene as _scene
from scenes import random_scene

from gspc.codec.cells import clamp_into, quantisation_cells
from gspc.encoder.coding import encode_attributes
from gspc.encoder.params import CodecParams
from gspc.errors import CodecError
from gspc.format.attribute_section import AttributeSection
from gspc.refine import Schedule, refine


def _inside(name, value, box, tol=1e-5):
    lo, hi = box
    v = value / value.norm(dim=1, keepdim=True) if name == "quats" else value
    ok = (v >= lo - tol) & (v <= hi + tol)
    if name == "quats":  # q and -q are one rotation
        ok = ok | ((-v >= lo - tol) & (-v <= hi + tol))
    return ok.reshape(len(v), -1).all(1)


@pytest.mark.parametrize("lam", [1.0, 8.0, 64.0])
def test_original_and_decoded_lie_in_their_cells(lam):
    scene = random_scene(
        300, sh_degree=2, seed=3, log_scale=-2.8, opacity_logit=1.0, dc_std=0.6, rest_std=0.2
    )
    enc = encode_attributes(scene, CodecParams(lam=lam))
    cells = quantisation_cells(enc.decoded, enc.section)
    kept = torch.from_numpy(enc.kept)
    assert set(cells) == {"means", "quats", "log_scales", "opacities", "sh_dc", "sh_rest"}
    for name, box in cells.items():
        decoded = getattr(enc.decoded, name)
        assert box[0].shape == decoded.shape and box[0].dtype == decoded.dtype
        assert _inside(name, decoded, box).all(), name
        # Rotations whose two largest components nearly tie may fall just outside (rare, bounded).
        frac = float(_inside(name, getattr(scene, name)[kept].float(), box).float().mean())
        assert frac >= (0.99 if name == "quats" else 1.0), (name, frac)


def test_projection_moves_only_what_is_outside():
    box = (torch.tensor([[0.0, -1.0]]), torch.tensor([[1.0, 1.0]]))
    v = torch.tensor([[2.0, 0.5]])
    clamp_into("means", v, box)
    assert v.tolist() == [[1.0, 0.5]]
    q = torch.tensor([[-2.0, 0.0, 0.0, 0.0]])  # -(1, 0, 0, 0) at twice the length: the box's rotation
    clamp_into("quats", q, (torch.tensor([[0.9, -0.1, -0.1, -0.1]]), torch.tensor([[1.0, 0.1, 0.1, 0.1]])))
    assert q.tolist() == [[1.0, 0.0, 0.0, 0.0]]


@pytest.mark.slow
def test_refinement_stays_in_cells():
    from gspc.render import render

    cams = _cameras()
    original = _scene(seed=2)
    with torch.no_grad():
        targets = [render(original, c).image for c in cams]
    enc = encode_attributes(original, CodecParams(lam=16.0, keep_invisible=True))
    cells = quantisation_cells(enc.decoded, enc.section)
    out = refine(enc.decoded, cams, [t + 0.05 for t in targets], Schedule(20), cells=cells).scene
    free = refine(enc.decoded, cams, [t + 0.05 for t in targets], Schedule(20)).scene
    for name, box in cells.items():
        assert _inside(name, getattr(out, name), box).all(), name
    assert not all(_inside(n, getattr(free, n), b).all() for n, b in cells.items())


def test_cells_need_a_checked_section():
    """The cells read a typed section; a malformed header never becomes one (gspc/format/)."""
    enc = encode_attributes(_scene(), CodecParams(lam=8.0, keep_invisible=True))
    with pytest.raises(CodecError, match="scale_step"):
        AttributeSection.from_dict({**enc.section.to_dict(), "scale_step": "x"})


def test_cells_in_blocks_equal_cells_at_once(monkeypatch):
    """Blocks only bound memory: a scene with a far set (per-row position cells) gets the same boxes."""
    from scenes import far_scene

    import gspc.codec.cells as cells_module
    from gspc.presets import QUALITY

    enc = encode_attributes(far_scene(), QUALITY["low"].attributes)
    assert enc.section.position.far is not None
    whole = quantisation_cells(enc.decoded, enc.section)
    monkeypatch.setattr(cells_module, "CELL_BLOCK", 7)
    blocks = quantisation_cells(enc.decoded, enc.section)
    for name, (lo, hi) in whole.items():
        assert torch.equal(lo, blocks[name][0]) and torch.equal(hi, blocks[name][1]), name
