"""Spatial tiles (format 1.5, spec 10.14): a scene larger than a tile coded as tiles a decoder reads one at a
time, with the same bytes for any number of workers; a region decoded alone; hostile tile indexes refused;
each tile's own side information (format 1.6, 10.15) refining it with its neighbours drawn (1.7)."""

import re
from dataclasses import replace

import msgpack
import numpy as np
import pytest
import torch
from cli_runs import assert_one_line_error, run
from scenes import random_scene, unbounded

import gspc.format.container as container
from gspc.codec.cells import span_cells
from gspc.codec.tiles import decode_tile_section, file_tile_jobs
from gspc.encoder.tiles import _octree_runs, plan_tiles
from gspc.errors import CodecError, InputError
from gspc.format.file import FileReader, read_file
from gspc.format.tiles import TIDX, Tile, pack_tile_index
from gspc.io import read_scene, write_ply
from gspc.limits import MIN_TILE_SIZE, DecodeBudget
from gspc.options import DecodeOptions, EncodeOptions, check_region
from gspc.pipeline import decode, decode_bytes, decode_tiles, encode, encode_scene

# Small and quick: two or three tiles, few small views, the searches off (the slow test runs the method).
QUICK = dict(
    tile_size=MIN_TILE_SIZE,
    synth_views=4,
    max_side=32,
    removal_search=False,
    tune_iterations=0,
    side_info=False,
)
# ... and with each tile's own side information, sent unchecked at a coarse rate (spec 10.15).
SIDED = {**QUICK, "side_info": True, "check_iterations": 0, "lam": 40.0}


def scene(n=2500, seed=3):
    return random_scene(n, sh_degree=1, seed=seed, opacity_logit=2.0)


@pytest.fixture(scope="module")
def tiled(tmp_path_factory):
    d = tmp_path_factory.mktemp("tiles")
    src, out = d / "in.ply", d / "t.gspc"
    write_ply(scene(), src)
    rep = encode(src, out, opts=EncodeOptions(**QUICK, workers=1))
    return src, out, rep


def test_octree_runs_cover_the_curve_in_cells_of_at_most_a_tile():
    codes = np.sort(np.random.default_rng(0).integers(0, 1 << 30, 5000))
    runs = _octree_runs(codes, 10, 700)
    assert runs[0][0] == 0 and runs[-1][1] == 5000
    assert all(a < b and b - a <= 700 for a, b in runs)
    assert all(b == c for (_, b), (c, _) in zip(runs, runs[1:]))
    same = np.zeros(3000, np.int64)  # one voxel holding more than a tile is cut in pieces
    assert [b - a for a, b in _octree_runs(same, 10, 1024)] == [1024, 1024, 952]


def test_plan_tiles_is_a_partition_in_curve_order():
    s = scene(5000)
    plan = plan_tiles(s.means.numpy(), s.log_scales.numpy(), 12.0, 1500)
    rows = np.concatenate(plan.rows)
    assert sorted(rows.tolist()) == list(range(5000)) and all(len(r) <= 1500 for r in plan.rows)
    far = plan_tiles(unbounded(n=3000), np.full((3305, 3), -3.0), 12.0, 1024)
    assert far.shared.frame.contraction is not None and far.shared.inside_size > 0


def test_a_scene_larger_than_a_tile_is_a_tiled_file(tiled):
    _, out, rep = tiled
    f = read_file(out.read_bytes())
    assert f.version == (1, 5) and f.tiles is not None and len(f.tiles.tiles) >= 2
    assert f.header.attributes is None and rep.num_gaussians_out == f.num_gaussians
    assert all(t.n <= MIN_TILE_SIZE for t in f.tiles.tiles)
    assert "tiles" in rep.info and rep.info["side info"] == "none (--no-side-info)"
    # Each tile was measured with what the others hide, at the scene's cameras and the views between them.
    known = rep.decisions.tiles[0].occlusion
    views = known.views
    assert views % 2 == 0 and 0 < known.seen <= views  # a view halfway from each camera
    assert rep.info["occlusion"].startswith("each tile measured with what the other tiles hide"), rep.info
    assert f" of {views} views (the cameras and halfway between them)" in rep.info["occlusion"]
    # Each tile aimed at the preset's fidelity: the header states the lowest tile's, and `gspc info` says it.
    lowest = min(t.fidelity_db for t in rep.decisions.tiles)
    assert f.header.scene.psnr_db == pytest.approx(lowest)
    assert f"fidelity: {lowest:.2f} dB (its lowest tile's)" in " ".join(run("info", out).stdout.split())
    small = random_scene(300, sh_degree=1, seed=1)  # no larger than a tile: the untiled format, as before
    data, _ = encode_scene(small, opts=EncodeOptions(**QUICK))
    assert read_file(data).version == (1, 4) and read_file(data).tiles is None


