"""The JavaScript decoder (web/, written from the spec) against gspc's: the PLY that
``node web/bin/gspc-decode.mjs IN OUT`` writes is byte for byte the one ``gspc decode IN -o OUT --no-refine
--no-restore`` writes, on the conformance vectors and on fresh encodes of every attribute codec version; and
both refuse the same files. Skips cleanly where node or web/node_modules (``npm ci`` in web/) is missing."""

import hashlib
import json
import shutil
import subprocess
from pathlib import Path

import msgpack
import pytest
from cli_runs import run
from make_vectors import (
    encode_classed,
    encode_scene,
    scene_meta,
    tiny_scene,
    unbounded_scene,
)
from scenes import random_scene

from gspc.errors import GspcError
from gspc.format import container
from gspc.format.file import FileReader
from gspc.io import write_ply
from gspc.options import DecodeOptions
from gspc.pipeline import decode

ROOT = Path(__file__).resolve().parents[1]
WEB = ROOT / "web"
CLI = WEB / "bin" / "gspc-decode.mjs"
VECTORS = ROOT / "spec" / "vectors"
MANIFEST = json.loads((VECTORS / "MANIFEST.json").read_text())
NODE = shutil.which("node")

pytestmark = pytest.mark.skipif(
    NODE is None or not (WEB / "node_modules" / "fzstd").is_dir(),
    reason="node, or web/node_modules (run `npm ci` in web/), is missing",
)


def node_decode(source: Path, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [NODE, str(CLI), str(source), str(out)], capture_output=True, text=True, timeout=300
    )


# One node process for many files: per file, the SHA-256 of the PLY the decoder writes, or the error's class.
_NODE_BATCH = """
import { readFileSync } from 'node:fs';
import { createHash } from 'node:crypto';
import { decodeGspc, writePly } from './src/index.mjs';
const out = {};
for (const path of JSON.parse(process.argv[1])) {
  try {
    const ply = writePly(decodeGspc(new Uint8Array(readFileSync(path))));
    out[path] = createHash('sha256').update(ply).digest('hex');
  } catch (err) {
    out[path] = err.name;
  }
}
console.log(JSON.stringify(out));
"""


def node_batch(paths: list[Path]) -> dict[str, str]:
    res = subprocess.run(
        [NODE, "--input-type=module", "-e", _NODE_BATCH, json.dumps([str(p) for p in paths])],
        capture_output=True,
        text=True,
        cwd=WEB,
        timeout=600,
    )
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def python_ply(source: Path, out: Path) -> str:
    """SHA-256 of the PLY gspc writes for ``source`` (--no-refine --no-restore), or the error's class."""
    try:
        decode(source, out, DecodeOptions(restore=False, refine=False))
    except GspcError as err:
        return type(err).__name__
    return hashlib.sha256(out.read_bytes()).hexdigest()


def assert_same_ply(source: Path, tmp_path: Path) -> None:
    """The CLI of both decoders decodes ``source``, and their PLY files are the same bytes."""
    ours, theirs = tmp_path / "python.ply", tmp_path / "node.ply"
    decode(source, ours, DecodeOptions(restore=False, refine=False))
    res = node_decode(source, theirs)
    assert res.returncode == 0, res.stderr
    assert theirs.read_bytes() == ours.read_bytes()


def assert_same_outcomes(names: list[str], tmp_path: Path) -> None:
    """The same PLY bytes from both decoders, or refused by both (the codec's refusals as CodecError, the
    container's as the same FormatError subclass)."""
    paths = [VECTORS / name for name in names]
    node = node_batch(paths)
    for path in paths:
        assert node[str(path)] == python_ply(path, tmp_path / "x.ply"), path.name


SAMPLE = [
    "codec_sh3.gspc",
    "codec_far_set.gspc",
    "codec_precision_sh3.gspc",
    "codec_precision_far_set.gspc",
    "codec_resi_1_0.gspc",
    "codec_invalid_morton_overflow.gspc",
    "codec_invalid_side_gain_nan.gspc",
    "invalid_flip_header.gspc",
]


def test_sample_vectors_give_the_same_ply_or_are_refused_by_both(tmp_path):
    assert_same_outcomes(SAMPLE, tmp_path)


@pytest.mark.slow
def test_every_vector_gives_the_same_ply_or_is_refused_by_both(tmp_path):
    assert_same_outcomes([v["file"] for v in MANIFEST["vectors"]], tmp_path)


