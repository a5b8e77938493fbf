"""Files crafted at each limit of gspc/limits.py that bounds work by a file's size (issue 26), and just
past it: Gaussians per coded bit, entropy-model tables and model lists per payload byte, and the Gaussians an
SPZ or SOG scene may declare. At the edge a file decodes (or reads); one step past it is refused in one line
before anything of its size is allocated. tools/hostile_cases.py turns them into CLI cases.

Every .gspc file here codes identical Gaussians (each ECM column has one-value models, which cost no bits),
padded where a case needs more payload bytes with range-coder words the decoder never reads (spec 10.0:
words left over are ignored): the cheapest way to ask for the most work.
"""

from __future__ import annotations

import gzip
import json
import struct
import zipfile
from pathlib import Path

import imagecodecs
import msgpack
import numpy as np
import zstandard

from gspc import limits
from gspc.format import container
from gspc.scene import num_sh_rest

ATTRIBUTES = ("POSN", "PREC", "OPAC", "SCAL", "ROTN", "SHDC", "SHRS")
ONE_VALUE = [[1, 0]] * 15  # the 15 model specs of a column whose every row is 0 (spec 10.0)


def ecm(m: int, columns: list[tuple[int, list]], words: bytes = b"") -> bytes:
    """An entropy-coded matrix payload of ``m`` rows: one (mode, 15 specs) per column, then ``words``."""
    models = zstandard.ZstdCompressor(level=19).compress(
        msgpack.packb([[mode, specs] for mode, specs in columns])
    )
    return msgpack.packb([m, len(columns), models, words], use_bin_type=True)