def test_workers_write_the_same_bytes_and_decode_the_same_bits(tiled, tmp_path):
    src, out, _ = tiled
    two = tmp_path / "two.gspc"
    encode(src, two, opts=EncodeOptions(**QUICK, workers=2))
    assert two.read_bytes() == out.read_bytes()
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    decode(out, a, DecodeOptions(workers=1))
    decode(out, b, DecodeOptions(workers=2))
    assert a.read_bytes() == b.read_bytes()
    whole, _ = decode_bytes(out.read_bytes())
    assert np.array_equal(read_scene(a).means.numpy(), whole.means.numpy())


def test_a_region_decodes_only_the_tiles_that_meet_it(tiled, tmp_path, monkeypatch):
    _, out, _ = tiled
    tiles = list(decode_tiles(out))
    first = tiles[0].box
    corner = (first[0], first[1], first[2], first[0], first[1], first[2])
    read = []
    real = container.read_chunk
    monkeypatch.setattr(container, "read_chunk", lambda f, h, i: read.append(h.entries[i]) or real(f, h, i))
    part = tmp_path / "part.ply"
    rep = decode(out, part, DecodeOptions(region=corner, workers=1))
    meeting = [t for t in tiles if all(t.box[a] <= corner[a] <= t.box[a + 3] for a in range(3))]
    assert (
        read_scene(part).num_gaussians == sum(t.scene.num_gaussians for t in meeting) == rep.num_gaussians_out
    )
    assert {e.index for e in read if e.type != TIDX} == {t.number for t in meeting} and len(meeting) < len(
        tiles
    )
    with pytest.raises(InputError, match="meets none"):
        decode(out, tmp_path / "none.ply", DecodeOptions(region=(1e6, 1e6, 1e6, 2e6, 2e6, 2e6)))


def test_info_lists_the_tiles(tiled):
    _, out, _ = tiled
    res = run("info", out)
    assert res.exit_code == 0 and "tiles" in res.output and "box" in res.output, res.output


@pytest.mark.parametrize(
    ("value", "needle"),
    [("1,2,3", "six"), ("0,0,0,1,1,nan", "finite"), ("2,0,0,1,1,1", "minimum is above"), ("a,b", "six")],
)
def test_bad_regions_are_refused_in_one_line(value, needle):
    with pytest.raises(InputError, match=needle):
        check_region(value)


def test_bad_worker_counts_are_refused_in_one_line(tiled, tmp_path):
    src, out, _ = tiled
    assert_one_line_error(run("decode", out, "-o", tmp_path / "o.ply", "--workers", 0), "--workers")
    assert_one_line_error(run("encode", src, "-o", tmp_path / "o.gspc", "--tile-size", 10), "--tile-size")
    assert not (tmp_path / "o.ply").exists()


def _rewritten(path, tiles=None, order=None, index_of=None):
    """The tiled file at ``path`` with its tile index replaced, its chunks reordered or renumbered."""
    c = container.read(path)
    chunks = list(c.chunks)
    if tiles is not None:
        chunks = [container.Chunk(TIDX, pack_tile_index(tiles)) if ch.type == TIDX else ch for ch in chunks]
    if order is not None:
        chunks = order(chunks)
    if index_of is not None:
        chunks = [replace(ch, index=index_of(ch)) for ch in chunks]
    return container.pack(c.header, chunks, c.version)