def test_cli_refuses_with_one_line_and_no_output(tmp_path):
    for name in ("codec_invalid_mode_4.gspc", "invalid_truncated_136.gspc"):
        out = tmp_path / "x.ply"
        res = node_decode(VECTORS / name, out)
        assert res.returncode == 1, name
        assert len(res.stderr.strip().splitlines()) == 1, (name, res.stderr)
        assert not list(tmp_path.iterdir()), name


def write_file(tmp_path: Path, attributes: dict, chunks: dict[str, bytes]) -> Path:
    order = ["POSN", "PREC", "OPAC", "SCAL", "ROTN", "SHDC", "SHRS"]
    data = container.pack(
        scene_meta(attributes), [container.Chunk(t, chunks[t]) for t in order if t in chunks]
    )
    path = tmp_path / "scene.gspc"
    path.write_bytes(data)
    return path


@pytest.mark.parametrize(
    "make",
    [
        pytest.param(lambda: encode_scene(tiny_scene(300, 3, 11)), id="version-1-sh3"),
        pytest.param(lambda: encode_scene(unbounded_scene(500, 80, 12, 0.0, degree=2)), id="version-2"),
        pytest.param(lambda: encode_scene(unbounded_scene(500, 150, 13, 0.5)), id="version-3-far-set"),
        pytest.param(lambda: encode_classed(tiny_scene(300, 3, 14), (-1, 2), 14), id="version-4-classes"),
        pytest.param(
            lambda: encode_classed(unbounded_scene(400, 120, 15, 0.5, degree=0), (0, 2), 15),
            id="version-4-far",
        ),
    ],
)
def test_fresh_encodes_decode_to_the_same_ply(make, tmp_path):
    attributes, chunks = make()
    assert_same_ply(write_file(tmp_path, attributes, chunks), tmp_path)


@pytest.mark.slow
def test_cli_encode_with_side_information(tmp_path):
    """A whole `gspc encode` (precision classes, side information) of a small scene."""
    scene = tmp_path / "scene.ply"
    write_ply(random_scene(400, sh_degree=1, seed=3), scene)
    source = tmp_path / "scene.gspc"
    res = run("encode", scene, "-o", source, "--views", 8, "--max-side", 48, "--tune-iterations", 0)
    assert res.exit_code == 0, res.output
    out = tmp_path / "out"
    out.mkdir()
    assert_same_ply(source, out)


TILED = WEB / "test" / "fixtures" / "tiny_tiled_sh1.gspc"  # gspc encode --tile-size 1024: 4 tiles


@pytest.mark.slow
def test_tiled_file_whole_and_by_region_gives_the_same_ply(tmp_path):
    """A tiled file (format 1.5) from gspc's encoder: whole, and the tiles whose boxes meet a region."""
    assert_same_ply(TILED, tmp_path)
    with FileReader(TILED) as reader:
        region = ",".join(repr(v) for v in reader.tiles.tiles[1].box)
    ours, theirs = tmp_path / "region.python.ply", tmp_path / "region.node.ply"
    decode(TILED, ours, DecodeOptions(restore=False, refine=False, region=region))
    res = subprocess.run(
        [NODE, str(CLI), str(TILED), str(theirs), "--region", region], capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr
    assert theirs.read_bytes() == ours.read_bytes()
    assert len(ours.read_bytes()) < len((tmp_path / "python.ply").read_bytes())


def retiled(tmp_path: Path, name: str, change) -> Path:
    """The tiled fixture with its tile index (a list of maps) changed by ``change``, checksums right."""
    c = container.unpack(TILED.read_bytes())
    chunks = []
    for ch in c.chunks:
        if ch.type == "TIDX":
            tiles = msgpack.unpackb(ch.payload, raw=False)
            ch = container.Chunk("TIDX", msgpack.packb(change(tiles), use_bin_type=True))
        chunks.append(ch)
    path = tmp_path / f"{name}.gspc"
    path.write_bytes(container.pack(c.header, chunks, c.version))
    return path


def shrunk_box(tiles):
    box = tiles[2]["box"]
    box[3] = (box[0] + box[3]) / 2  # half the tile's positions now lie outside
    return tiles


def more_gaussians(tiles):
    tiles[0]["attributes"]["n"] += 1
    return tiles


@pytest.mark.slow
def test_hostile_tiled_files_are_refused_by_both(tmp_path):
    paths = [
        retiled(tmp_path, "box", shrunk_box),
        retiled(tmp_path, "count", more_gaussians),
        retiled(tmp_path, "one_tile", lambda tiles: tiles[:1]),
        retiled(tmp_path, "no_box", lambda tiles: [{"attributes": t["attributes"]} for t in tiles]),
    ]
    node = node_batch(paths)
    for path in paths:
        assert node[str(path)] == python_ply(path, tmp_path / "x.ply") == "CodecError", path.name
