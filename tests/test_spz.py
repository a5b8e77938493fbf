"""SPZ reader: real files from three writers (tests/data/spz, made by tools/make_spz_fixtures.py), the
writers' own decoding, and damaged files that must fail with one-line InputErrors."""

import gzip
import struct
from pathlib import Path

import numpy as np
import pytest
import torch
import zstandard
from typer.testing import CliRunner

from gspc.cli import app
from gspc.errors import InputError
from gspc.io import read_ply, read_scene, read_spz
from gspc.io.spz import decode_spz

DATA = Path(__file__).parent / "data" / "spz"
COLOUR_MAX = 0.5 / 0.15  # SPZ colour bytes span f_dc in [-3.33, 3.33]

# file -> (source PLY, version, worst SH error: half the bucket the writer rounded to, plus byte rounding).
# splat-transform and spz-js keep 5 bits of SH band 1 and 4 of the others (Niantic's defaults), gsply all 8.
FIXTURES = {
    "donut256.v2.spz": ("donut256.ply", 2, 0.0),
    "donut256.v3.spz": ("donut256.ply", 3, 0.0),
    "donut256.v4.spz": ("donut256.ply", 4, 0.0),
    "synth_sh3.v2.spz": ("synth_sh3.ply", 2, 2**-4 + 0.5 / 128),
    "synth_sh3.v3.spz": ("synth_sh3.ply", 3, 2**-4 + 0.5 / 128),
    "synth_sh3.v4.spz": ("synth_sh3.ply", 4, 2**-4 + 0.5 / 128),
    "synth_sh3.gsply.v3.spz": ("synth_sh3.ply", 3, 0.5 / 128),
    "synth_sh3.gsply.v4.spz": ("synth_sh3.ply", 4, 0.5 / 128),
}
EPS = 1e-6  # float32 rounding of decoded values


@pytest.mark.parametrize("name", list(FIXTURES))
def test_fixture_matches_its_source_within_spz_quantisation(name):
    source_name, version, sh_error = FIXTURES[name]
    source = read_ply(DATA / source_name)
    header, scene = decode_spz((DATA / name).read_bytes(), name)
    assert (header.version, header.num_points, header.sh_degree) == (
        version,
        source.num_gaussians,
        source.sh_degree,
    )
    assert scene.sh_degree == source.sh_degree and not header.antialiased
    step = 2.0**-header.fractional_bits
    assert header.fractional_bits == 12
    assert (scene.means - source.means).abs().max() <= step / 2 + EPS
    alpha_error = (torch.sigmoid(scene.opacities) - torch.sigmoid(source.opacities)).abs().max()
    assert alpha_error <= 0.5 / 255 + EPS  # bytes 0 and 255 read as alpha 1e-6 from the ends
    assert (scene.log_scales - source.log_scales.clamp(-10, 255 / 16 - 10)).abs().max() <= 1 / 32 + EPS
    dc_error = (scene.sh_dc - source.sh_dc.clamp(-COLOUR_MAX, COLOUR_MAX)).abs().max()
    assert dc_error <= 0.5 / (0.15 * 255) + EPS
    unit = source.quats / source.quats.norm(dim=1, keepdim=True)
    cosine = (unit * scene.quats).sum(1).abs()  # q and -q are one rotation
    # Version 2 keeps x, y, z in 8 bits and derives w; versions 3-4 keep 9 bits of the smallest three.
    assert cosine.min() >= (0.995 if version == 2 else 1 - 1e-5)
    # Version 2 leaves w at 0 where rounding put |(x, y, z)| past 1 (splat-transform reads it alike).
    np.testing.assert_allclose(scene.quats.norm(dim=1).numpy(), 1.0, atol=0.01 if version == 2 else 1e-6)
    if source.sh_degree:
        assert (scene.sh_rest - source.sh_rest).abs().max() <= sh_error + EPS


@pytest.mark.parametrize("name", [n for n in FIXTURES if "gsply" not in n])
def test_fixture_agrees_with_splat_transforms_own_decoding(name):
    ours = read_spz(DATA / name)
    theirs = read_ply(DATA / name.replace(".spz", ".st.ply"))
    for attr in ("means", "log_scales", "opacities", "sh_dc", "sh_rest", "quats"):
        torch.testing.assert_close(getattr(ours, attr), getattr(theirs, attr), atol=1e-6, rtol=0, msg=attr)


