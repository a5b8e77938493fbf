"""Rate control (gspc/encoder/rate.py): the lambda that codes a scene in a number of bytes."""

import numpy as np
import pytest
from scenes import varied_scene as _scene

from gspc.encoder.coding import encode_attributes
from gspc.encoder.params import CodecParams
from gspc.encoder.rate import search_lambda
from gspc.errors import ValueRangeError
from gspc.presets import QUALITY


def test_search_lambda_hits_target():
    scene = _scene(n=3000, degree=1)
    full = encode_attributes(scene, QUALITY["high"].attributes).num_bytes
    target = int(full * 0.6)
    enc = search_lambda(scene, target, QUALITY["high"].attributes, rel_tol=0.05)
    assert 0.95 * target <= enc.num_bytes <= target


@pytest.mark.parametrize("share", [0.7, 0.9, 1.3])
def test_search_lambda_needs_few_encodes(monkeypatch, share):
    """Each try is a whole encode (half a minute at a million Gaussians): secant steps reach the window in a
    few, where bisection from the full lambda range took up to 12 (bird fit, 0.5% windows: 3-7 against
    7-11)."""
    import gspc.encoder.rate as rate

    scene = _scene(n=3000, degree=1)
    params = QUALITY["low"].attributes
    first = encode_attributes(scene, params)
    target = int(first.num_bytes * share)
    calls = []
    real = rate.encode_attributes
    monkeypatch.setattr(rate, "encode_attributes", lambda *a, **k: calls.append(1) or real(*a, **k))
    enc = search_lambda(scene, target, params, rel_tol=0.02, first=first)
    assert 0.98 * target <= enc.num_bytes <= target
    assert len(calls) <= 6


def test_search_lambda_stops_where_the_sizes_jump_over_the_window(monkeypatch):
    """Sizes may jump with lambda (a threshold of the precision plan crossed by many Gaussians at once): a
    window inside the jump has no lambda, and the search stops once the lambdas around it are too close
    instead of spending every try (a whole encode each) on it."""
    from types import SimpleNamespace

    import gspc.encoder.rate as rate

    jump = 2.0**1.5
    calls = []

    def sizes_with_a_jump(scene, params, *a, **k):
        calls.append(params.lam)
        size = 100_000 * params.lam**-0.5 * (1.03 if params.lam < jump else 1.0)
        return SimpleNamespace(num_bytes=int(size), lam=params.lam)

    monkeypatch.setattr(rate, "encode_attributes", sizes_with_a_jump)
    above = 100_000 * jump**-0.5 * 1.03
    below = 100_000 * jump**-0.5
    target = int(below + 0.6 * (above - below))
    enc = search_lambda(None, target, QUALITY["low"].attributes, rel_tol=0.005)
    assert enc.num_bytes <= target and len(calls) <= 10  # 12 (every try) before it stopped
    assert jump <= enc.lam < jump * 1.01


def test_search_lambda_starts_no_encode_past_its_deadline(monkeypatch):
    from types import SimpleNamespace

    import gspc.encoder.rate as rate

    calls = []

    def sizes(scene, params, *a, **k):
        calls.append(params.lam)
        return SimpleNamespace(num_bytes=int(100_000 * params.lam**-0.5), lam=params.lam)

    monkeypatch.setattr(rate, "encode_attributes", sizes)
    params = QUALITY["low"].attributes
    search_lambda(None, 1_000, params, rel_tol=0.005)
    assert len(calls) > 3
    calls.clear()
    enc = search_lambda(None, 1_000, params, rel_tol=0.005, deadline=0.0)  # long past
    assert len(calls) == 1 and enc.lam == pytest.approx(params.lam)


def test_search_lambda_backs_off_where_removal_takes_every_gaussian(monkeypatch):
    """At a coarse enough lambda the precision plan removes every Gaussian: the search treats it as too
    coarse (a tiny scene's check rival hit it) instead of failing the encode."""
    import gspc.encoder.rate as rate
    from gspc.errors import NothingCodedError

    scene = _scene(n=300, degree=1)
    real = rate.encode_attributes

    def coarse_removes_all(scene, params, *a, **k):
        if params.lam > 20:
            raise NothingCodedError("every Gaussian was pruned")
        return real(scene, params, *a, **k)

    monkeypatch.setattr(rate, "encode_attributes", coarse_removes_all)
    enc = search_lambda(scene, 10, QUALITY["low"].attributes)  # no lambda reaches 10 bytes
    assert enc.lam <= 20 and enc.num_bytes > 10


def test_search_lambda_steps_over_lambdas_too_fine_for_the_scene():
    # A DC value of 100 is beyond what lambda 1e-3 can code: a search asked for more bytes than any lambda
    # gives moves up from there instead of failing.
    params = CodecParams(lam=8.0)
    scene = _scene(n=300, opacities=np.full(300, 5.0))
    scene.sh_dc[3, 0] = 100.0
    with pytest.raises(ValueRangeError):
        encode_attributes(scene, params.with_lambda(1e-3))
    enc = search_lambda(scene, 10**9, params)
    assert enc.lam > 1e-3 and abs(float(enc.decoded.sh_dc.abs().max()) - 100.0) < 1.0


def test_search_lambda_keeps_its_best_coding_where_its_last_is_too_fine(monkeypatch):
    """A search whose last coding is too fine for the scene returns the best it has (a codebook trial in the
    preset's bytes on the glossy scene reached one) instead of failing the encode; with none, it raises."""
    import gspc.encoder.rate as rate

    scene = _scene(n=300, degree=1)
    real = rate.encode_attributes
    first = real(scene, QUALITY["low"].attributes.with_lambda(8.0))

    def fine_out_of_range(scene, params, *a, **k):
        if params.lam < 6:
            raise ValueRangeError("too fine")
        return real(scene, params, *a, **k)

    monkeypatch.setattr(rate, "encode_attributes", fine_out_of_range)
    enc = search_lambda(scene, 10 * first.num_bytes, QUALITY["low"].attributes, max_iter=3)
    assert 6 <= enc.lam and enc.num_bytes <= 10 * first.num_bytes
    monkeypatch.setattr(
        rate, "encode_attributes", lambda *a, **k: fine_out_of_range(None, CodecParams(lam=1))
    )
    with pytest.raises(ValueRangeError):
        search_lambda(scene, 10 * first.num_bytes, QUALITY["low"].attributes, max_iter=3)
