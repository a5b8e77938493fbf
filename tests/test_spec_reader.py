"""tests/spec_reader.py (a decoder written from spec/gspc-format.md alone) against gspc's decoder.

The range decoder and the probability tables of spec section 10.0 are compared with constriction, the
reference's coder, symbol by symbol; whole files from gspc's encoder must decode to the same bits.
"""

import re
import struct
from dataclasses import replace
from pathlib import Path

import constriction
import make_vectors as mv
import msgpack
import numpy as np
import pytest
import spec_reader as sr
import torch
import zstandard
from scenes import random_scene

from gspc.codec.attributes import decode_attributes
from gspc.codec.entropy import _categorical, decode_matrix, encode_matrix, fixed_point_table
from gspc.encoder.coding import encode_attributes
from gspc.encoder.params import CodecParams
from gspc.encoder.precision_plan import PrecisionParams
from gspc.errors import CodecError
from gspc.format import container
from gspc.format.attribute_section import AttributeSection
from gspc.format.file import pack_file
from gspc.format.header import FileHeader, SideInfoHeader
from gspc.format.side_chunk import read_side_views
from gspc.io import read_scene
from gspc.pipeline import EncodeOptions, encode
from gspc.presets import QUALITY

ROOT = Path(__file__).resolve().parents[1]
SPEC = (ROOT / "spec" / "gspc-format.md").read_text()


def random_spec(rng: np.random.Generator) -> list[int]:
    lo = int(rng.integers(-50, 50))
    hi = lo + int(rng.integers(1, 300))
    if rng.uniform() < 0.5:
        return [2, lo, hi, int(rng.integers(lo, hi + 1)), int(rng.integers(0, 131)), int(rng.integers(0, 22))]
    w = rng.integers(0, 1 << int(rng.integers(1, 39)), hi - lo + 1)
    w[rng.integers(0, w.size)] += 1
    return [3, lo, hi, *(int(x) for x in w)]


@pytest.mark.parametrize("seed", range(6))
def test_tables_match_the_reference(seed):
    rng = np.random.default_rng(seed)
    for _ in range(20):
        spec = random_spec(rng)
        cdf = sr.cdf_of(sr.check_spec(spec))
        assert np.diff(cdf).tolist() == fixed_point_table(spec).tolist()


@pytest.mark.parametrize("seed", range(8))
def test_range_decoder_matches_constriction(seed):
    """Valid streams, and arbitrary words (which decode to something or fail at the same symbol)."""
    rng = np.random.default_rng(100 + seed)
    specs = [random_spec(rng) for _ in range(4)]
    order = rng.integers(0, 4, 400)
    if seed % 2 == 0:
        enc = constriction.stream.queue.RangeEncoder()
        for k in order:
            lo, hi = specs[k][1], specs[k][2]
            enc.encode(np.array([rng.integers(0, hi - lo + 1)], np.int32), _categorical(specs[k]))
        words = enc.get_compressed()
    else:
        words = rng.integers(0, 1 << 32, int(rng.integers(0, 12)), dtype=np.uint64).astype(np.uint32)
        if seed == 3:
            words[:2] = 0xFFFFFFFF  # the first quantile is 2^24: refused at once
    ref = constriction.stream.queue.RangeDecoder(words.copy())
    ours = sr.RangeDecoder([int(w) for w in words])
    for k in order:
        try:
            want = int(ref.decode(_categorical(specs[k]), 1)[0])
        except AssertionError:  # constriction: "invalid for the employed entropy model"
            with pytest.raises(sr.SpecError, match="quantile"):
                ours.decode(sr.cdf_of(specs[k]))
            assert seed % 2 == 1
            return
        assert ours.decode(sr.cdf_of(specs[k])) == want