def test_read_scene_and_cli_accept_spz(tmp_path):
    spz = DATA / "synth_sh3.v4.spz"
    scene = read_scene(spz)
    runner = CliRunner()
    res = runner.invoke(app, ["convert", str(spz), "-o", str(tmp_path / "out.ply")])
    assert res.exit_code == 0, res.output
    assert torch.equal(read_ply(tmp_path / "out.ply").means, scene.means)
    res = runner.invoke(app, ["info", str(spz)])
    assert res.exit_code == 0 and "128" in res.output, res.output
    # Content decides, not the name: an SPZ called .ply still reads as SPZ.
    (tmp_path / "renamed.ply").write_bytes(spz.read_bytes())
    assert torch.equal(read_scene(tmp_path / "renamed.ply").means, scene.means)


# ---------------------------------------------------------------- hand-built files from the fixtures' bytes


def _legacy_parts() -> tuple[list, bytes]:
    """Header fields and attribute bytes of the SH-3 fixture (version 3, identical data to version 4)."""
    raw = gzip.decompress((DATA / "synth_sh3.v3.spz").read_bytes())
    return list(struct.unpack("<IIIBBBB", raw[:16])), raw[16:]


def _legacy(fields: list, body: bytes) -> bytes:
    return gzip.compress(struct.pack("<IIIBBBB", *fields) + body, mtime=0)


def _blocks(body: bytes, n: int = 128, rotation: int = 4, k: int = 15) -> list[bytes]:
    sizes = [9 * n, n, 3 * n, 3 * n, rotation * n, 3 * k * n]
    out, at = [], 0
    for size in sizes:
        out.append(body[at : at + size])
        at += size
    return out


def _v4(
    blocks: list[bytes],
    *,
    count: int = 128,
    degree: int = 3,
    flags: int = 0,
    version: int = 4,
    extensions: bytes = b"",
    sizes: list[int] | None = None,
) -> bytes:
    frames = [zstandard.ZstdCompressor().compress(b) for b in blocks]
    toc = 32 + len(extensions)
    head = struct.pack("<IIIBBBBI12x", 0x5053474E, version, count, degree, 12, flags, len(blocks), toc)
    sizes = sizes or [len(b) for b in blocks]
    table = b"".join(struct.pack("<QQ", len(f), s) for f, s in zip(frames, sizes))
    return head + extensions + table + b"".join(frames)


def _decode(data: bytes):
    return decode_spz(data, "f.spz")


def test_hand_built_v4_and_legacy_match_the_fixtures():
    fields, body = _legacy_parts()
    reference = read_spz(DATA / "synth_sh3.v4.spz")
    header, scene = _decode(_v4(_blocks(body)))
    assert torch.equal(scene.means, reference.means) and torch.equal(scene.quats, reference.quats)
    fields[5] = 1  # antialiased flag
    header, scene = _decode(_legacy(fields, body))
    assert header.antialiased and torch.equal(scene.sh_rest, reference.sh_rest)


def test_extension_records_are_skipped_or_refused():
    fields, body = _legacy_parts()
    unknown = struct.pack("<II", 0x12340001, 5) + b"hello"
    _, scene = _decode(_v4(_blocks(body), flags=2, extensions=unknown))
    assert scene.num_gaussians == 128
    fields[5] = 2  # versions 2-3: records follow the attribute blocks (Niantic's load-spz.cc)
    _, scene = _decode(_legacy(fields, body + unknown))
    assert scene.num_gaussians == 128
    quantised = struct.pack("<II", 0xADBE0001, 10) + bytes(10)
    with pytest.raises(InputError, match="SH-quantisation extension 0xADBE0001"):
        _decode(_v4(_blocks(body), flags=2, extensions=quantised))
    with pytest.raises(InputError, match="runs past the extension block"):
        _decode(_v4(_blocks(body), flags=2, extensions=struct.pack("<II", 0x12340001, 99) + b"x"))
    fields[5] = 0  # extension bytes without the flag: more data than the header implies
    with pytest.raises(InputError, match="holds more than the 8,320 bytes the header implies"):
        _decode(_legacy(fields, body + unknown))


@pytest.mark.parametrize("cut", [3, 31, 40, 200, -1])
def test_truncated_v4(cut):
    data = (DATA / "synth_sh3.v4.spz").read_bytes()
    with pytest.raises(InputError, match="truncated|table of contents|stream"):
        _decode(data[:cut])


@pytest.mark.parametrize("cut", [2, 12, 100, -9, -1])
def test_truncated_gzip(cut):
    data = (DATA / "synth_sh3.v3.spz").read_bytes()
    with pytest.raises(InputError, match="truncated|corrupt gzip|not an SPZ"):
        _decode(data[:cut])


