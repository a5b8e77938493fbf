"""Generator of hostile inputs for the CLI (issue 15): bad option values, bad camera files, hostile .gspc
files (header fields mutated from a valid tiny encode's, side-information views and residual images that ask
for too much) and SOG archives with oversized members.

Every case must end in exit status 1 with one ``error:`` line and no output file. tests/test_hostile.py runs
them; tools/fuzz_inputs.py counts them into bench/robustness.md.
"""

from __future__ import annotations

import copy
import json
import math
import os
import re
import struct
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import imagecodecs
import numpy as np
from plyfile import PlyData

from gspc.format import container
from gspc.format.side_chunk import pack_side, unpack_side
from gspc.format.view_records import ViewRecord


@dataclass(frozen=True)
class Case:
    category: str  # for bench/robustness.md
    name: str
    args: list[str]  # CLI arguments
    # "refused": exit 1, one error line, ``output`` not written; "ok": exit 0 and ``output`` written (a file
    # crafted at a limit's edge, or input gspc now reads). Either way no other file changes.
    output: Path | None  # None: the command writes nothing / it is an input
    expect: str = "refused"
    env: dict[str, str] | None = None  # environment for the run (GSPC_THREADS)


def outcome(case: Case, exit_code: int, text: str) -> str:
    """How a run ended: "refused" or "ok" when clean, else what went wrong."""
    lines = text.strip().splitlines() or [""]
    if "Traceback" in text or "internal error" in text:
        return "internal error"
    if exit_code == 0:
        if case.expect == "ok" and (case.output is None or case.output.exists()):
            return "ok"
        return "accepted" if case.expect == "refused" else "output missing"
    if any("warning" in x for x in lines):
        return "warnings before the error"  # e.g. numpy's, on values a check should have refused first
    if (
        exit_code != 1
        or not lines[-1].startswith("error:")
        or not all(x.startswith("gspc: ") for x in lines[:-1])
    ):
        return "not one error line"
    if case.output is not None and case.output.exists():
        return "output left behind"
    return "refused"


def snapshot(folder: Path) -> dict[Path, tuple[int, int, int]]:
    """Every file under ``folder`` with its mode, size and modification time: what a run must not touch."""
    out = {}
    for p in folder.rglob("*"):
        try:
            st = p.lstat()
        except FileNotFoundError:
            continue
        out[p] = (st.st_mode, st.st_size, st.st_mtime_ns)
    return out


def touched(before: dict, after: dict, allowed: Path | None) -> list[str]:
    """Files created, changed or removed between two snapshots, other than ``allowed`` (and inside it)."""
    changed = {p for p in before.keys() | after.keys() if before.get(p) != after.get(p)}
    if allowed is not None:
        changed = {p for p in changed if p != allowed and allowed not in p.parents}
    return sorted(str(p) for p in changed)


# --------------------------------------------------------------------------------------------- options


def _small_encode(scene: Path, out: Path) -> list[str]:
    """A quick encode's arguments: few small views, no check."""
    small = ["--views", "4", "--max-side", "32", "--check-iterations", "0"]
    return ["encode", str(scene), "-o", str(out), *small]