def test_hostile_tile_indexes_are_refused(tiled):
    _, out, _ = tiled
    f = read_file(out.read_bytes())
    tiles = list(f.tiles.tiles)
    box = tiles[0].box
    cases = {
        # a box that misses its tile's Gaussians: their positions lie outside it
        "outside its box": _rewritten(out, [Tile((*box[:3], *box[:3]), tiles[0].section), *tiles[1:]]),
        # a count that disagrees with its chunks' rows
        "entropy-coded matrix": _rewritten(
            out, [Tile(box, replace(tiles[0].section, n=tiles[0].n - 1)), *tiles[1:]]
        ),
        # a chunk naming a tile the index does not hold
        "names no tile": _rewritten(
            out, index_of=lambda ch: 99 if ch.type == "OPAC" and ch.index == 1 else ch.index
        ),
        # tile 1's chunks before tile 0's
        "comes after": _rewritten(
            out, order=lambda chs: [chs[0], *sorted(chs[1:], key=lambda ch: -ch.index)]
        ),
        # the index after the tiles
        "before the tile index": _rewritten(out, order=lambda chs: [*chs[1:], chs[0]]),
        # one tile alone is not a tiled file
        "2..": _rewritten(out, [tiles[0]]),
        # tiles drawn with a tile's views (spec 10.15): itself, one the file does not hold, one twice
        "drawn tiles": _rewritten(out, [replace(tiles[0], drawn=(0,)), *tiles[1:]]),
        "distinct other": _rewritten(out, [replace(tiles[0], drawn=(len(tiles),)), *tiles[1:]]),
        "at most": _rewritten(out, [replace(tiles[0], drawn=(1, 1)), *tiles[1:]]),
    }
    for needle, data in cases.items():
        with pytest.raises(CodecError, match=needle):
            decode_bytes(data)


def test_a_tile_index_that_is_not_msgpack_or_mixes_sh_degrees_is_refused(tiled):
    _, out, _ = tiled
    f = read_file(out.read_bytes())
    t0, t1, *rest = f.tiles.tiles
    c = container.read(out)
    garbage = [container.Chunk(TIDX, b"\xc1") if ch.type == TIDX else ch for ch in c.chunks]
    with pytest.raises(CodecError, match="msgpack"):
        read_file(container.pack(c.header, garbage, c.version))
    classes = tuple(replace(k, sh_steps=()) for k in t1.section.classes)
    degree0 = replace(t1.section, sh_degree=0, sh_steps=(), classes=classes)
    mixed = pack_tile_index([t0, Tile(t1.box, degree0), *rest])
    raw = msgpack.unpackb(mixed)
    assert raw[1]["attributes"]["sh_degree"] == 0
    chunks = [container.Chunk(TIDX, mixed) if ch.type == TIDX else ch for ch in c.chunks]
    with pytest.raises(CodecError, match="SH degrees"):
        read_file(container.pack(c.header, chunks, c.version))


def test_each_tile_spends_its_share_of_the_files_floors():
    # spec 10.14: the file's floors are shared among its tiles by bytes, so many tiny tiles get no more
    # than one file's floors in all
    budgets = [DecodeBudget(1000, 100_000) for _ in range(100)]
    one = DecodeBudget(100_000, 100_000)
    assert sum(b.table_entries for b in budgets) <= one.table_entries + 100
    assert sum(b.model_bytes for b in budgets) <= one.model_bytes + 100
    assert one.spend_tables(one.table_entries) and not one.spend_tables(1)


def test_a_partial_reader_checks_the_chunks_it_reads(tiled, tmp_path):
    _, out, _ = tiled
    data = bytearray(out.read_bytes())
    with FileReader(out) as r:
        last = max(i for i, e in enumerate(r.head.entries) if e.index == len(r.tiles.tiles) - 1)
        at = r.head.entries[last].offset
    data[at] ^= 0xFF  # a byte of the last tile's last chunk
    bad = tmp_path / "bad.gspc"
    bad.write_bytes(bytes(data))
    first = next(decode_tiles(bad))  # the first tile reads clean; the damaged one is refused when read
    assert first.number == 0
    with pytest.raises(container.ChecksumMismatch):
        list(decode_tiles(bad))
    with pytest.raises(container.ChecksumMismatch):
        decode(bad, tmp_path / "o.ply", DecodeOptions(workers=1))
    assert not (tmp_path / "o.ply").exists()