def test_bad_magic_and_versions():
    fields, body = _legacy_parts()
    with pytest.raises(InputError, match="not an SPZ file \\(magic 0x12345678"):
        _decode(_legacy([0x12345678, *fields[1:]], body))
    with pytest.raises(InputError, match="not an SPZ file \\(neither gzip nor an NGSP header\\)"):
        _decode(b"PLYX" + bytes(60))
    with pytest.raises(InputError, match="file is empty"):
        _decode(b"")
    for version in (1, 5):
        with pytest.raises(InputError, match=f"SPZ version {version} is not supported"):
            _decode(_legacy([fields[0], version, *fields[2:]], body))
    with pytest.raises(InputError, match="SPZ version 4 inside gzip"):
        _decode(_legacy([fields[0], 4, *fields[2:]], body))
    with pytest.raises(InputError, match="SPZ version 7 is not supported"):
        _decode(_v4(_blocks(body), version=7))
    with pytest.raises(InputError, match="version 3 with a plain header"):
        _decode(_v4(_blocks(body), version=3))


def test_sh_degrees_outside_gspc_or_the_format():
    fields, body = _legacy_parts()
    with pytest.raises(InputError, match="SH degree 4 is not supported"):
        _decode(_legacy([*fields[:3], 4, *fields[4:]], body))
    with pytest.raises(InputError, match="declares SH degree 9"):
        _decode(_legacy([*fields[:3], 9, *fields[4:]], body))
    with pytest.raises(InputError, match="25 fractional position bits"):
        _decode(_legacy([*fields[:4], 25, *fields[5:]], body))


@pytest.mark.parametrize("count", [129, 10_000_000, 2**32 - 1])
def test_declared_count_beyond_the_data(count):
    fields, body = _legacy_parts()
    with pytest.raises(InputError, match="more than a .*-byte SPZ file can hold|truncated SPZ data"):
        _decode(_legacy([fields[0], fields[1], count, *fields[3:]], body))
    with pytest.raises(InputError, match="more than a .*-byte SPZ file can hold|stream holds"):
        _decode(_v4(_blocks(body), count=count))


def test_zero_gaussians():
    fields, _ = _legacy_parts()
    with pytest.raises(InputError, match="zero Gaussians"):
        _decode(_legacy([fields[0], fields[1], 0, *fields[3:]], b""))


def test_decompression_is_capped_at_what_the_header_implies():
    """Zip bombs: 64 MB of zeros behind a 128-Gaussian header fail after reading one byte too many."""
    fields, body = _legacy_parts()
    bomb = gzip.compress(struct.pack("<IIIBBBB", *fields) + body + bytes(64 << 20), mtime=0, compresslevel=9)
    assert len(bomb) < 100_000
    with pytest.raises(InputError, match="holds more than the 8,320 bytes"):
        _decode(bomb)
    blocks = _blocks(body)
    blocks[0] = bytes(64 << 20)  # the positions stream inflates far past the size its TOC entry declares
    with pytest.raises(InputError, match="positions stream decompresses to"):
        _decode(_v4(blocks, sizes=[9 * 128, *[len(b) for b in blocks[1:]]]))


def test_v4_layout_errors():
    _, body = _legacy_parts()
    good = _v4(_blocks(body))
    with pytest.raises(InputError, match="bytes after the last SPZ stream"):
        _decode(good + b"\0")
    with pytest.raises(InputError, match="lists 5 streams, expected 6"):
        _decode(_v4(_blocks(body)[:5]))
    broken = bytearray(good)
    broken[32 + 6 * 16 + 8] ^= 0xFF  # inside the first zstd frame
    with pytest.raises(InputError, match="corrupt zstd stream|decompresses to"):
        _decode(bytes(broken))


def test_v4_may_list_the_empty_sh_stream():
    raw = gzip.decompress((DATA / "donut256.v3.spz").read_bytes())[16:]
    blocks = _blocks(raw, n=256, k=0)
    reference = read_spz(DATA / "donut256.v4.spz")
    for listed in (blocks[:5], blocks):  # degree 0: five streams, or six with an empty SH stream
        _, scene = _decode(_v4(listed, count=256, degree=0))
        assert torch.equal(scene.sh_dc, reference.sh_dc) and scene.sh_rest.shape == (256, 0, 3)


def test_read_spz_names_the_file(tmp_path):
    (tmp_path / "bad.spz").write_bytes(b"\x1f\x8bnot really gzip")
    with pytest.raises(InputError, match="bad.spz: corrupt gzip|bad.spz: truncated"):
        read_scene(tmp_path / "bad.spz")
    (tmp_path / "text.spz").write_bytes(b"hello")
    with pytest.raises(InputError, match="text.spz: not an SPZ file"):
        read_scene(tmp_path / "text.spz")