def option_cases(scene: Path, gspc_file: Path, tmp: Path) -> Iterator[Case]:
    """Bad option values of encode, decode, render and eval; outputs equal to inputs."""
    out = tmp / "opt_out.gspc"
    enc = _small_encode(scene, out)
    bad_encode = {
        "background 2 2 2": ["--background", "2", "2", "2"],
        "background negative": ["--background", "-0.5", "0", "0"],
        "background nan": ["--background", "nan", "0", "0"],
        "background inf": ["--background", "0", "inf", "0"],
        "max-side 0": ["--max-side", "0"],
        "max-side negative": ["--max-side", "-4"],
        "max-side 8": ["--max-side", "8"],
        "max-side huge": ["--max-side", str(1 << 20)],
        "target-size 0": ["--target-size", "0"],
        "target-size 1": ["--target-size", "1"],
        "target-size negative": ["--target-size", "-100"],
        "lambda inf": ["--lambda", "inf"],
        "lambda nan": ["--lambda", "nan"],
        "lambda 1e-300": ["--lambda", "1e-300"],
        "lambda 0": ["--lambda", "0"],
        "lambda negative": ["--lambda", "-3"],
        "lambda 1e9": ["--lambda", "1e9"],
        "views 0": ["--views", "0"],
        "views negative": ["--views", "-2"],
        "views huge": ["--views", str(10**9)],
        "views-fraction 0": ["--views-fraction", "0"],
        "views-fraction 1.5": ["--views-fraction", "1.5"],
        "views-fraction nan": ["--views-fraction", "nan"],
        "check-iterations negative": ["--check-iterations", "-1"],
        "check-iterations 1e12": ["--check-iterations", str(10**12)],
        "quality unknown": ["--quality", "best"],
        "restorer empty": ["--restorer", ""],
    }
    for name, extra in bad_encode.items():
        yield Case("options: encode", name, enc + extra, out)
    dout = tmp / "opt_out.ply"
    dec = ["decode", str(gspc_file), "-o", str(dout)]
    for name, extra in {
        "iterations negative": ["--iterations", "-1"],
        "iterations 1e12": ["--iterations", str(10**12)],
        "device tpu": ["--device", "tpu"],
        "restorer empty": ["--restorer", ""],
    }.items():
        yield Case("options: decode", name, dec + extra, dout)
    rdir = tmp / "opt_renders"
    for name, extra in {"views 0": ["--views", "0"], "max-side 0": ["--max-side", "0"]}.items():
        yield Case("options: render", name, ["render", str(scene), "-o", str(rdir), *extra], rdir)
    for name, extra in {
        "background 2 2 2": ["--background", "2", "2", "2"],
        "views 0": ["--views", "0"],
        "max-side -1": ["--max-side", "-1"],
    }.items():
        yield Case("options: eval", name, ["eval", str(scene), str(scene), *extra], None)
    # Output paths naming an input: the input must survive (checked by the test through its bytes).
    link = tmp / "scene_link.ply"
    if not link.exists():
        os.link(scene, link)
    same = {
        "encode -o SCENE": ["encode", str(scene), "-o", str(scene)],
        "encode -o hard link of SCENE": ["encode", str(scene), "-o", str(link)],
        "encode -o CAMERAS": ["encode", str(scene), "-o", str(tmp / "cams_in.json"), "--cameras"],
        "decode -o FILE.gspc": ["decode", str(gspc_file), "-o", str(gspc_file)],
        "convert -o SCENE": ["convert", str(scene), "-o", str(scene)],
        "render -o SCENE": ["render", str(scene), "-o", str(scene)],
    }
    cams = tmp / "cams_in.json"
    cams.write_text(json.dumps([_inria_entry()]))
    for name, args in same.items():
        if args[-1] == "--cameras":
            args = [*args, str(cams)]
        yield Case("options: output is an input", name, args, None)


# ----------------------------------------------------------------------------------------- camera files


def _inria_entry(**over) -> dict:
    e = {
        "id": 0,
        "img_name": "a",
        "width": 32,
        "height": 24,
        "position": [0.0, 0.0, -3.0],
        "rotation": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        "fx": 30.0,
        "fy": 30.0,
    }
    e.update(over)
    return e


def _frame(**over) -> dict:
    f = {
        "file_path": "./r_0",
        "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]],
    }
    f.update(over)
    return f