def test_spec_worked_example():
    """Section 10.0's range-decoder example: its bytes decode to its symbols and states in both decoders."""
    block = SPEC[SPEC.index("*Worked example.*") :]
    hexbytes = re.search(r"the 8 bytes\s+`([0-9a-f ]+)`", block).group(1)
    words = np.frombuffer(bytes.fromhex(hexbytes.replace(" ", "")), "<u4").copy()
    a, b = [3, 0, 2, 1, 2, 1], [3, 0, 2, 0, 1, 0]
    seq = [(a, 1), (b, 0), (b, 2), (a, 2), (a, 0)]
    ref = constriction.stream.queue.RangeDecoder(words)
    assert [int(ref.decode(_categorical(m), 1)[0]) for m, _ in seq] == [s for _, s in seq]
    ours = sr.RangeDecoder([int(w) for w in words])
    rows = re.findall(
        r"^\| (\d) \| [AB] \| `(\w+)` \| `(\w+)` \| (\d) \| `(\w+)` \| `(\w+)` \| `(\w+)` \|$", block, re.M
    )
    assert len(rows) == 5
    for (m, s), row in zip(seq, rows):
        scale, quantile = ours.range >> 24, ((ours.point - ours.lower) & sr.MASK64) // (ours.range >> 24)
        assert ours.decode(sr.cdf_of(m)) == s == int(row[3])
        assert [scale, quantile, ours.lower, ours.range, ours.point] == [
            int(row[i], 16) for i in (1, 2, 4, 5, 6)
        ]


def attribute_file(scene, params, significance=None) -> tuple[bytes, dict]:
    enc = encode_attributes(scene, params, significance=significance)
    meta = {
        "attributes": enc.section.to_dict(),
        "side_info": {"background": [0.0, 0.0, 0.0], "restorer": "none"},
    }
    return container.pack(meta, [container.Chunk(k, v) for k, v in enc.chunks.items()]), enc


def assert_same(attrs: dict[str, np.ndarray], scene) -> None:
    for name, arr in attrs.items():
        ref = getattr(scene, name).numpy()
        assert arr.dtype == ref.dtype == np.float32 and arr.shape == ref.shape
        assert arr.tobytes() == ref.tobytes(), name


@pytest.mark.parametrize(
    "n, degree, preset, lam",
    [
        (1, 0, "low", None),
        (65, 3, "high", None),
        (700, 2, "low", None),
        (300, 1, "low", 64.0),
        (200, 3, "high", 0.3),
    ],
)
def test_spec_reader_decodes_encoder_output(n, degree, preset, lam):
    params = QUALITY[preset].attributes if lam is None else QUALITY[preset].attributes.with_lambda(lam)
    data, enc = attribute_file(random_scene(n=n, sh_degree=degree, seed=n), params)
    attrs, views = sr.read_scene(data)
    assert_same(attrs, enc.decoded)
    assert views == []


def test_spec_reader_decodes_the_finest_grid_the_high_presets_search_writes():
    """The high preset's search tries the grid a bit finer (gspc/presets.py): at its finest rates that is the
    format's most bits per axis, 17, with the voxels grown to fit (spec 10.1)."""
    params = replace(QUALITY["high"].attributes.with_lambda(0.1), position_offset=1.0)
    data, enc = attribute_file(random_scene(n=200, sh_degree=3, seed=9), params)
    assert enc.section.position.bits == 17
    assert_same(sr.read_scene(data)[0], enc.decoded)


def test_spec_reader_decodes_a_contracted_position_grid():
    """Attribute codec version 2 (spec 10.1): far Gaussians put the grid in contracted space."""
    scene = random_scene(n=500, sh_degree=1, seed=5)
    far = np.random.default_rng(5).normal(size=(25, 3)).astype(np.float32) * 300.0
    scene.means[:25] += torch.from_numpy(far)
    data, enc = attribute_file(scene, QUALITY["low"].attributes)
    assert enc.section.version == 2
    assert_same(sr.read_scene(data)[0], enc.decoded)


# Coarse classes (no finer steps than the rate's), so that far Gaussians stay coarse enough for a far set.
PRECISION = CodecParams(lam=8.0, precision=PrecisionParams(exponents=(0, 2), bias=1.0, sh_keep=1.0))