@pytest.mark.slow
def test_the_whole_method_runs_per_tile_and_the_target_holds(tmp_path):
    src, out = tmp_path / "in.ply", tmp_path / "t.gspc"
    write_ply(scene(3000, seed=4), src)
    opts = EncodeOptions(tile_size=MIN_TILE_SIZE, synth_views=6, max_side=48, workers=2)
    rep = encode(src, out, opts=opts)
    # Each tile weighs side information of its own; those that send none have their values tuned.
    assert "removal" in rep.info and rep.info["side info"], rep.info
    assert "tuning" in rep.info or rep.info["side info"].startswith("each tile's own: sent for"), rep.info
    # The preset's fidelity, per tile at the cameras that see it (gspc/presets.py).
    assert rep.info["fidelity"].startswith("each tile coded to its share of 44 dB at views"), rep.info
    target = int(0.8 * out.stat().st_size)
    encode(src, out, opts=replace(opts, target_size=target))
    assert out.stat().st_size <= target


@pytest.fixture(scope="module")
def sided(tmp_path_factory):
    d = tmp_path_factory.mktemp("sided")
    src, out = d / "in.ply", d / "s.gspc"
    write_ply(scene(), src)
    rep = encode(src, out, opts=EncodeOptions(**SIDED, workers=1, tile_neighbours=True))
    return src, out, rep


def test_tiles_carry_their_own_side_information_drawn_with_their_neighbours(sided, tmp_path):
    src, out, rep = sided
    f = read_file(out.read_bytes())
    sent = [k for k, side in enumerate(f.tile_sides) if side is not None]
    assert f.version == (1, 7) and len(sent) >= 2 and all(f.tile_sides[k].images for k in sent), rep.info
    assert all(not c.required for c in f.chunks if c.type == "TSID")  # a 1.5 reader skips them
    # The views of a tile that sends some show the tiles next to it: here, four tiles side by side.
    assert all(bool(t.drawn) == (k in sent) and k not in t.drawn for k, t in enumerate(f.tiles.tiles))
    tiles = len(f.tiles.tiles)
    assert rep.info["side info"].startswith(f"each tile's own: sent for {len(sent)} of {tiles}"), rep.info
    assert "each drawn with its neighbouring tiles" in rep.info["side info"], rep.info
    assert rep.info["decoder refines"].startswith(f"each of {len(sent)} tiles against its own views")
    # The same bytes on two workers, and the same bits decoded there.
    two = tmp_path / "two.gspc"
    encode(src, two, opts=EncodeOptions(**SIDED, workers=2, tile_neighbours=True))
    assert two.read_bytes() == out.read_bytes()
    opts = DecodeOptions(iterations=3, workers=1)
    whole, drep = decode_bytes(out.read_bytes(), opts)
    assert drep.info["refine"].startswith(f"{len(sent)} of {tiles} tiles refined"), drep.info
    assert "of the tiles next to them drawn beside them" in drep.info["refine"], drep.info
    plain, _ = decode_bytes(out.read_bytes(), replace(opts, refine=False))
    assert not torch.equal(whole.sh_dc, plain.sh_dc)  # refinement moved the values
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    decode(out, a, opts)
    decode(out, b, replace(opts, workers=2))
    assert a.read_bytes() == b.read_bytes()
    # A tile's neighbours are drawn as decoded, never refined: decoded as part of a region (its neighbours
    # outside it), a tile comes out as in the whole scene.
    box = f.tiles.tiles[1].box
    inner = tuple((box[i] + box[i + 3]) / 2 for i in range(3))
    part = tmp_path / "part.ply"
    decode(out, part, replace(opts, region=(*inner, *inner)))
    ours = read_scene(part)
    rows = f.tiles.meeting((*inner, *inner))
    start = [0, *np.cumsum([t.n for t in f.tiles.tiles])]
    for name in ("means", "sh_dc", "opacities", "log_scales"):
        expect = torch.cat([getattr(whole, name)[start[k] : start[k + 1]] for k in rows])
        assert torch.equal(getattr(ours, name), expect), name