def write_camera_files(tmp: Path) -> dict[str, Path]:
    """Bad camera files, by name. JSON allows Infinity and NaN the way Python writes them."""
    d = tmp / "cams"
    d.mkdir(exist_ok=True)
    files: dict[str, object] = {
        "cameras.json fx 0": [_inria_entry(fx=0.0)],
        "cameras.json fy negative": [_inria_entry(fy=-5.0)],
        "cameras.json fx string": [_inria_entry(fx="wide")],
        "cameras.json fx NaN": [_inria_entry(fx=math.nan)],
        "cameras.json width Infinity": [_inria_entry(width=math.inf)],
        "cameras.json width 1e12": [_inria_entry(width=10**12)],
        "cameras.json width 0": [_inria_entry(width=0)],
        "cameras.json height string": [_inria_entry(height="tall")],
        "cameras.json empty list": [],
        "cameras.json entry not a map": [3],
        "cameras.json lacks fx": [{k: v for k, v in _inria_entry().items() if k != "fx"}],
        "cameras.json short rotation": [_inria_entry(rotation=[[1.0, 0.0]])],
        "transforms.json camera_angle_x 0": {"camera_angle_x": 0.0, "w": 32, "h": 24, "frames": [_frame()]},
        "transforms.json camera_angle_x 4": {"camera_angle_x": 4.0, "w": 32, "h": 24, "frames": [_frame()]},
        "transforms.json camera_angle_x negative": {
            "camera_angle_x": -0.5,
            "w": 32,
            "h": 24,
            "frames": [_frame()],
        },
        "transforms.json camera_angle_y 0": {
            "camera_angle_x": 0.7,
            "camera_angle_y": 0.0,
            "w": 32,
            "h": 24,
            "frames": [_frame()],
        },
        "transforms.json fl_x 0": {"fl_x": 0.0, "w": 32, "h": 24, "frames": [_frame()]},
        "transforms.json w Infinity": {"fl_x": 20.0, "w": math.inf, "h": 24, "frames": [_frame()]},
        "transforms.json w NaN": {"fl_x": 20.0, "w": math.nan, "h": 24, "frames": [_frame()]},
        "transforms.json frames empty": {"fl_x": 20.0, "w": 32, "h": 24, "frames": []},
        "transforms.json k1 string": {"fl_x": 20.0, "w": 32, "h": 24, "k1": "x", "frames": [_frame()]},
        "transforms.json matrix 2x2": {
            "fl_x": 20.0,
            "w": 32,
            "h": 24,
            "frames": [_frame(transform_matrix=[[1, 0], [0, 1]])],
        },
        "transforms.json truncated JPEG": {
            "camera_angle_x": 0.7,
            "frames": [_frame(file_path="./trunc")],
        },
        "transforms.json JPEG zero-length segment": {
            "camera_angle_x": 0.7,
            "frames": [_frame(file_path="./zeroseg")],
        },
        "transforms.json truncated PNG": {
            "camera_angle_x": 0.7,
            "frames": [_frame(file_path="./short")],
        },
    }
    out = {}
    for i, (name, body) in enumerate(files.items()):
        sub = d / f"c{i:02d}"
        sub.mkdir(exist_ok=True)
        fname = "cameras.json" if name.startswith("cameras.json") else "transforms.json"
        p = sub / fname
        p.write_text(json.dumps(body))
        jpeg = imagecodecs.jpeg8_encode(np.zeros((24, 32, 3), np.uint8))
        (sub / "trunc.jpg").write_bytes(jpeg[:6])  # SOI and an APP0 marker whose length runs off the end
        (sub / "zeroseg.jpg").write_bytes(b"\xff\xd8\xff\xe0\x00\x00" + b"\x00" * 16)
        (sub / "short.png").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
        out[name] = p
    colmap = d / "colmap_f0"
    colmap.mkdir(exist_ok=True)
    (colmap / "cameras.txt").write_text("1 PINHOLE 32 24 0 0 16 12\n")
    (colmap / "images.txt").write_text("1 1 0 0 0 0 0 3 1 a.png\n\n")
    out["COLMAP focal 0"] = colmap
    empty = d / "colmap_empty"
    empty.mkdir(exist_ok=True)
    (empty / "cameras.txt").write_text("1 PINHOLE 32 24 20 20 16 12\n")
    (empty / "images.txt").write_text("# no images\n")
    out["COLMAP no images"] = empty
    big = d / "colmap_wide"
    big.mkdir(exist_ok=True)
    (big / "cameras.txt").write_text(f"1 PINHOLE {10**10} 24 20 20 16 12\n")
    (big / "images.txt").write_text("1 1 0 0 0 0 0 3 1 a.png\n\n")
    out["COLMAP width 1e10"] = big
    return out


def camera_cases(scene: Path, tmp: Path) -> Iterator[Case]:
    out = tmp / "cam_out.gspc"
    for name, path in write_camera_files(tmp).items():
        args = ["encode", str(scene), "-o", str(out), "--cameras", str(path), "--check-iterations", "0"]
        yield Case("camera files (encode --cameras)", name, args, out)
    rdir = tmp / "cam_renders"
    for name, path in list(write_camera_files(tmp).items())[:6]:
        yield Case(
            "camera files (render --cameras)",
            name,
            ["render", str(scene), "-o", str(rdir), "--cameras", str(path)],
            rdir,
        )


# ------------------------------------------------------------------------------------- scene values


def scene_value_cases(scene: Path, tmp: Path) -> Iterator[Case]:
    """Finite scene values too large for the codec to code at any preset (their symbols would outgrow an
    entropy model's window): once an internal error, a wrapped cast or a 395 GiB allocation."""
    out = tmp / "value_out.gspc"
    for prop, value in [("scale_0", 1e30), ("f_dc_1", -1e6), ("f_rest_0", 3e9), ("f_rest_2", 1e30)]:
        ply = PlyData.read(str(scene))
        ply["vertex"].data[prop][0] = value
        path = tmp / f"value_{prop}.ply"
        ply.write(str(path))
        yield Case("scene values (encode)", f"{prop} = {value:g}", _small_encode(path, out), out)


# --------------------------------------------------------------------------------------- .gspc headers

BAD_TYPES: list[object] = ["x", {"a": 1}, [1, 2], None, True]
BAD_NUMBERS: list[object] = [math.nan, math.inf, -math.inf]
# Finite floats too large for any field: a quantiser step or position field this large decoded infinite
# values or every Gaussian onto one point (issue 50).
HUGE_FLOATS: list[float] = [3.4e38, 1e300]


def _paths(meta: dict) -> Iterator[tuple[tuple, object]]:
    """(key path, value) of every field the decoder reads."""
    for section in ("attributes", "side_info", "scene"):
        stack = [((section,), meta[section])]
        while stack:
            path, v = stack.pop()
            yield path, v
            if isinstance(v, dict):
                stack.extend((path + (k,), x) for k, x in v.items())
            elif isinstance(v, list) and not (path[-1] == "views"):
                stack.extend((path + (i,), x) for i, x in enumerate(v))