@pytest.mark.parametrize("degree, grid", [(0, 1), (1, 2), (2, 3), (3, 1), (0, 3)])
def test_spec_reader_decodes_precision_classes(degree, grid):
    """Attribute codec version 4 (spec 10.13) on each position grid (its version 1, 2 or 3): classes and
    per-Gaussian SH degrees from the encoder, every decoded value the same in both decoders."""
    far = {1: 0, 2: 15, 3: 40}[grid]
    scene = mv.unbounded_scene(300, far, 20 + degree, 0.5 if grid == 3 else 0.0, degree=degree)
    sig = mv.synthetic_significance(scene.num_gaussians, degree, seed=degree)
    data, enc = attribute_file(scene, PRECISION, sig)
    assert enc.section.version == 4 and enc.section.position.version == grid and enc.section.classes
    assert_same(sr.read_scene(data)[0], enc.decoded)


def _example_section(version: int, **class_1) -> dict:
    """The attribute section of the examples of spec 10.13 and 10.16: three Gaussians of SH degree 1, class
    0's steps and class 1's (class 0's with ``class_1`` and SH steps of 1)."""
    steps = {"opacity_levels": 8, "scale_step": 0.5, "rotation_levels": 4, "dc_step": 0.25}
    return {
        "version": version,
        "n": 3,
        "sh_degree": 1,
        "position": {"bits": 2, "lo": [0.0, 0.0, 0.0], "step": [1.0, 1.0, 1.0]},
        **steps,
        "sh_steps": [0.125] * 3,
        "classes": [dict(steps, **class_1, sh_steps=[1.0] * 3)],
    }


def test_spec_precision_example():
    """Section 10.13's example: C = 2, SH degree 1, PREC rows (0, 1), (1, 0), (0, 0): OPAC bins of 2 and 1
    rows, SHRS bins 1 x 9 and 0 x 9; both decoders read it alike, each class with its own steps."""
    a = _example_section(4, opacity_levels=2, scale_step=2.0, dc_step=1.0)
    rows = {0: [0, 2], 1: [1]}  # Gaussians of each class, in decoded order

    def bins(columns: int, values) -> bytes:
        return msgpack.packb([encode_matrix(values(k, len(r), columns)) for k, r in rows.items()])

    def q(k: int, m: int, c: int) -> np.ndarray:
        return np.arange(m * c, dtype=np.int64).reshape(m, c) + k + 1

    def rot(k: int, m: int, c: int) -> np.ndarray:
        return np.tile([0, 2, 2, 2], (m, 1))  # largest component w, the others 2 of M = 4 levels: in range

    chunks = {
        "POSN": msgpack.packb([encode_matrix(np.array([[0], [1], [1]])), b""]),
        "PREC": encode_matrix(np.array([[0, 1], [1, 0], [0, 0]])),
        "OPAC": bins(1, q),
        "SCAL": bins(3, q),
        "ROTN": bins(4, rot),
        "SHDC": bins(3, q),
        "SHRS": msgpack.packb([encode_matrix(q(0, 1, 9)), msgpack.packb([0, 9, b"", b""])]),
    }
    assert [msgpack.unpackb(b)[0] for b in msgpack.unpackb(chunks["OPAC"])] == [2, 1]
    meta = {"attributes": a, "side_info": {"background": [0.0, 0.0, 0.0], "restorer": "none"}}
    data = container.pack(meta, [container.Chunk(t, p) for t, p in chunks.items()])
    ref = decode_attributes(chunks, AttributeSection.from_dict(a))
    assert_same(sr.read_scene(data)[0], ref)
    assert ref.log_scales[1].tolist() == [4.0, 6.0, 8.0]  # class 1's row 0 (2, 3, 4) x its step 2
    assert ref.log_scales[2].tolist() == [2.0, 2.5, 3.0]  # class 0's row 1 (4, 5, 6) x 0.5
    assert ref.sh_rest[0, :, 0].tolist() == [0.125, 0.5, 0.875]  # coefficient j, channel 0: column 3 j
    assert not ref.sh_rest[1:].any()  # degree 0: no SH rest


