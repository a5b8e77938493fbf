"""The SIDE chunk (spec 10.9): round trips, both camera layouts, and bad payloads as CodecError."""

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gspc.cameras import Camera
from gspc.codec.sideinfo import pack_side, unpack_side
from gspc.errors import CodecError


def camera(k: int, w: int = 40, h: int = 30, f: float = 35.0) -> dict:
    rot = np.linalg.qr(np.random.default_rng(k).normal(size=(3, 3)))[0]
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = rot, [0.1 * k, -0.2, 3.0]
    K = np.array([[f, 0, w / 2], [0, f * 1.01, h / 2], [0, 0, 1]])
    return Camera(w2c, K, w, h, f"v{k}").to_dict()


def residual_meta(w=40, h=30, scale=1, bits=8, gain=123.25) -> dict:
    m = {"codec": "jxl", "shape": [-(-h // scale), -(-w // scale)], "bits": bits, "gain": gain}
    m["offset"] = 1 << (bits - 1)
    if scale != 1:
        m.update(scale=scale, full_shape=[h, w])
    return m


def same(a: list[dict], b: list[dict]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        cx, cy = dict(x["camera"]), dict(y["camera"])
        cx.pop("name"), cy.pop("name")  # names are not stored
        assert cx == cy and x.get("residual") == y.get("residual")


@pytest.mark.parametrize("scale", [1, 2, 3])
def test_round_trip_shared_camera(scale):
    views = [{"camera": camera(k)} for k in range(4)]
    for k in (0, 2, 3):
        views[k]["residual"] = residual_meta(scale=scale, gain=10.0 + k)
    images = {0: b"abc", 2: b"q", 3: b"xyz1"}
    payload = pack_side(views, images)
    # head 8 + shared camera 24 + 4 views x (48 + 4) + 3 gains + 8 image bytes
    assert len(payload) == 8 + 24 + 4 * 52 + 3 * 4 + 8
    got, got_images = unpack_side(payload)
    same(views, got)
    assert got_images == images
    assert (
        Camera.from_dict(got[1]["camera"]).world_to_cam.tolist()
        == Camera.from_dict(views[1]["camera"]).world_to_cam.tolist()
    )


def test_round_trip_per_view_cameras_and_16_bits():
    views = [
        {"camera": camera(0, 40, 30), "residual": residual_meta(40, 30, bits=16)},
        {"camera": camera(1, 64, 48, f=50.0), "residual": residual_meta(64, 48, bits=16)},
        {"camera": camera(2, 64, 48, f=50.0)},
    ]
    images = {0: b"a" * 7, 1: b"b" * 3}
    payload = pack_side(views, images)
    assert payload[4] == 1  # per-view cameras
    got, got_images = unpack_side(payload)
    same(views, got)
    assert got_images == images


def test_encoder_side_mismatches_are_bugs():
    views = [
        {"camera": camera(0), "residual": residual_meta()},
        {"camera": camera(1), "residual": residual_meta()},
    ]
    views[1]["residual"]["codec"] = "webp"
    with pytest.raises(ValueError, match="share"):
        pack_side(views, {0: b"a", 1: b"b"})
    with pytest.raises(ValueError, match="image"):
        pack_side(views[:1], {})
    with pytest.raises(ValueError, match="empty"):
        pack_side(views[:1], {0: b""})
    with pytest.raises(ValueError, match="whole image"):
        pack_side([{"camera": camera(0), "residual": residual_meta(w=20)}], {0: b"a"})


def good_payload() -> bytes:
    views = [{"camera": camera(0), "residual": residual_meta()}, {"camera": camera(1)}]
    return pack_side(views, {0: b"image"})


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda p: p[:-1], "need 5 bytes"),
        (lambda p: p + b"!", "need 5 bytes"),
        (lambda p: p[:20], "truncated"),
        (lambda p: struct.pack("<I", 0) + p[4:], "0 views"),
        (lambda p: p[:4] + b"\x02" + p[5:], "flags"),
        (lambda p: p[:5] + b"\x07" + p[6:], "codec 7"),
        (lambda p: p[:6] + b"\x0c" + p[7:], "12 bits"),
        (lambda p: p[:7] + b"\x00" + p[8:], "scale 0"),
        (lambda p: p[:8] + struct.pack("<I", 0) + p[12:], "0x30 camera"),
        (lambda p: p[:16] + struct.pack("<f", float("nan")) + p[20:], "NaN"),
    ],
)
def test_bad_payloads(mutate, message):
    with pytest.raises(CodecError, match=message):
        unpack_side(mutate(good_payload()))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 200))
def test_random_bytes_only_raise_codec_error(noise, cut):
    data = good_payload()
    for blob in (noise, data[:cut] + noise, data[: min(cut, len(data))]):
        try:
            unpack_side(blob)
        except CodecError:
            pass


def test_conformance_vector_payload():
    """spec/vectors/valid_chunk_SIDE.gspc: the SIDE payload decodes to the two views 10.9 describes."""
    from pathlib import Path

    from gspc.format import container

    c = container.read(Path(__file__).parents[1] / "spec" / "vectors" / "valid_chunk_SIDE.gspc")
    assert c.version == (1, 1)
    views, images = unpack_side(c.find("SIDE", 0).payload)
    assert len(views) == 2 and images == {1: b"image"} and "residual" not in views[0]
    r = views[1]["residual"]
    assert (r["codec"], r["bits"], r["offset"], r["gain"]) == ("jxl", 8, 128, 64.0)
    assert (r["shape"], r["full_shape"], r["scale"]) == ([24, 32], [48, 64], 2)
    cam = Camera.from_dict(views[1]["camera"])
    assert (cam.width, cam.height) == (64, 48) and cam.world_to_cam[0, 3] == np.float32(0.1)