def test_tiles_alone_are_format_1_6_and_refine_alone(tmp_path):
    src, out = tmp_path / "in.ply", tmp_path / "alone.gspc"
    write_ply(scene(), src)
    encode(src, out, opts=EncodeOptions(**SIDED, workers=1))  # the default: each tile alone
    f = read_file(out.read_bytes())
    sent = sum(side is not None for side in f.tile_sides)
    assert f.version == (1, 6) and not any(t.drawn for t in f.tiles.tiles) and sent >= 2
    whole, rep = decode_bytes(out.read_bytes(), DecodeOptions(iterations=3))
    assert rep.info["refine"].startswith(f"{sent} of {len(f.tiles.tiles)} tiles refined"), rep.info


@pytest.mark.slow
def test_the_spec_reader_decodes_a_tiled_file_to_the_same_bits(tiled):
    # tests/spec_reader.py, written from spec 10.14 alone, agrees with gspc bit for bit.
    import spec_reader

    _, out, _ = tiled
    data = out.read_bytes()
    attrs, views = spec_reader.read_scene(data)
    scene, _ = decode_bytes(data)
    assert not views
    for name, value in attrs.items():
        assert np.array_equal(value, getattr(scene, name).numpy()), name


def test_default_workers_fit_the_available_memory(monkeypatch):
    """--workers by default: every core, but no more workers than the memory available holds."""
    import gspc.workers as workers

    cores = workers.default_workers()
    monkeypatch.setattr(workers, "available_memory", lambda: 5 << 30)
    assert workers.default_workers(2 << 30) == min(cores, 2)
    monkeypatch.setattr(workers, "available_memory", lambda: 1 << 20)
    assert workers.default_workers(2 << 30) == 1
    monkeypatch.setattr(workers, "available_memory", lambda: None)
    assert workers.default_workers(2 << 30) == cores


def test_each_tile_aims_at_its_share_of_the_views_error():
    # gspc/encoder/tiles.py error_shares: a view's error is the sum of the tiles' it shows, so a tile's
    # target is raised by 10 log10 of the tiles the cameras that see it see (0 where a camera sees one).
    from gspc.encoder.tiles import error_shares
    from gspc.views import synthesize_views

    s = scene(3000, seed=4)
    means, log_scales = s.means.numpy().astype(np.float64), s.log_scales.numpy().astype(np.float64)
    cams = synthesize_views(s, 6, 32, 32)
    halves = [np.arange(0, 1500), np.arange(1500, 3000)]
    shares = error_shares(halves, means, log_scales, cams)
    assert np.allclose(shares, 10 * np.log10(2))  # every camera sees both halves
    assert np.allclose(error_shares([np.arange(3000)], means, log_scales, cams), 0.0)


def test_each_tiles_check_is_summarised():
    """A tile's check weighs its side information against the same bytes on its attributes; the summary
    gives what the checks measured, and why none was sent."""
    _, rep = encode_scene(scene(), opts=EncodeOptions(**{**SIDED, "check_iterations": 20, "lam": 20.0}))
    checks = rep.info["tile checks"]  # the tiles with a residual worth sending (of 4)
    assert re.match(r"[1-4] tiles: refined with their side information", checks), checks
    side = rep.info["side info"]
    assert side.startswith("each tile's own: sent for") or side.startswith("none sent: "), side