@pytest.mark.parametrize("degree, grid", [(1, 1), (3, 2), (2, 3)])
def test_spec_reader_decodes_the_sh_rest_by_codebook(degree, grid):
    """Attribute codec version 5 (spec 10.16) on each position grid: the encoder's codebook, every decoded
    value the same in both decoders, and a file marked 1.8."""
    far = {1: 0, 2: 15, 3: 40}[grid]
    scene = mv.unbounded_scene(300, far, 30 + degree, 0.5 if grid == 3 else 0.0, degree=degree)
    sig = mv.synthetic_significance(scene.num_gaussians, degree, seed=degree)
    data, enc = attribute_file(scene, replace(PRECISION, sh_codebook=64), sig)
    assert enc.section.version == 5 and 1 <= enc.section.codebook <= 64
    assert_same(sr.read_scene(data)[0], enc.decoded)
    # gspc's writer marks the file 1.8, the lowest format version with attribute codec version 5 (spec 3).
    header = FileHeader(enc.section, SideInfoHeader((0.0, 0.0, 0.0), "none", 0))
    written = pack_file(header, enc.chunks, None)
    assert struct.unpack_from("<HH", written, 8) == (1, 8)
    assert_same(sr.read_scene(written)[0], enc.decoded)


def test_spec_codebook_example():
    """Section 10.16's example: SH degree 1, E = 2, PREC rows (0, 1), (0, 0), (1, 1): entries 2 x 9 at class
    0's steps whatever the Gaussian's class, indices 2 x 1 for Gaussians 0 and 2."""
    a = dict(_example_section(5), codebook=2)
    rows = {0: [0, 1], 1: [2]}
    rot = np.array([0, 2, 2, 2])
    entries = np.arange(18, dtype=np.int64).reshape(2, 9) - 4

    def bins(columns: int, value=None) -> bytes:
        return msgpack.packb(
            [encode_matrix(np.tile(rot if value is None else value, (len(r), 1))) for r in rows.values()]
        )

    chunks = {
        "POSN": msgpack.packb([encode_matrix(np.array([[0], [1], [1]])), b""]),
        "PREC": encode_matrix(np.array([[0, 1], [0, 0], [1, 1]])),
        "OPAC": bins(1, np.array([3])),
        "SCAL": bins(3, np.array([1, 2, 3])),
        "ROTN": bins(4),
        "SHDC": bins(3, np.array([1, 1, 1])),
        "SHRS": msgpack.packb([encode_matrix(entries), encode_matrix(np.array([[1], [0]]))]),
    }
    meta = {"attributes": a, "side_info": {"background": [0.0, 0.0, 0.0], "restorer": "none"}}
    data = container.pack(meta, [container.Chunk(t, p) for t, p in chunks.items()], (1, 8))
    ref = decode_attributes(chunks, AttributeSection.from_dict(a))
    assert_same(sr.read_scene(data)[0], ref)
    assert ref.sh_rest[0, :, 0].tolist() == [0.625, 1.0, 1.375]  # entry 1's (5, 8, 11) x class 0's 0.125
    assert ref.sh_rest[2, :, 0].tolist() == [-0.5, -0.125, 0.25]  # entry 0's, class 0's step too
    assert not ref.sh_rest[1].any()  # degree 0: no SH rest
    bad = dict(chunks, SHRS=msgpack.packb([encode_matrix(entries), encode_matrix(np.array([[2], [0]]))]))
    with pytest.raises(CodecError, match="codebook index"):
        decode_attributes(bad, AttributeSection.from_dict(a))
    with pytest.raises(sr.SpecError):
        sr.read_scene(container.pack(meta, [container.Chunk(t, p) for t, p in bad.items()], (1, 8)))


@pytest.mark.slow
def test_spec_reader_decodes_the_example_scene():
    """The 20k-Gaussian lego example at the low preset: every decoded value the same."""
    lego = read_scene(ROOT / "examples" / "lego" / "point_cloud.ply")
    data, enc = attribute_file(lego, QUALITY["low"].attributes)
    assert_same(sr.read_scene(data)[0], enc.decoded)