# Header fields the decoder does not read (informative): mutating them must not be refused.
_UNREAD = {("scene", "source_gaussians"), ("encoder",)}
# Fields with a default: removing them is allowed.
_OPTIONAL = {
    ("side_info", "restorer"),
    ("side_info", "refine_iterations"),
    ("scene",),
    ("scene", "num_gaussians"),
    ("scene", "sh_degree"),
}


def _set(meta: dict, path: tuple, value: object, delete: bool = False) -> dict:
    m = copy.deepcopy(meta)
    parent = m
    for k in path[:-1]:
        parent = parent[k]
    if delete:
        if isinstance(parent, list):
            del parent[path[-1]]
        else:
            del parent[path[-1]]
    else:
        parent[path[-1]] = value
    return m


def header_mutations(meta: dict) -> Iterator[tuple[str, dict]]:
    """(description, mutated header): each one a header the decoder must refuse."""
    for path, v in _paths(meta):
        if path in _UNREAD:
            continue
        where = ".".join(str(p) for p in path)
        if path not in _OPTIONAL:
            yield f"{where} missing", _set(meta, path, None, delete=True)
        if isinstance(v, bool) or v is None:
            continue
        if isinstance(v, (int, float)):
            for bad in BAD_TYPES:
                yield f"{where} = {bad!r}", _set(meta, path, bad)
            for bad in BAD_NUMBERS:
                yield f"{where} = {bad!r}", _set(meta, path, bad)
            if isinstance(v, float):
                for bad in HUGE_FLOATS:
                    yield f"{where} = {bad!r}", _set(meta, path, bad)
            if not (len(path) >= 3 and path[-2] == "lo"):  # any finite lo is a position
                yield f"{where} = -1", _set(meta, path, -1)
        elif isinstance(v, str):
            for bad in (7, 1.5, {"a": 1}, [1], None, ""):
                yield f"{where} = {bad!r}", _set(meta, path, bad)
        elif isinstance(v, list):
            if v:
                yield f"{where} short", _set(meta, path, v[:-1])
            yield f"{where} long", _set(meta, path, [*v, 0.5])
            yield f"{where} = 'x'", _set(meta, path, "x")
            yield f"{where} = {{}}", _set(meta, path, {})
        elif isinstance(v, dict):
            yield f"{where} = []", _set(meta, path, [])
            yield f"{where} = 'x'", _set(meta, path, "x")
            yield f"{where} = 0", _set(meta, path, 0)
    # Specific huge asks.
    for name, value in {
        "refine_iterations 1e12": 10**12,
        "refine_iterations 2^63": 2**63 - 1,
        "refine_iterations 100001": 100_001,
    }.items():
        yield name, _set(meta, ("side_info", "refine_iterations"), value)
    yield "attributes.n 2^62", _set(meta, ("attributes", "n"), 2**62)
    lo = meta["attributes"]["position"]["lo"]
    yield (
        "attributes.position.lo.0 = 2^64 (grid under binary32's resolution)",
        _set(meta, ("attributes", "position", "lo"), [2.0**64, *lo[1:]]),
    )
    yield "attributes.sh_degree 4", _set(meta, ("attributes", "sh_degree"), 4)
    yield "side_info.views not a list", _set(meta, ("side_info", "views"), {"a": 1})


def precision_mutations(meta: dict) -> Iterator[tuple[str, dict]]:
    """(description, mutated header) of a version-4 header (spec 10.13): header_mutations' of its classes
    array, its first map and that map's first SH step (the others are alike), and version 1 over its PREC
    and bins; each one a header the decoder must refuse."""
    alike = re.compile(r"attributes\.classes\.([1-9]|0\.sh_steps\.[1-9])")
    for desc, m in header_mutations(meta):
        if desc.startswith("attributes.classes") and not alike.match(desc):
            yield desc, m
    yield "attributes.version 1 over PREC and bins", _set(meta, ("attributes", "version"), 1)


def precision_base(base: Path, tmp: Path) -> Path:
    """A version-4 file of 3 precision classes of 4 identical Gaussians each, with the base file's header
    otherwise (tools/amplification_cases.py): the file precision_mutations breaks."""
    import amplification_cases as amp

    header = amp.precision_header(container.read(base).header, 3)
    chunks = amp.precision_chunks(header["attributes"], [4, 4, 4])
    return amp.write_gspc(tmp / "precision_base.gspc", header, 12, chunks)


def _views_10(records: list[dict], width: int, height: int, count: int) -> list[dict]:
    """Side-information views in the 1.0 header form, each ``width`` x ``height``, no residual."""
    cam = dict(records[0]["camera"])
    cam.update(width=width, height=height)
    return [{"camera": dict(cam)} for _ in range(count)]