def test_a_tiles_neighbours_are_the_tiles_its_box_meets():
    # gspc/encoder/tiles.py plan_neighbours: boxes that meet (grown by a twentieth of the tile's diagonal),
    # never the tile itself; three unit cubes in a row, the last 1.5 apart.
    from gspc.encoder.tiles import plan_neighbours

    rng = np.random.default_rng(0)
    cubes = [np.vstack([[0, 0, 0], [1, 1, 1], rng.random((48, 3))]) + [x, 0, 0] for x in (0.0, 1.0, 3.5)]
    rows = [np.arange(50 * k, 50 * (k + 1)) for k in range(3)]
    assert plan_neighbours(rows, np.concatenate(cubes)) == [(1,), (0,), ()]


def test_the_tiles_a_tile_draws_count_in_its_work(sided):
    # spec 10.15: the drawn tiles' Gaussians that a view sees count in its pairs and in the first work, so a
    # tile that stays within its allowance alone is refused once what it draws passes it.
    from gspc.codec.tiles import decode_tile, file_tile_jobs
    from gspc.limits import RenderAllowance
    from gspc.tile_reconstruct import tile_views_work

    _, out, _ = sided
    f = read_file(out.read_bytes())
    k = next(k for k, t in enumerate(f.tiles.tiles) if t.drawn)
    jobs = file_tile_jobs(f.tiles.tiles, f.tile_chunks)
    scene = decode_tile(jobs[k])
    roomy = RenderAllowance(1 << 30, 1 << 30, 1 << 40, f"tile {k}", "spec 10.15")
    drawn = tuple(jobs[j] for j in f.tiles.tiles[k].drawn)
    _, alone = tile_views_work(scene, f.tile_sides[k], (), roomy)
    shown, work = tile_views_work(scene, f.tile_sides[k], drawn, roomy)
    assert shown is not None and work.num_gaussians == alone.num_gaussians + shown.num_gaussians
    assert sum(work.pairs) > sum(alone.pairs) and work.first > alone.first
    tight = RenderAllowance(1 << 30, max(alone.pairs), alone.first, f"tile {k}", "spec 10.15")
    tile_views_work(scene, f.tile_sides[k], (), tight)  # alone, within it
    with pytest.raises(CodecError, match=f"tile {k}"):
        tile_views_work(scene, f.tile_sides[k], drawn, tight)


@pytest.fixture(scope="module")
def spanned(tmp_path_factory):
    d = tmp_path_factory.mktemp("spanned")
    src, out = d / "in.ply", d / "span.gspc"
    write_ply(scene(), src)
    rep = encode(src, out, opts=EncodeOptions(**SIDED, workers=1, span_size=4 * MIN_TILE_SIZE))
    return src, out, rep