def constant_chunks(meta: dict, n: int, opac: bytes | None = None, pad: int = 0) -> dict[str, bytes]:
    """Attribute payloads of ``n`` identical Gaussians for the codec section ``meta`` (its version, grid
    and SH degree); ``opac`` replaces the OPAC matrix; ``pad`` bytes of unread words go after OPAC's."""
    k = num_sh_rest(meta["sh_degree"])
    curve = ecm(n, [(0, ONE_VALUE)])  # every position code 0: all Gaussians in voxel 0
    far = meta["position"].get("far_count")
    posn = (
        [curve, b""]
        if far is None
        else [ecm(n - far, [(0, ONE_VALUE)]), b"", ecm(far, [(0, ONE_VALUE)]), b""]
    )
    rotation = [(0, ONE_VALUE), *[(0, [[1, meta["rotation_levels"] // 2]] * 15)] * 3]
    chunks = {
        "POSN": msgpack.packb(posn, use_bin_type=True),
        "OPAC": opac if opac is not None else ecm(n, [(0, ONE_VALUE)], bytes(pad)),
        "SCAL": ecm(n, [(0, ONE_VALUE)] * 3),
        "ROTN": ecm(n, rotation),
        "SHDC": ecm(n, [(0, ONE_VALUE)] * 3),
    }
    if k:
        values = msgpack.packb([0, 3 * k, b"", b""], use_bin_type=True)
        chunks["SHRS"] = msgpack.packb([ecm(n, [(0, ONE_VALUE)]), values], use_bin_type=True)
    return chunks


def write_gspc(path: Path, header: dict, n: int, chunks: dict[str, bytes]) -> Path:
    """A file of the base ``header`` with attributes.n = ``n`` and these attribute chunks (and SIDE chunk, if
    any: none of the base's side information)."""
    meta = json.loads(json.dumps(header, default=lambda b: b.hex()))  # a deep copy (no bins in these maps)
    meta["attributes"] = dict(header["attributes"], n=n)
    meta["scene"] = dict(meta.get("scene", {}), num_gaussians=n, sh_degree=header["attributes"]["sh_degree"])
    meta["side_info"] = {k: v for k, v in header["side_info"].items() if k != "views"}
    types = [*ATTRIBUTES, "SIDE"]
    container.write(path, meta, [container.Chunk(t, chunks[t]) for t in types if t in chunks])
    return path


def payload_bytes(chunks: dict[str, bytes]) -> int:
    return sum(len(p) for p in chunks.values())


def count_files(header: dict, d: Path) -> list[tuple[str, Path, bool]]:
    """(name, file, decodes) at the Gaussian-count rule's floor and per-byte edge, one past each, and the
    issue's 2^20 Gaussians in 17 KB."""
    a = header["attributes"]
    out = []
    n = limits.GAUSSIAN_FLOOR
    for name, count in (("at the floor: 65,536 Gaussians", n), ("past the floor: 65,537", n + 1)):
        out.append(
            (
                name,
                write_gspc(d / f"count_{count}.gspc", header, count, constant_chunks(a, count)),
                count == n,
            )
        )
    # Padded to ~150 KB: the per-byte term decides (8 P / 12 > 65,536).
    probe = constant_chunks(a, 1 << 17, pad=150_000)
    edge = limits.max_coded_gaussians(payload_bytes(probe))
    for name, count in (
        (f"at 12 coded bits per Gaussian: {edge:,} in ~150 KB", edge),
        ("one more", edge + 1),
    ):
        chunks = constant_chunks(a, count, pad=150_000)
        assert limits.max_coded_gaussians(payload_bytes(chunks)) == edge
        out.append((name, write_gspc(d / f"count_{count}.gspc", header, count, chunks), count == edge))
    # The most work per byte this rule allows: SH degree 3 (the widest rows) in a 1 MB file.
    steps = a["sh_steps"] or [a["dc_step"]]
    sh3 = dict(header, attributes=dict(a, sh_degree=3, sh_steps=[steps[0]] * 15))
    probe = constant_chunks(sh3["attributes"], 1 << 20, pad=1_000_000)
    edge = limits.max_coded_gaussians(payload_bytes(probe))
    chunks = constant_chunks(sh3["attributes"], edge, pad=1_000_000)
    path = write_gspc(d / "count_sh3.gspc", sh3, edge, chunks)
    out.append((f"SH 3 at 12 coded bits per Gaussian: {edge:,} in 1 MB", path, True))
    issue = constant_chunks(a, 1 << 20, pad=16_000)
    out.append(
        (
            "2^20 Gaussians in 17 KB (issue 26)",
            write_gspc(d / "count_issue.gspc", header, 1 << 20, issue),
            False,
        )
    )
    return out


def _opac_with_tables(n: int, windows: list[int], pad: int = 0) -> bytes:
    """An OPAC matrix whose 15 specs are geometric models over windows 0 .. w - 1 (one per bucket, unused
    ones one-value): every row decodes to 0 from the all-zero words."""
    specs = [[2, 0, w - 1, 0, 0, 0] for w in windows] + [[1, 0]] * (15 - len(windows))
    return ecm(n, [(0, specs)], bytes(pad))


def _windows(total: int) -> list[int]:
    """At most 15 windows of 2 .. 2^22 symbols summing to ``total``."""
    out = []
    while total > 0:
        w = min(limits.MODEL_TABLE_FLOOR, total if total - limits.MODEL_TABLE_FLOOR != 1 else total - 2)
        out.append(w)
        total -= w
    assert len(out) <= 15 and min(out) >= 2
    return out


def table_files(header: dict, d: Path) -> list[tuple[str, Path, bool]]:
    """(name, file, decodes) with OPAC tables at the floor of 2^22 entries and at 16 per payload byte, one
    entry past each, and the issue's 15 widest geometric models in each of 3 columns."""
    a, n = header["attributes"], 1000
    out = []
    for label, pad in (("floor: 2^22 entries", 0), ("16 per byte: ~6.4M entries in ~400 KB", 400_000)):
        for past in (0, 1):
            opac = _opac_with_tables(n, _windows(limits.MODEL_TABLE_FLOOR), pad)
            for _ in range(4):  # the payload's size moves with its models' bytes: settle
                opac = _opac_with_tables(n, _windows(limits.max_model_entries(len(opac)) + past), pad)
            entries = sum(_windows(limits.max_model_entries(len(opac)) + past))
            assert entries - limits.max_model_entries(len(opac)) == past
            name = f"tables {'past' if past else 'at'} the {label}"
            path = d / f"tables_{len(out)}.gspc"
            out.append((name, write_gspc(path, header, n, constant_chunks(a, n, opac=opac)), not past))
    widest = [[2, 0, limits.MODEL_TABLE_FLOOR - 1, 0, 0, 0]] * 15
    chunks = constant_chunks(a, n)
    chunks["SCAL"] = ecm(n, [(0, widest)] * 3)
    out.append(
        (
            "45 models of 2^22 symbols in a 1 KB matrix (issue 26)",
            write_gspc(d / "tables_issue.gspc", header, n, chunks),
            False,
        )
    )
    return out


def _kind3_list(size: int) -> bytes:
    """A one-column model list of exactly ``size`` msgpack bytes: one explicit model (kind 3) in bucket 12,
    which every level-0 row uses, the other buckets one-value."""

    def packed(weights: int, twos: int) -> bytes:
        spec = [3, 0, weights - 1, *([128] * twos), *([1] * (weights - twos))]
        return msgpack.packb([[0, [[1, 0]] * 12 + [spec] + [[1, 0]] * 2]])

    base = len(packed(2, 0))
    weights = size - base + 2  # one byte per weight of 1
    for _ in range(4):  # the array's length prefix grows with it: settle
        over = len(packed(weights, 0)) - size
        weights -= over
    twos = size - len(packed(weights, 0))  # a weight of 128 takes two bytes
    raw = packed(weights, twos)
    assert len(raw) == size, (len(raw), size)
    return raw


def model_list_files(header: dict, d: Path) -> list[tuple[str, Path, bool]]:
    """(name, file, decodes) with an OPAC model list of exactly the floor of 2^16 bytes, one byte more, and
    the old cap's 2^26 bytes from a small frame (issue 26: 3.6 KB took 17.7 s and 1.07 GB)."""
    a, n = header["attributes"], 1000
    out = []
    for name, size, ok in (
        ("model list at the floor: 65,536 bytes", limits.MODEL_LIST_FLOOR, True),
        ("model list one byte past the floor", limits.MODEL_LIST_FLOOR + 1, False),
    ):
        models = zstandard.ZstdCompressor(level=19).compress(_kind3_list(size))
        assert limits.max_model_list_bytes(len(models)) == limits.MODEL_LIST_FLOOR
        opac = msgpack.packb([n, 1, models, b""], use_bin_type=True)
        out.append(
            (name, write_gspc(d / f"models_{size}.gspc", header, n, constant_chunks(a, n, opac=opac)), ok)
        )
    raw = msgpack.packb([[0, [[1, 0]] * 14 + [[3, 0, (1 << 22) - 1, *([1] * (1 << 22))]]]])
    models = zstandard.ZstdCompressor(level=19).compress(raw)
    opac = msgpack.packb([n, 1, models, b""], use_bin_type=True)
    name = f"model list of {len(raw):,} bytes from a {len(models):,}-byte frame"
    out.append((name, write_gspc(d / "models_big.gspc", header, n, constant_chunks(a, n, opac=opac)), False))
    return out


# ------------------------------------------------------------------------ precision classes (version 4)


def precision_header(header: dict, classes: int) -> dict:
    """The base header at attribute codec version 4 (spec 10.13) with ``classes`` precision classes, each
    with the section's own quantisers (maps need not differ)."""
    a = header["attributes"]
    steps = {k: a[k] for k in ("opacity_levels", "scale_step", "rotation_levels", "dc_step", "sh_steps")}
    return dict(header, attributes=dict(a, version=4, classes=[steps] * (classes - 1)))


def precision_chunks(
    meta: dict, counts: list[int], tables: dict[str, list[int]] | None = None
) -> dict[str, bytes]:
    """Version-4 payloads of identical Gaussians, ``counts[k]`` of them in class k (in class order), each of
    the section's SH degree; ``tables``: chunk -> per class the window of one unused geometric model (column
    0, bucket 14, which column 0 never uses) in each of the class's matrices of that chunk."""
    from gspc.codec.entropy import encode_matrix

    n, degree = sum(counts), meta["sh_degree"]
    tables = tables or {}

    def matrix(name: str, k: int, columns: list[tuple[int, list]]) -> bytes:
        if not counts[k]:
            return msgpack.packb([0, len(columns), b"", b""], use_bin_type=True)
        if name in tables:
            columns = [(0, [*columns[0][1][:14], [2, 0, tables[name][k] - 1, 0, 0, 0]]), *columns[1:]]
        return ecm(counts[k], columns)

    rotation = [(0, ONE_VALUE), *[(0, [[1, meta["rotation_levels"] // 2]] * 15)] * 3]
    widths = {"OPAC": [(0, ONE_VALUE)], "SCAL": [(0, ONE_VALUE)] * 3, "ROTN": rotation}
    widths["SHDC"] = widths["SCAL"]
    classes = np.repeat(np.arange(len(counts)), counts)
    prec = np.stack([classes, np.full(n, degree)], 1)[:, : 1 if degree == 0 else 2]
    chunks = {
        "POSN": msgpack.packb([ecm(n, [(0, ONE_VALUE)]), b""], use_bin_type=True),
        "PREC": encode_matrix(prec),
    }
    for name, columns in widths.items():
        chunks[name] = msgpack.packb(
            [matrix(name, k, columns) for k in range(len(counts))], use_bin_type=True
        )
    if degree:
        bands = [
            matrix("SHRS", k, [(0, ONE_VALUE)] * 3 * (2 * b + 1))
            for k in range(len(counts))
            for b in range(1, degree + 1)
        ]
        chunks["SHRS"] = msgpack.packb(bands, use_bin_type=True)
    return chunks


def precision_files(header: dict, d: Path) -> list[tuple[str, Path, bool]]:
    """(name, file, decodes) of version-4 files: 16 classes at the Gaussian-count floor, one widest table in
    every matrix of 16 classes (each chunk's matrices share one bound), a chunk's tables at that shared bound
    and one entry past it, 17 classes, and a matrix declaring more rows than its class has."""
    h16 = precision_header(header, 16)
    a, n, ones = h16["attributes"], limits.GAUSSIAN_FLOOR, [1] * 16
    out = [
        (
            "16 classes of 4,096 identical Gaussians: the count floor",
            write_gspc(d / "prec_floor.gspc", h16, n, precision_chunks(a, [n // 16] * 16)),
            True,
        )
    ]
    widest = {t: [limits.MODEL_TABLE_FLOOR] * 16 for t in ("OPAC", "SCAL", "ROTN", "SHDC", "SHRS")}
    path = write_gspc(d / "prec_widest.gspc", h16, 16, precision_chunks(a, ones, widest))
    out.append(
        (f"16 classes, a 2^22-symbol table in every matrix ({path.stat().st_size:,} bytes)", path, False)
    )
    for past in (0, 1):
        # OPAC's 16 one-row matrices with tables summing to the chunk's bound (its floor, 2^22), or one more.
        total = limits.MODEL_TABLE_FLOOR + past
        windows = [total // 16 + (k < total % 16) for k in range(16)]
        chunks = precision_chunks(a, ones, {"OPAC": windows})
        name = (
            f"16 classes, OPAC's tables {'one entry past' if past else 'at'} the chunk's shared bound, 2^22"
        )
        out.append((name, write_gspc(d / f"prec_tables_{past}.gspc", h16, 16, chunks), not past))
    h17 = precision_header(header, 17)
    chunks = precision_chunks(h17["attributes"], [1] * 17)
    out.append(("17 classes (16 class maps)", write_gspc(d / "prec_17.gspc", h17, 17, chunks), False))
    chunks = precision_chunks(a, ones)
    bins = msgpack.unpackb(chunks["SCAL"])
    bins[3] = msgpack.packb([1 << 40, 3, b"", b""], use_bin_type=True)
    chunks["SCAL"] = msgpack.packb(bins, use_bin_type=True)
    name = "a class of 1 Gaussian whose SCAL matrix declares 2^40 rows"
    out.append((name, write_gspc(d / "prec_rows.gspc", h16, 16, chunks), False))
    return out


# ------------------------------------------------------------------------------------------ scene files


def spz_file(path: Path, count: int, noise: int) -> Path:
    """A version-3 SPZ (gzip) of ``count`` SH-0 Gaussians: positions with ``noise`` random low bytes per
    Gaussian (so gzip cannot shrink the file past its 1032:1 rule), everything else zero."""
    rng = np.random.default_rng(0)
    body = bytearray(20 * count)
    positions = np.zeros((count, 9), np.uint8)
    positions[:, :noise] = rng.integers(0, 256, (count, noise), dtype=np.uint8)
    body[: 9 * count] = positions.tobytes()
    head = struct.pack("<IIIBBBB", 0x5053474E, 3, count, 0, 12, 0, 0)
    path.write_bytes(gzip.compress(head + bytes(body), compresslevel=1, mtime=0))
    return path


def sog_file(path: Path, count: int) -> Path:
    """A SOG zip of ``count`` identical Gaussians: constant maps (lossless WebP shrinks them to bytes)."""
    width = 1024
    height = -(-count // width)
    flat = imagecodecs.webp_encode(np.full((height, width, 4), 128, np.uint8), lossless=True)
    quat = imagecodecs.webp_encode(
        np.tile(np.array([128, 128, 128, 252], np.uint8), (height, width, 1)), lossless=True
    )
    meta = {
        "version": 2,
        "count": count,
        "means": {"mins": [0.0] * 3, "maxs": [1.0] * 3, "files": ["means_l.webp", "means_u.webp"]},
        "scales": {"codebook": [-5.0] * 256, "files": ["scales.webp"]},
        "quats": {"files": ["quats.webp"]},
        "sh0": {"codebook": [0.0] * 256, "files": ["sh0.webp"]},
    }
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        for name in ("means_l.webp", "means_u.webp", "scales.webp", "sh0.webp"):
            z.writestr(name, flat)
        z.writestr("quats.webp", quat)
        z.writestr("meta.json", json.dumps(meta))
    return path


def ply_header_file(path: Path, count: int, text: bool) -> Path:
    """A PLY whose header declares ``count`` vertices of 14 float properties, followed by 100 bytes."""
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2"]
    props = "".join(f"property float {p}\n" for p in [*names, "rot_0", "rot_1", "rot_2", "rot_3"])
    form = "ascii" if text else "binary_little_endian"
    path.write_bytes(
        f"ply\nformat {form} 1.0\nelement vertex {count}\n{props}end_header\n".encode() + b"0 " * 50
    )
    return path


def scene_files(d: Path) -> list[tuple[str, Path, bool]]:
    """(name, file, reads) of SPZ and SOG scenes at the scene rule's floor (2^19 Gaussians), one past it, and
    past the 4-bytes-per-Gaussian term; PLY headers declaring more rows than the file holds."""
    floor = limits.SCENE_GAUSSIAN_FLOOR
    out = [
        ("SPZ at the floor: 2^19 Gaussians", spz_file(d / "floor.spz", floor, 1), True),
        ("SPZ one past the floor", spz_file(d / "past.spz", floor + 1, 1), False),
    ]
    big = spz_file(d / "big.spz", 1 << 20, 2)  # about 2.5 bytes per Gaussian: under 4
    assert limits.max_scene_gaussians(big.stat().st_size) < 1 << 20
    out.append((f"SPZ of 2^20 Gaussians in {big.stat().st_size / 1e6:.1f} MB", big, False))
    for text in (False, True):
        kind = "ASCII" if text else "binary"
        path = ply_header_file(d / f"count_{kind}.ply", 10**9, text)
        out.append((f"{kind} PLY declaring 10^9 vertices in 500 bytes", path, False))
    out.append(("SOG at the floor: 2^19 Gaussians", sog_file(d / "floor.sog", floor), True))
    out.append(("SOG one past the floor", sog_file(d / "past.sog", floor + 1), False))
    return out


# ----------------------------------------------------------------- the decoder's render and refinement work


def facing_view(point: list[float], width: int, height: int, distance: float, residual: bool) -> tuple:
    """(view record, residual image or None) of a camera ``distance`` in front of ``point`` looking at it
    (OpenCV axes: along +z), focal length = its width; the residual a constant lossless JPEG XL of 8 bits
    (a few dozen bytes whatever its size) with gain 1."""
    from gspc.format.view_records import CameraRecord, ResidualRecord, ViewRecord

    centre = np.array(point, np.float64) - np.array([0.0, 0.0, distance])
    pose = np.concatenate([np.eye(3), -centre[:, None]], 1).astype("<f4").tobytes()
    intrinsics = np.array([width, width, width / 2, height / 2], "<f4").tobytes()
    camera = CameraRecord(width, height, intrinsics, pose)
    if not residual:
        return ViewRecord(camera), None
    image = imagecodecs.jpegxl_encode(np.full((height, width, 3), 128, np.uint8), lossless=True, effort=1)
    return ViewRecord(camera, ResidualRecord("jxl", 8, 1.0, (height, width), 1)), image


def work_file(
    path: Path,
    header: dict,
    n: int,
    views: list[tuple],
    log_scale: float = 0.0,
    iterations: int | None = None,
    pad: int = 0,
) -> Path:
    """A file of ``n`` identical, opaque Gaussians of log-scale about ``log_scale`` (the nearest multiple of
    the header's step), all at the grid's origin, with the side-information ``views`` (facing_view's), the
    refinement ``iterations`` it names (None: the header's) and ``pad`` bytes of unread words."""
    from gspc.format.side_chunk import pack_side

    a = header["attributes"]
    chunks = constant_chunks(a, n, pad=pad)
    chunks["SCAL"] = ecm(n, [(0, [[1, round(log_scale / a["scale_step"])]] * 15)] * 3)
    chunks["OPAC"] = ecm(n, [(0, [[1, a["opacity_levels"]]] * 15)], bytes(pad))
    side = {k: v for k, v in header["side_info"].items() if k != "views"}
    if iterations is not None:
        side["refine_iterations"] = iterations
    images = {k: image for k, (_, image) in enumerate(views) if image is not None}
    chunks["SIDE"] = pack_side([v for v, _ in views], images)
    return write_gspc(path, dict(header, side_info=side), n, chunks)


def work_files(header: dict, d: Path) -> list[tuple[str, Path, bool]]:
    """(name, file, decodes) asking a decoder that restores and refines for work out of proportion to their
    bytes (issue 50; spec 10.8, "The decoder's work"): a default refinement of 2^16 iterations over 2^16
    Gaussians, a view's Gaussian-tile pairs at the floor and one Gaussian past it, the issue's 2^16 large
    Gaussians before one 640 x 640 and one 2048 x 2048 view, first renders at the work budget and one view
    past it, and views of the pixel floor's restored. Each has a residual at its first view at least: a
    decoder renders only where it refines, and refines only where a view has a residual (spec 10.8)."""
    lo = header["attributes"]["position"]["lo"]
    out = []
    view = facing_view(lo, 48, 48, 3.0, True)
    name = "65,536 identical Gaussians naming 65,536 refinement iterations (runs what its budget pays for)"
    out.append((name, work_file(d / "work_refine.gspc", header, 1 << 16, [view], -4.0, 1 << 16), True))
    # Gaussians covering every tile of a 512 x 512 view (64 x 64 tiles): 2^22 / 4096 of them at the floor.
    big, plain = facing_view(lo, 512, 512, 3.0, True), facing_view(lo, 512, 512, 3.0, False)
    per = (512 // 8) ** 2
    for count, ok in ((limits.PAIR_FLOOR // per, True), (limits.PAIR_FLOOR // per + 1, False)):
        name = f"{count:,} large Gaussians before a 512 x 512 view: {count * per:,} pairs"
        name += " (the floor)" if ok else " (one Gaussian past the floor)"
        out.append((name, work_file(d / f"work_pairs_{count}.gspc", header, count, [big], 2.0), ok))
    for side in (640, 2048):
        name = f"65,536 large Gaussians before one {side} x {side} view (issue 50)"
        view = facing_view(lo, side, side, 3.0, True)
        out.append((name, work_file(d / f"work_view_{side}.gspc", header, 1 << 16, [view], 2.0), False))
    # Views each at the pair floor: their first renders reach the work floor after a few.
    count = limits.PAIR_FLOOR // per
    first = limits.view_work(count, limits.PAIR_FLOOR, 512 * 512)
    fits = (limits.WORK_FLOOR - limits.RESTORE_PIXEL_WORK * 512 * 512) // first
    for views, ok in ((fits, True), (fits + 1, False)):
        path = work_file(d / f"work_views_{views}.gspc", header, count, [big] + [plain] * (views - 1), 2.0)
        assert limits.decode_work_budget(path.stat().st_size) == limits.WORK_FLOOR
        name = f"{views} views at the pair floor: first renders {'within' if ok else 'past'} the work floor"
        out.append((name, path, ok))
    restored = facing_view(lo, 400, 400, 3.0, True)
    views = limits.PIXEL_FLOOR // (400 * 400)
    name = f"{views} views of 400 x 400 restored (the pixel floor), 16 Gaussians"
    out.append((name, work_file(d / "work_restore.gspc", header, 16, [restored] * views, -4.0), True))
    # The most Gaussians a megabyte may declare, at SH degree 3 (the widest rows), restored and refined for
    # a few iterations: the memory of a refinement per file byte.
    a = header["attributes"]
    steps = a["sh_steps"] or [a["dc_step"]]
    sh3 = dict(header, attributes=dict(a, sh_degree=3, sh_steps=[steps[0]] * 15))
    edge = limits.max_coded_gaussians(
        payload_bytes(constant_chunks(sh3["attributes"], 1 << 20, pad=1_000_000))
    )
    view = facing_view(lo, 400, 400, 3.0, True)
    path = work_file(d / "work_sh3.gspc", sh3, edge, [view], -4.0, iterations=3, pad=1_000_000)
    out.append((f"{edge:,} SH-3 Gaussians in 1 MB (12 coded bits each) refined 3 iterations", path, True))
    return out