def side_mutations(meta: dict, chunks: list[container.Chunk]) -> Iterator[tuple[str, dict, list]]:
    """(description, header, chunks) with side-information views that ask for too many pixels, and residual
    images whose codestream declares a size that is not their view's."""
    base = [c for c in chunks if c.type != "SIDE"]
    side = next(c for c in chunks if c.type == "SIDE")
    unpacked = unpack_side(side.payload)
    records, images = [v.to_dict() for v in unpacked.views], unpacked.images

    def with_views(views: list[dict], imgs: dict[int, bytes]) -> list:
        side = pack_side([ViewRecord.from_dict(v) for v in views], imgs)
        return [*base, container.Chunk("SIDE", side)]

    bare = [{"camera": dict(records[0]["camera"])}]
    for desc, (w, h, n) in {
        "SIDE view 65536 x 65536": (65536, 65536, 1),
        "SIDE view 8192 x 8192": (8192, 8192, 1),
        "SIDE 64 views of 2048 x 2048": (2048, 2048, 64),
        "SIDE 100 views of 65536 x 4": (65536, 4, 1),
    }.items():
        views = []
        for _ in range(n):
            cam = dict(bare[0]["camera"])
            cam.update(width=w, height=h)
            views.append({"camera": cam})
        if desc.endswith("65536 x 4"):
            views = views * 100  # 26 Mpixel in an 8 KB file: over its budget, under every per-view limit
        yield desc, meta, with_views(views, {})
    # 1.0 layout: the same asks as header records.
    for desc, (w, h, n) in {
        "1.0 views 65536 x 65536": (65536, 65536, 1),
        "1.0 views 100 x 4096 x 4096": (4096, 4096, 100),
        "1.0 view width 2^40": (2**40, 4, 1),
        "1.0 view width 0": (0, 4, 1),
        "1.0 view width 1.5": (1.5, 4, 1),
    }.items():
        m = copy.deepcopy(meta)
        m["side_info"]["views"] = _views_10(records, w, h, n)
        yield desc, m, base
    m = copy.deepcopy(meta)
    m["side_info"]["views"] = [{"camera": "x"}]
    yield "1.0 view camera 'x'", m, base
    m = copy.deepcopy(meta)
    m["side_info"]["views"] = [{"camera": {**records[0]["camera"], "intrinsics": b"\x00" * 16}}]
    yield "1.0 view focal 0", m, base
    m = copy.deepcopy(meta)
    m["side_info"]["views"] = [{"camera": {**records[0]["camera"], "intrinsics": b"\x00" * 3}}]
    yield "1.0 view short intrinsics", m, base
    # Residual images whose codestream declares another size than the view's (decoded before: issue 15).
    k = min(images)
    for desc, shape in {
        "residual JXL declares 4096 x 4096": (4096, 4096),
        "residual JXL declares 1 x 1": (1, 1),
    }.items():
        big = imagecodecs.jpegxl_encode(np.full((*shape, 3), 128, np.uint8), distance=8.0, effort=1)
        yield desc, meta, with_views(records, {**images, k: big})
    # The 1.0 layout: residual records in the header, one RESI chunk per image; each record field mutated.
    views10 = copy.deepcopy(records)
    resi = [container.Chunk("RESI", img, index=i) for i, img in images.items()]
    for field, bads in {
        "codec": [[1], 7, "png", None],
        "shape": [[24], ["a", "b"], [2**40, 2**40], "x"],
        "gain": [math.nan, "x", 0.0, -1.0, math.inf],
        "offset": ["x", None],
        "scale": [0, "x", 99, [2]],
        "full_shape": [[2**40, 1], "x", [0, 0]],
    }.items():
        for bad in bads:
            m = copy.deepcopy(meta)
            vs = copy.deepcopy(views10)
            vs[k]["residual"][field] = bad
            m["side_info"]["views"] = vs
            yield f"1.0 residual {field} = {bad!r}", m, [*base, *resi]
    yield "residual not JXL", meta, with_views(records, {**images, k: b"\x00" * 40})
    yield "residual JXL cut to 3 bytes", meta, with_views(records, {**images, k: images[k][:3]})
    yield "residual JXL cut after its size header (restoring)", meta, with_views(records, cut_images(images))