@pytest.mark.slow
def test_spec_reader_decodes_a_gspc_encode_file(tmp_path):
    """A file from gspc's whole encoder, side information included (lossy JPEG XL residuals)."""
    from gspc.io import write_ply

    src, out = tmp_path / "in.ply", tmp_path / "s.gspc"
    write_ply(random_scene(n=400, sh_degree=3, seed=11), src)
    encode(src, out, opts=EncodeOptions(lam=40, synth_views=5, max_side=40, check_iterations=0))
    data = out.read_bytes()
    attrs, views = sr.read_scene(data)
    c = container.unpack(data)
    assert c.find("SIDE") is not None and any("residual" in v for v in views)
    chunks = {ch.type: ch.payload for ch in c.chunks if ch.type != "SIDE"}
    header = FileHeader.from_dict(c.header)
    assert_same(attrs, decode_attributes(chunks, header.attributes))
    side = read_side_views(header.side_info.legacy_views, c.chunks, len(data))
    from gspc.codec.residuals import decode_residual

    for k, (v, ref) in enumerate(zip(views, side.views)):
        assert ("residual" in v) == (k in side.images)
        if k in side.images:
            assert v["residual"].tobytes() == decode_residual(side.images[k], ref.residual).tobytes()


def test_spec_reader_decodes_each_tiles_own_side_information():
    """Spec 10.15: the conformance vector with a TSID on tiles 0 and 2 decodes in both decoders to the same
    attributes and the same views per tile (cameras, residual records, images and residuals R), and each
    tile's default refinement is the same length in both (its share of the file's budgets)."""
    from gspc.codec.residuals import decode_residual
    from gspc.codec.tiles import TileDecodeJob, decode_tile
    from gspc.format.file import read_file
    from gspc.pipeline import DecodeOptions, decode_bytes
    from gspc.reconstruct import decode_work, refine_iterations

    data = (ROOT / "spec" / "vectors" / "codec_tile_sides.gspc").read_bytes()
    attrs, views = sr.read_scene(data)
    assert_same(attrs, decode_bytes(data, DecodeOptions(refine=False))[0])
    f = read_file(data)
    assert f.version == (1, 6) and [s is not None for s in f.tile_sides] == [True, False, True]
    ref = [(k, v, s.images.get(i)) for k, s in enumerate(f.tile_sides) if s for i, v in enumerate(s.views)]
    assert [v["tile"] for v in views] == [k for k, _, _ in ref] == [0, 0, 2]
    for got, (_, v, image) in zip(views, ref):
        cam = v.camera
        assert (got["width"], got["height"]) == (cam.width, cam.height)
        assert struct.pack("<4f", *got["intrinsics"]) == cam.intrinsics
        assert struct.pack("<12f", *got["pose"]) == cam.pose
        assert got["length"] == len(image or b"") and ("residual" in got) == (image is not None)
        if image is not None:
            r = v.residual
            assert got["image"] == image
            codec = ["jxl", "webp", "avif"][got["codec"]]
            assert (codec, got["bits"], got["scale"]) == (r.codec, r.bits, r.scale)
            assert np.float32(got["gain"]) == np.float32(r.gain)
            assert got["residual"].tobytes() == decode_residual(image, r).tobytes()
    # The decoder's work (10.8, per tile by 10.15): each tile's Gaussians alone at its own views.
    total = sum(sum(len(p) for p in c.values()) for c in f.tile_chunks)
    runs = []
    for k, (t, c) in enumerate(zip(f.tiles.tiles, f.tile_chunks)):
        side = f.tile_sides[k]
        if side is None:
            runs.append(None)
            continue
        scene = decode_tile(TileDecodeJob(k, c, t.section, t.box, total))
        cams = [v.camera.to_camera() for v in side.views]
        work = decode_work(scene, cams, side.images, f.tile_allowances[k])
        runs.append(refine_iterations(f.header.side_info.refine_iterations, work, f.tile_allowances[k]))
    assert sr.decoder_work(data) == runs == [300, None, 300]


