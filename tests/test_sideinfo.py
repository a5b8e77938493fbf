"""The SIDE chunk (spec 10.9): round trips, both camera layouts, and bad payloads as CodecError."""

import struct
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gspc.cameras import Camera
from gspc.errors import CodecError
from gspc.format.side_chunk import pack_side, unpack_side
from gspc.format.view_records import CameraRecord, ResidualRecord, ViewRecord


def camera(k: int, w: int = 40, h: int = 30, f: float = 35.0) -> CameraRecord:
    rot = np.linalg.qr(np.random.default_rng(k).normal(size=(3, 3)))[0]
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = rot, [0.1 * k, -0.2, 3.0]
    K = np.array([[f, 0, w / 2], [0, f * 1.01, h / 2], [0, 0, 1]])
    return CameraRecord.from_camera(Camera(w2c, K, w, h, f"v{k}"))


def residual(w=40, h=30, scale=1, bits=8, gain=123.25, codec="jxl") -> ResidualRecord:
    return ResidualRecord(codec, bits, gain, (h, w), scale)


def view(k: int, w: int = 40, h: int = 30, f: float = 35.0, res: ResidualRecord | None = None) -> ViewRecord:
    return ViewRecord(camera(k, w, h, f), res)


def same(a, b) -> None:
    """Equal views but for the camera names, which a SIDE chunk does not store."""
    assert [replace(v, camera=replace(v.camera, name="")) for v in a] == list(b)


@pytest.mark.parametrize("scale", [1, 2, 3])
def test_round_trip_shared_camera(scale):
    views = [view(k, res=residual(scale=scale, gain=10.0 + k) if k != 1 else None) for k in range(4)]
    images = {0: b"abc", 2: b"q", 3: b"xyz1"}
    payload = pack_side(views, images)
    # head 8 + shared camera 24 + 4 views x (48 + 4) + 3 gains + 8 image bytes
    assert len(payload) == 8 + 24 + 4 * 52 + 3 * 4 + 8
    got = unpack_side(payload)
    same(views, got.views)
    assert got.images == images
    assert (
        got.views[1].camera.to_camera().world_to_cam.tolist()
        == views[1].camera.to_camera().world_to_cam.tolist()
    )


def test_round_trip_per_view_cameras_and_16_bits():
    views = [
        view(0, 40, 30, res=residual(40, 30, bits=16)),
        view(1, 64, 48, f=50.0, res=residual(64, 48, bits=16)),
        view(2, 64, 48, f=50.0),
    ]
    images = {0: b"a" * 7, 1: b"b" * 3}
    payload = pack_side(views, images)
    assert payload[4] == 1  # per-view cameras
    got = unpack_side(payload)
    same(views, got.views)
    assert got.images == images


def test_encoder_side_mismatches_are_bugs():
    views = [view(0, res=residual()), view(1, res=residual(codec="webp"))]
    with pytest.raises(ValueError, match="share"):
        pack_side(views, {0: b"a", 1: b"b"})
    with pytest.raises(ValueError, match="image"):
        pack_side(views[:1], {})
    with pytest.raises(ValueError, match="empty"):
        pack_side(views[:1], {0: b""})
    with pytest.raises(CodecError, match="cover"):  # a record that does not fit its camera is no record
        view(0, res=residual(w=20))


def good_payload() -> bytes:
    return pack_side([view(0, res=residual()), view(1)], {0: b"image"})


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
        (lambda p: p[:8] + struct.pack("<I", 0) + p[12:], "camera width 0"),
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
    side = unpack_side(c.find("SIDE", 0).payload)
    views = side.views
    assert len(views) == 2 and side.images == {1: b"image"} and views[0].residual is None
    r = views[1].residual
    assert (r.codec, r.bits, r.offset, r.gain) == ("jxl", 8, 128, 64.0)
    assert (r.shape, r.full_shape, r.scale) == ((24, 32), (48, 64), 2)
    cam = views[1].camera.to_camera()
    assert (cam.width, cam.height) == (64, 48) and cam.world_to_cam[0, 3] == np.float32(0.1)


def test_legacy_records_are_checked_once_where_read():
    """The 1.0 layout's maps (spec 10.7, 10.8) read to the same typed records, each field checked there."""
    good = view(0, res=residual(scale=2)).to_dict()
    assert ViewRecord.from_dict(good) == view(0, res=residual(scale=2))
    for change, message in (
        ({"gain": 0.0}, "gain"),
        ({"gain": 2}, "gain"),  # a binary32 value is a msgpack float
        ({"offset": 127}, "offset"),
        ({"codec": "png"}, "codec"),
        ({"scale": 17}, "scale"),
        ({"shape": [16, 20]}, "cover"),
        ({"full_shape": [30, 41]}, "cover"),
        ({"bits": True}, "bits"),
    ):
        with pytest.raises(CodecError, match=message):
            ViewRecord.from_dict({**good, "residual": {**good["residual"], **change}})
    for change, message in (({"width": 0}, "width"), ({"pose": b"x"}, "pose"), ({"height": 1.5}, "height")):
        with pytest.raises(CodecError, match=message):
            ViewRecord.from_dict({**good, "camera": {**good["camera"], **change}})
    with pytest.raises(CodecError, match="lacks 'gain'"):
        ViewRecord.from_dict({**good, "residual": {k: v for k, v in good["residual"].items() if k != "gain"}})