def test_a_span_of_tiles_shares_its_side_information_and_refines_as_one(spanned, tmp_path):
    src, out, rep = spanned
    f = read_file(out.read_bytes())
    tiles = f.tiles.tiles
    # One span holds every tile of this small scene: its first tile's TSID serves them all (spec 10.17).
    assert f.version == (1, 9) and len(tiles) >= 2 and tiles[0].span == len(tiles), rep.info
    assert f.tile_sides[0] is not None and all(side is None for side in f.tile_sides[1:])
    assert rep.info["side info"].startswith("shared by spans of tiles: sent for 1 of 1 spans"), rep.info
    assert f"with their spans' {len(tiles)} tiles, as one" in rep.info["decoder refines"], rep.info
    res = run("info", out)
    text = " ".join(res.output.split())  # rich wraps lines at the test's width
    assert res.exit_code == 0 and f"1 serve spans of {len(tiles)}-{len(tiles)} tiles" in text, res.output
    with pytest.raises(InputError, match="--span-size"):
        EncodeOptions(span_size=10).validate()
    # In a byte target: the span's tiles and its side information share it (the tiles coded again in what
    # the residuals leave).
    target = int(0.9 * out.stat().st_size)
    small = tmp_path / "small.gspc"
    opts = EncodeOptions(**SIDED, workers=1, span_size=4 * MIN_TILE_SIZE, target_size=target)
    encode(src, small, opts=opts)
    assert small.stat().st_size <= target and read_file(small.read_bytes()).tiles.tiles[0].span == len(tiles)
    opts = DecodeOptions(iterations=3, workers=1)
    whole, drep = decode_bytes(out.read_bytes(), opts)
    assert drep.info["refine"].startswith(f"{len(tiles)} of {len(tiles)} tiles refined"), drep.info
    assert f"1 spans of {len(tiles)}-{len(tiles)} tiles refined as one" in drep.info["refine"], drep.info
    plain, _ = decode_bytes(out.read_bytes(), replace(opts, refine=False))
    start = [0, *np.cumsum([t.n for t in tiles])]
    last = slice(int(start[-2]), int(start[-1]))
    assert not torch.equal(whole.sh_dc[last], plain.sh_dc[last])  # a member's values moved too
    # Every refined value stays inside its own tile's cell (spec 10.17), the span refined as one scene.
    jobs = file_tile_jobs(f.tiles.tiles, f.tile_chunks)
    cells = span_cells([(d.scene, j.section, d.precision) for j in jobs for d in [decode_tile_section(j)]])
    for name, (lo, hi) in cells.items():
        value = getattr(whole, name)
        assert bool(((value >= lo - 1e-6) & (value <= hi + 1e-6)).all()), name
    two = tmp_path / "two.gspc"
    encode(src, two, opts=EncodeOptions(**SIDED, workers=2, span_size=4 * MIN_TILE_SIZE))
    assert two.read_bytes() == out.read_bytes()
    a, b = tmp_path / "a.ply", tmp_path / "b.ply"
    decode(out, a, opts)
    decode(out, b, replace(opts, workers=2))
    assert a.read_bytes() == b.read_bytes()
    # A region meeting one member: the whole span is refined for it, and that tile comes out as in the whole.
    box = tiles[-1].box
    inner = tuple((box[i] + box[i + 3]) / 2 for i in range(3))
    part = tmp_path / "part.ply"
    decode(out, part, replace(opts, region=(*inner, *inner)))
    ours, rows = read_scene(part), f.tiles.meeting((*inner, *inner))
    for name in ("means", "sh_dc", "opacities", "log_scales"):
        expect = torch.cat([getattr(whole, name)[start[k] : start[k + 1]] for k in rows])
        assert torch.equal(getattr(ours, name), expect), name


def test_hostile_spans_are_refused(spanned):
    _, out, _ = spanned
    f = read_file(out.read_bytes())
    tiles = list(f.tiles.tiles)
    cases = [  # (the index, what the error names): spec 10.17's rules
        ([replace(tiles[0], span=len(tiles) + 1), *tiles[1:]], "span is not an integer"),
        ([replace(tiles[0], span=1), replace(tiles[1], span=2), *tiles[2:]], "no TSID"),
        ([replace(tiles[0], drawn=(1,)), *tiles[1:]], "drawn tiles name a tile of its own span"),
    ]
    for index, needle in cases:
        with pytest.raises(CodecError, match=needle):
            read_file(_rewritten(out, index))


def test_a_spans_check_sends_what_beats_its_rival_and_the_same_bytes_on_any_workers(tmp_path):
    src = tmp_path / "in.ply"
    write_ply(scene(), src)
    checked = {**SIDED, "check_iterations": 5, "span_size": 2 * MIN_TILE_SIZE}
    out = {}
    for name, margin, workers in [("sent", -50.0, 1), ("sent2", -50.0, 2), ("declined", 50.0, 2)]:
        out[name] = tmp_path / f"{name}.gspc"
        opts = EncodeOptions(**checked, check_margin_db=margin, workers=workers)
        rep = encode(src, out[name], opts=opts)
        f = read_file(out[name].read_bytes())
        sent = [k for k, side in enumerate(f.tile_sides) if side is not None]
        if name == "declined":  # the spans' tiles as a file without side information holds them
            assert not sent and "declined by the check" in rep.info["side info"], rep.info
        else:
            assert sent and all(f.tiles.tiles[k].span == 2 for k in sent), rep.info
            reasons = [rep.decisions.tiles[k].side.reason for k in sent]
            assert all(r.startswith("sent: at") and "(tuned)" in r for r in reasons), reasons
    assert out["sent"].read_bytes() == out["sent2"].read_bytes()