def _respanned(data: bytes, maps: list[dict], sides: dict[int, bytes]) -> bytes:
    """``data`` (a tiled file) with the tile index ``maps`` and the TSID payloads ``sides`` by tile, each TSID
    after its tile's attribute chunks."""
    c = container.unpack(data)
    out = [container.Chunk("TIDX", msgpack.packb(maps, use_bin_type=True), index=0)]
    for k in range(len(maps)):
        out += [ch for ch in c.chunks if ch.type not in ("TIDX", "TSID") and ch.index == k]
        if k in sides:
            out.append(container.Chunk("TSID", sides[k], required=False, index=k))
    return container.pack(c.header, out, (1, 9))


def test_spans_are_read_and_refused_alike_in_both_decoders():
    """Spec 10.17, on codec_tile_sides' three tiles: a span decodes to the same bits as its tiles without
    one, in both decoders; every rule of a span broken is refused by both; and a span's pixel share sums
    its tiles' bytes, so views within it are read that its first tile's own share refuses."""
    from gspc.format.file import read_file
    from gspc.format.side_chunk import pack_side
    from gspc.format.view_records import ViewRecord
    from gspc.limits import PIXEL_FLOOR, PIXELS_PER_FILE_BYTE
    from gspc.pipeline import DecodeOptions, decode_bytes

    data = (ROOT / "spec" / "vectors" / "codec_tile_sides.gspc").read_bytes()
    c = container.unpack(data)
    maps = msgpack.unpackb(c.find("TIDX").payload)
    side0, side2 = c.find("TSID", 0).payload, c.find("TSID", 2).payload
    both = {0: side0, 2: side2}

    def with_maps(*changes: dict, sides: dict[int, bytes] = both) -> bytes:
        return _respanned(data, [{**m, **ch} for m, ch in zip(maps, changes)], sides)

    plain = sr.read_scene(data)[0]
    for good, spans, sides, runs in [
        (with_maps({"span": 1}, {"span": 1}, {"span": 1}), [1, 1, 1], both, [300, None, 300]),
        (with_maps({"span": 2}, {}, {}), [2, 1, 1], both, [300, None, 300]),
        (with_maps({"span": 3}, {}, {}, sides={0: side0}), [3, 1, 1], {0: side0}, [300, None, None]),
    ]:
        attrs, views = sr.read_scene(good)
        assert all(attrs[k].tobytes() == plain[k].tobytes() for k in plain)
        assert_same(attrs, decode_bytes(good, DecodeOptions(refine=False))[0])
        assert [v["tile"] for v in views] == [k for k in sorted(sides) for _ in range(2 if k == 0 else 1)]
        f = read_file(good)
        assert [t.span for t in f.tiles.tiles] == spans
        assert [s is not None for s in f.tile_sides] == [k in sides for k in range(3)]
        assert sr.decoder_work(good) == runs
    only0 = {0: side0}
    bad = {
        "span 0": with_maps({"span": 0}, {}, {}),
        "span true": with_maps({"span": True}, {}, {}),
        "span 2.0": with_maps({"span": 2.0}, {}, {}),
        "span past the last tile": with_maps({}, {"span": 3}, {}, sides=only0),
        "span 65": with_maps({"span": 65}, {}, {}),
        "span without a TSID": with_maps({}, {"span": 2}, {}, sides=only0),
        "a member with a TSID": with_maps({"span": 3}, {}, {}),
        "a member with drawn tiles": with_maps({"span": 2}, {"drawn": [2]}, {}),
        "a member with a span": with_maps({"span": 3}, {"span": 2}, {}, sides=only0),
        "a span's tile drawn by it": with_maps({"span": 2, "drawn": [1]}, {}, {}),
    }
    for what, file in bad.items():
        with pytest.raises(CodecError, match="span"):
            read_file(file)
            pytest.fail(f"gspc read {what}")
        with pytest.raises(sr.SpecError):
            sr.read_scene(file)
            pytest.fail(f"the spec reader read {what}")

    # One view of w x h on tile 0 past its own pixel share but within its span's (tiles 0 and 1's bytes).
    def one_view(w: int, h: int) -> bytes:
        return pack_side([ViewRecord.from_dict({"camera": mv.camera(1, w, h)})], {})

    q = [
        sum(len(ch.payload) for ch in c.chunks if ch.type not in ("TIDX", "TSID") and ch.index == k)
        for k in range(3)
    ]
    q[0] += len(one_view(1, 1))
    q[2] += len(side2)
    share = [
        min(1 << 28, max(PIXEL_FLOOR * b // sum(q), PIXELS_PER_FILE_BYTE * b)) for b in (q[0], q[0] + q[1])
    ]
    w = 4096
    h = share[0] // w + 1
    assert share[0] < w * h <= share[1]
    sides = {0: one_view(w, h), 2: side2}
    spanned, alone = with_maps({"span": 2}, {}, {}, sides=sides), with_maps({}, {}, {}, sides=sides)
    assert [(v.camera.width, v.camera.height) for v in read_file(spanned).tile_sides[0].views] == [(w, h)]
    assert sr.read_scene(spanned)[1][0]["height"] == h
    with pytest.raises(CodecError, match="pixels"):
        read_file(alone)
    with pytest.raises(sr.SpecError, match="pixel share"):
        sr.read_scene(alone)


# ------------------------------------------------------------------ section 10.11 in the reference decoder


def test_words_that_run_out_or_are_left_over_are_accepted():
    q = np.random.default_rng(0).integers(-20, 20, (500, 2))
    payload = encode_matrix(q)
    m, c, models, words = msgpack.unpackb(payload)
    assert np.array_equal(decode_matrix(msgpack.packb([m, c, models, words + bytes(8)])), q)
    short = msgpack.packb([m, c, models, words[:-4]])  # the last word is often one the decoder never needs
    assert decode_matrix(short).shape == q.shape


def test_zstd_frame_declaring_a_huge_size_is_refused_before_decompressing():
    frame = bytearray(zstandard.ZstdCompressor().compress(b"\x90"))
    header = zstandard.get_frame_parameters(bytes(frame))
    assert header.content_size == 1
    big = zstandard.ZstdCompressor(write_content_size=True).compress(bytes(1 << 12))
    models = msgpack.packb([8, 1, big, b""])
    with pytest.raises(CodecError):
        decode_matrix(models, (8, 1))
    huge = bytes([0x28, 0xB5, 0x2F, 0xFD, 0xE0]) + (1 << 40).to_bytes(8, "little") + bytes(8)
    with pytest.raises(CodecError, match="declare"):
        decode_matrix(msgpack.packb([8, 1, huge, b""]), (8, 1))


def test_shape_is_checked_before_decoding():
    with pytest.raises(CodecError, match="expected"):
        decode_matrix(msgpack.packb([1 << 40, 3, b"x", b""]), (10, 3))


def test_1_0_residual_record_with_bad_gain_is_refused_when_read():
    cam = {
        "name": "",
        "width": 8,
        "height": 6,
        "intrinsics": struct.pack("<4f", 8, 8, 4, 3),
        "pose": bytes(48),
    }
    rec = {"codec": "jxl", "shape": [6, 8], "bits": 8, "gain": -1.0, "offset": 128}
    side = {"views": [{"camera": cam, "residual": rec}], "background": [0, 0, 0], "restorer": "none"}
    with pytest.raises(CodecError, match="gain"):
        SideInfoHeader.from_dict(side)
    with pytest.raises(CodecError, match="cover"):
        SideInfoHeader.from_dict(
            {**side, "views": [{"camera": cam, "residual": dict(rec, gain=1.0, shape=[3, 4])}]}
        )
    good = SideInfoHeader.from_dict({**side, "views": [{"camera": cam, "residual": dict(rec, gain=2.0)}]})
    assert good.legacy_views[0].residual.gain == 2.0
    # Its image must then declare the record's size (before anything is decoded).
    with pytest.raises(CodecError, match="JPEG XL signature"):
        read_side_views(good.legacy_views, [container.Chunk("RESI", b"img", index=0)], 1000)