def cut_images(images: dict[int, bytes]) -> dict[int, bytes]:
    """The residual images with the first one cut to half its bytes: its size header intact, its pixels not
    (spec 10.7: decoded without restoration, refused with)."""
    k = min(images)
    return {**images, k: images[k][: len(images[k]) // 2]}


def unrestored_cases(base: Path, tmp: Path) -> Iterator[Case]:
    """A residual image cut after its size header: a decode that does not restore reads only its header and
    decodes (spec 10.7); the restoring decode refuses it (side_mutations)."""
    c = container.read(base)
    side = unpack_side(next(ch for ch in c.chunks if ch.type == "SIDE").payload)
    chunks = [ch for ch in c.chunks if ch.type != "SIDE"]
    chunks.append(container.Chunk("SIDE", pack_side(side.views, cut_images(side.images))))
    path = tmp / "residual_cut.gspc"
    container.write(path, c.header, chunks)
    out = tmp / "unrestored.ply"
    for extra in (["--no-restore"], ["--no-restore", "--no-refine"]):
        args = ["decode", str(path), "-o", str(out), *extra]
        name = f"residual JXL cut after its size header, {' '.join(extra)}"
        yield Case(".gspc residual images, not restored", name, args, out, "ok")


def gspc_files(base: Path, tmp: Path) -> list[tuple[str, str, Path]]:
    """(category, name, path) of hostile .gspc files built from a valid one; CRCs are right."""
    c = container.read(base)
    out = []
    d = tmp / "hostile_gspc"
    d.mkdir(exist_ok=True)
    for i, (desc, meta) in enumerate(header_mutations(c.header)):
        p = d / f"h{i:04d}.gspc"
        container.write(p, meta, c.chunks)
        out.append(("header fields", desc, p))
    for i, (desc, meta, chunks) in enumerate(side_mutations(c.header, c.chunks)):
        p = d / f"s{i:04d}.gspc"
        container.write(p, meta, chunks)
        out.append(("side-information views and images", desc, p))
    v4 = container.read(precision_base(base, tmp))
    for i, (desc, meta) in enumerate(precision_mutations(v4.header)):
        p = d / f"p{i:04d}.gspc"
        container.write(p, meta, v4.chunks)
        out.append(("header fields of version 4", desc, p))
    return out


def gspc_cases(base: Path, tmp: Path) -> Iterator[Case]:
    out = tmp / "hostile_out.ply"
    for category, name, path in gspc_files(base, tmp):
        yield Case(f".gspc {category}", name, ["decode", str(path), "-o", str(out)], out)


# --------------------------------------------------------------------------------------------- SOG


def _zip_with_claimed_size(src: Path, dst: Path, member: str, size: int) -> None:
    """Copy of a zip whose ``member`` claims ``size`` uncompressed bytes in its local and central headers
    (a lie zipfile would catch only while inflating it)."""
    data = bytearray(src.read_bytes())
    with zipfile.ZipFile(src) as z:
        struct.pack_into("<I", data, z.getinfo(member).header_offset + 22, size)
    pos = data.find(b"PK\x01\x02")
    while pos >= 0:
        (nlen,) = struct.unpack_from("<H", data, pos + 28)
        if data[pos + 46 : pos + 46 + nlen].decode() == member:
            struct.pack_into("<I", data, pos + 24, size)
        pos = data.find(b"PK\x01\x02", pos + 4)
    dst.write_bytes(bytes(data))


def sog_cases(tmp: Path, make_sog) -> Iterator[Case]:
    """SOG archives whose members ask for too much. ``make_sog(path)`` writes a valid tiny SOG zip."""
    good = tmp / "good.sog"
    make_sog(good)
    out = tmp / "sog_out.ply"
    bomb = tmp / "bomb_needed.sog"
    with zipfile.ZipFile(good) as z, zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as w:
        for info in z.infolist():
            data = z.read(info)
            if info.filename == "means_l.webp":
                data = data + bytes(48 << 20)  # 48 MiB of zeros after the image: deflates ~1000:1
            w.writestr(info.filename, data)
    yield Case("SOG archives", "needed member inflates 1000:1", ["info", str(bomb)], None)
    yield Case(
        "SOG archives", "needed member inflates 1000:1 (convert)", ["convert", str(bomb), "-o", str(out)], out
    )
    lie = tmp / "lie_meta.sog"
    _zip_with_claimed_size(good, lie, "meta.json", (1 << 32) - 1)
    yield Case("SOG archives", "meta.json claims 4 GiB", ["info", str(lie)], None)
    lie2 = tmp / "lie_map.sog"
    _zip_with_claimed_size(good, lie2, "quats.webp", (1 << 32) - 1)
    yield Case("SOG archives", "map claims 4 GiB", ["convert", str(lie2), "-o", str(out)], out)
    bounds = tmp / "bounds.sog"
    make_sog(bounds, meta_override=lambda m: m["means"].update(mins=[-1e308] * 3, maxs=[1e308] * 3))
    yield Case("SOG archives", "position bounds +-1e308", ["info", str(bounds)], None)
    huge = tmp / "huge_map.sog"
    flat = imagecodecs.webp_encode(np.zeros((4096, 4096, 4), np.uint8), lossless=True)
    with zipfile.ZipFile(good) as z, zipfile.ZipFile(huge, "w", zipfile.ZIP_STORED) as w:
        for info in z.infolist():
            w.writestr(info.filename, flat if info.filename == "sh0.webp" else z.read(info))
    yield Case("SOG archives", "10-Gaussian scene with a 4096 x 4096 map", ["info", str(huge)], None)


def unneeded_bomb(tmp: Path, make_sog) -> Path:
    """A valid SOG with an extra member of 64 MiB of zeros that no reader needs: must read fast."""
    p = tmp / "bomb_unneeded.sog"
    make_sog(p)
    with zipfile.ZipFile(p, "a", zipfile.ZIP_DEFLATED) as z:
        z.writestr("junk.bin", bytes(64 << 20))
    return p


# ----------------------------------------------------------------------------- work out of proportion


def amplification_cases(base: Path, tmp: Path) -> Iterator[Case]:
    """Files at each size-bounded limit and just past it (tools/amplification_cases.py), and the base file
    naming a refinement of 100,000 iterations for its 300 Gaussians (the decoder runs at most
    max(1000, n))."""
    import amplification_cases as amp

    header = container.read(base).header
    d = tmp / "amplification"
    d.mkdir(exist_ok=True)
    out = tmp / "amp_out.ply"
    for category, make in (
        ("work: Gaussians per coded bit", amp.count_files),
        ("work: entropy-model tables", amp.table_files),
        ("work: entropy-model lists", amp.model_list_files),
        ("work: precision classes (version 4)", amp.precision_files),
    ):
        for name, path, ok in make(header, d):
            args = ["decode", str(path), "-o", str(out), "--no-restore", "--no-refine"]
            yield Case(category, name, args, out, "ok" if ok else "refused")
    for name, path, ok in amp.work_files(header, d):
        args = ["decode", str(path), "-o", str(out)]
        yield Case("work: render, restoration and refinement", name, args, out, "ok" if ok else "refused")
    c = container.read(base)
    long = d / "refine_100000.gspc"
    meta = copy.deepcopy(c.header)
    meta["side_info"]["refine_iterations"] = 100_000
    container.write(long, meta, c.chunks)
    name = "300 Gaussians naming 100,000 refinement iterations (runs 1000)"
    yield Case("work: default refinement", name, ["decode", str(long), "-o", str(out)], out, "ok")
    for name, path, ok in amp.scene_files(d):
        args = ["info", str(path)] if ok else ["convert", str(path), "-o", str(out)]
        yield Case(
            "work: scene file counts (SPZ, SOG, PLY)",
            name,
            args,
            None if ok else out,
            "ok" if ok else "refused",
        )


# ------------------------------------------------------------------------------------------ outputs


def output_cases(scene: Path, gspc_file: Path, tmp: Path) -> Iterator[Case]:
    """-o naming a character device (written as a stream), a folder, a path ending in '/', a socket."""
    import socket

    folder = tmp / "an_output_folder"
    folder.mkdir(exist_ok=True)
    sock = tmp / "a.sock"
    if not sock.exists():
        with socket.socket(socket.AF_UNIX) as s:
            s.bind(str(sock))  # the node stays after the socket closes
    yield Case("outputs", "convert -o /dev/null", ["convert", str(scene), "-o", os.devnull], None, "ok")
    yield Case(
        "outputs",
        "decode -o /dev/null",
        ["decode", str(gspc_file), "-o", os.devnull, "--iterations", "1"],
        None,
        "ok",
    )
    for command, src in (("convert", scene), ("encode", scene), ("decode", gspc_file)):
        yield Case(
            "outputs",
            f"{command} -o DIR/name/",
            [command, str(src), "-o", f"{tmp}/slash_out/"],
            tmp / "slash_out",
        )
        yield Case(
            "outputs", f"{command} -o an existing folder", [command, str(src), "-o", str(folder)], None
        )
        yield Case("outputs", f"{command} -o a socket", [command, str(src), "-o", str(sock)], None)


# -------------------------------------------------------------------------------- environment, cameras


def environment_cases(scene: Path) -> Iterator[Case]:
    """GSPC_THREADS values: refused in one line, or (beyond the cores) clamped to them."""
    for value in ("0", "-1", "text", "1.5", "", "1e3"):
        expect = "ok" if value == "" else "refused"
        yield Case(
            "environment: GSPC_THREADS",
            repr(value),
            ["info", str(scene)],
            None,
            expect,
            {"GSPC_THREADS": value},
        )
    for value in (str(2**40), "10000"):
        yield Case(
            "environment: GSPC_THREADS", value, ["info", str(scene)], None, "ok", {"GSPC_THREADS": value}
        )


def camera_input_cases(scene: Path, tmp: Path) -> Iterator[Case]:
    """COLMAP quaternions huge (rotations, normalised without overflow), non-finite or zero (refused), and a
    camera with lens distortion (one warning line)."""
    d = tmp / "colmap_q"
    for i, (name, q, ok) in enumerate(
        (
            ("quaternion (1e300, 1e300, 0, 0)", "1e300 1e300 0 0", True),
            ("quaternion (inf, 0, 0, 0)", "inf 0 0 0", False),
            ("quaternion (nan, 1, 0, 0)", "nan 1 0 0", False),
            ("quaternion (0, 0, 0, 0)", "0 0 0 0", False),
            ("OPENCV camera with distortion", "1 0 0 0", True),
        )
    ):
        sub = d / f"m{i}"
        sub.mkdir(parents=True, exist_ok=True)
        model = "OPENCV 32 24 30 30 16 12 0.1 0 0 0" if "OPENCV" in name else "PINHOLE 32 24 30 30 16 12"
        (sub / "cameras.txt").write_text(f"1 {model}\n")
        (sub / "images.txt").write_text(f"1 {q} 0 0 3 1 a.png\n\n")
        rdir = tmp / f"cam_q_{i}"
        args = ["render", str(scene), "-o", str(rdir), "--cameras", str(sub), "--max-side", "16"]
        yield Case("camera input: COLMAP poses", name, args, rdir, "ok" if ok else "refused")


# ------------------------------------------------------------------------- values named where they are read


def read_value_cases(scene: Path, tmp: Path) -> Iterator[Case]:
    """Values that once passed their reader and warned or failed in arithmetic far from it (issue 50): each
    is named by its reader in one line before anything warns, or (a quaternion: a direction whatever its
    length) read as what it means. tests/test_hostile.py runs them under ``python -W error``."""
    from plyfile import PlyElement

    d = tmp / "read_values"
    d.mkdir(exist_ok=True)
    ply = PlyData.read(str(scene))
    for i in range(4):
        ply["vertex"].data[f"rot_{i}"][:2] = 3e38
    huge = d / "quaternion_3e38.ply"
    ply.write(str(huge))
    out = tmp / "read_value_out.gspc"
    yield Case(
        "values named where read: scenes",
        "quaternion (3e38, 3e38, 3e38, 3e38)",
        _small_encode(huge, out),
        out,
        "ok",
    )
    geometry = [(f"{b}_{a}", "f4") for b in ("min", "max") for a in "xyz"]
    geometry += [(f"{b}_scale_{a}", "f4") for b in ("min", "max") for a in "xyz"]
    for name, packed_type, bound in (
        ("compressed PLY: float32 packed_position holding NaN", "f4", 1.0),
        ("compressed PLY: chunk bound max_x = inf", "u4", math.inf),
    ):
        chunk = np.zeros(1, dtype=geometry)
        for a in "xyz":
            chunk[f"max_{a}"], chunk[f"min_scale_{a}"], chunk[f"max_scale_{a}"] = 1.0, -5.0, -4.0
        chunk["max_x"] = bound
        fields = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
        vertex = np.zeros(256, dtype=[(f, packed_type) for f in fields])
        vertex["packed_color"] = 0xFF8080FF
        if packed_type == "f4":
            vertex["packed_position"][3] = np.nan
        path = d / f"compressed_{packed_type}.ply"
        PlyData([PlyElement.describe(chunk, "chunk"), PlyElement.describe(vertex, "vertex")]).write(str(path))
        convert_out = tmp / "read_value_out.ply"
        yield Case(
            "values named where read: scenes",
            name,
            ["convert", str(path), "-o", str(convert_out)],
            convert_out,
        )
    frames = [_frame(transform_matrix=[[1, 0, 0, 1e200], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]])]
    frames += [_frame(file_path=f"./s{k}") for k in range(3)]
    far = d / "far" / "transforms.json"
    far.parent.mkdir(exist_ok=True)
    far.write_text(json.dumps({"camera_angle_x": 0.7, "w": 32, "h": 24, "frames": frames}))
    inria = d / "inria" / "cameras.json"
    inria.parent.mkdir(exist_ok=True)
    inria.write_text(json.dumps([_inria_entry(position=[1e200, 0.0, -3.0])]))
    colmap = d / "colmap"
    colmap.mkdir(exist_ok=True)
    (colmap / "cameras.txt").write_text("1 PINHOLE 32 24 30 30 16 12\n")
    (colmap / "images.txt").write_text("1 1 0 0 0 1e200 0 3 1 a.png\n\n")
    rdir = tmp / "read_value_renders"
    for name, cams in (
        ("transforms.json translation 1e200", far),
        ("cameras.json position 1e200", inria),
        ("COLMAP translation 1e200", colmap),
    ):
        render = ["render", str(scene), "-o", str(rdir), "--cameras", str(cams), "--max-side", "16"]
        yield Case("values named where read: cameras", f"{name} (render)", render, rdir)
    args = _small_encode(scene, out) + ["--cameras", str(far)]
    yield Case("values named where read: cameras", "transforms.json translation 1e200 (encode)", args, out)
