"""Hostile inputs through the CLI (tools/hostile_cases.py): each is refused in one typed line, leaves no
output, and costs memory bounded by its size (issue 15); files at a size-bounded limit's edge decode, one step
past it are refused (issue 26)."""

import os
import subprocess
import sys
import tracemalloc
from pathlib import Path

import pytest
from hostile_cases import (
    Case,
    amplification_cases,
    camera_cases,
    camera_input_cases,
    environment_cases,
    gspc_cases,
    gspc_files,
    option_cases,
    outcome,
    output_cases,
    read_value_cases,
    scene_value_cases,
    snapshot,
    sog_cases,
    touched,
    unneeded_bomb,
    unrestored_cases,
)
from scenes import random_scene
from sog_files import make_sog
from typer.testing import CliRunner

from gspc.cli import app
from gspc.errors import GspcError
from gspc.io import write_ply
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A tiny scene and a valid .gspc file of it that carries residual side information."""
    tmp = tmp_path_factory.mktemp("hostile")
    scene = tmp / "scene.ply"
    write_ply(random_scene(300, sh_degree=1, seed=0), scene)
    base = tmp / "base.gspc"
    # The uniform codec (versions 1-3): tools/amplification_cases.py builds its payloads for that layout.
    opts = EncodeOptions(lam=200, synth_views=6, max_side=48, check_iterations=0, precision=False)
    encode(scene, base, opts=opts)
    return tmp, scene, base


def all_cases(tmp, scene, base) -> list[Case]:
    return [
        *option_cases(scene, base, tmp),
        *camera_cases(scene, tmp),
        *scene_value_cases(scene, tmp),
        *gspc_cases(base, tmp),
        *sog_cases(tmp, make_sog),
        *amplification_cases(base, tmp),
        *output_cases(scene, base, tmp),
        *environment_cases(scene),
        *camera_input_cases(scene, tmp),
        *read_value_cases(scene, tmp),
        *unrestored_cases(base, tmp),
    ]


def run_case(case: Case, tmp) -> str | None:
    """Why the run is not clean (the outcome it expects, no file touched but its output), or None."""
    if case.output is not None and case.output.is_file():
        case.output.unlink()  # left by a case that wrongly succeeded: reported once, not again
    before = snapshot(tmp)
    res = runner.invoke(app, case.args, env=case.env)
    got = outcome(case, res.exit_code, res.output)
    extra = touched(before, snapshot(tmp), case.output)
    if got != case.expect:
        return f"{got}: {res.output.strip()[-200:]!r}"
    if extra:
        return f"touched {extra[:3]}"
    return None


@pytest.mark.slow
def test_hostile_inputs_end_as_expected(work):
    """Every case is refused in one line, or (at a limit's edge) succeeds; no other file is touched."""
    tmp, scene, base = work
    scene_bytes, base_bytes = scene.read_bytes(), base.read_bytes()
    # Control: the file every hostile one is made from decodes.
    ok = runner.invoke(app, ["decode", str(base), "-o", str(tmp / "ok.ply"), "--iterations", "2"])
    assert ok.exit_code == 0, ok.output
    cases = all_cases(tmp, scene, base)
    assert len(cases) > 300
    problems = [f"{c.category}: {c.name}: {why}" for c in cases if (why := run_case(c, tmp))]
    assert not problems, "\n".join(problems)
    # Outputs named as inputs were refused, not written over the inputs.
    assert scene.read_bytes() == scene_bytes and base.read_bytes() == base_bytes


@pytest.mark.slow
def test_hostile_files_decode_in_bounded_memory(work):
    """Peak memory (tracemalloc) decoding each hostile .gspc file: refused before its asks are allocated."""
    tmp, _, base = work
    tracemalloc.start()
    try:
        for _, name, path in gspc_files(base, tmp):
            tracemalloc.reset_peak()
            before = tracemalloc.get_traced_memory()[0]
            # A residual damaged after its header is refused by a decoder that restores (spec 10.7), which
            # it does for refinement's targets.
            restore = "(restoring)" in name
            with pytest.raises(GspcError):
                opts = DecodeOptions(restore=restore, refine=restore, restorer="none")
                decode(path, tmp / "mem_out.ply", opts)
            peak = tracemalloc.get_traced_memory()[1] - before
            size = path.stat().st_size
            # 4 MiB for the interpreter's own work (imports on first use, tracebacks), then 64 x the file.
            assert peak <= (4 << 20) + 64 * size, (name, peak, size)
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_bad_values_are_named_before_any_warning(work):
    """Issue 50: each bad value is named by the reader that reads it, in one line, before any arithmetic
    warns: run under ``python -W error``, every warning would end the run as an internal error."""
    tmp, scene, _ = work
    problems = []
    for case in read_value_cases(scene, tmp):
        if case.output is not None and case.output.is_file():
            case.output.unlink()
        code = "import sys; from gspc.cli import app; app(sys.argv[1:])"
        env = {**os.environ, "GSPC_THREADS": "1", "PYTHONPATH": str(ROOT)}
        run = subprocess.run(
            [sys.executable, "-W", "error", "-c", code, *case.args], capture_output=True, text=True, env=env
        )
        got = outcome(case, run.returncode, run.stdout + run.stderr)
        if got != case.expect:
            problems.append(f"{case.name}: {got}: {(run.stdout + run.stderr).strip()[-200:]!r}")
    assert not problems, "\n".join(problems)


def test_work_files_are_refused_before_they_render(work):
    """Issue 50: files whose views ask for more Gaussian-tile pairs, or first renders of more work, than
    their bytes pay for are refused in one line before anything is rendered (spec 10.8)."""
    import amplification_cases as amp

    from gspc.format import container

    tmp, _, base = work
    for name, path, ok in amp.work_files(container.read(base).header, tmp):
        if ok:
            continue  # decoded by the slow sweep (test_hostile_inputs_end_as_expected)
        out = tmp / "work_out.ply"
        res = runner.invoke(app, ["decode", str(path), "-o", str(out)])
        assert outcome(Case("", name, [], out), res.exit_code, res.output) == "refused", (name, res.output)
        assert "spec 10.8" in res.output, (name, res.output)


def test_unneeded_sog_member_is_not_read(tmp_path):
    """`gspc info` on a SOG archive with a 64 MiB member it does not need: never inflated (peak memory)."""
    bomb = unneeded_bomb(tmp_path, make_sog)
    tracemalloc.start()
    try:
        res = runner.invoke(app, ["info", str(bomb)])
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert res.exit_code == 0, res.output
    assert peak < 16 << 20, peak


def test_options_are_validated_by_the_dataclasses(tmp_path):
    with pytest.raises(GspcError, match="--background"):
        EncodeOptions(background=(2, 2, 2)).validate()
    with pytest.raises(GspcError, match="--lambda"):
        EncodeOptions(lam=float("inf")).validate()
    with pytest.raises(GspcError, match="--iterations"):
        DecodeOptions(iterations=10**12).validate()
    EncodeOptions().validate()
    DecodeOptions().validate()


@pytest.mark.parametrize(
    "vector",
    [
        "codec_invalid_float_count",
        "codec_invalid_count_vs_payload",
        "codec_invalid_far_shift",
        "codec_invalid_chunk_index",
        "codec_invalid_shrs_in_sh0",
    ],
)
def test_info_refuses_the_attribute_sections_decode_refuses(vector, tmp_path):
    path = Path(__file__).resolve().parents[1] / "spec" / "vectors" / f"{vector}.gspc"
    res = runner.invoke(app, ["info", str(path)])
    assert res.exit_code == 1 and res.output.startswith("error:"), res.output
    with pytest.raises(GspcError):
        decode(path, tmp_path / "o.ply", DecodeOptions(restore=False, refine=False))
    assert not (tmp_path / "o.ply").exists()


def test_info_reads_a_file_at_the_count_limit_and_refuses_one_past(work):
    import amplification_cases as amp

    tmp, _, base = work
    from gspc.format import container

    files = amp.count_files(container.read(base).header, tmp)
    for name, path, ok in files[:2]:
        res = runner.invoke(app, ["info", str(path)])
        assert (res.exit_code == 0) == ok, (name, res.output)


def test_spec_reader_refuses_every_hostile_header_and_view(work):
    """tests/spec_reader.py, written from the spec alone, refuses each file gspc refuses (issue 26: the spec
    states every rule the decoder enforces), with its own error rather than a crash."""
    import spec_reader
    from hostile_cases import header_mutations, side_mutations

    from gspc.format import container

    _, _, base = work
    c = container.read(base)
    spec_reader.read_scene(base.read_bytes())  # the base itself decodes
    files = [(d, container.pack(m, c.chunks)) for d, m in header_mutations(c.header)]
    files += [(d, container.pack(m, ch)) for d, m, ch in side_mutations(c.header, c.chunks)]
    accepted = []
    for desc, data in files:
        try:
            spec_reader.read_scene(data)
            accepted.append(desc)
        except spec_reader.SpecError:
            pass
    assert not accepted, accepted


@pytest.mark.slow
def test_spec_reader_takes_the_decoders_work_decisions(work):
    """Spec 10.8 "The decoder's work" as tests/spec_reader.py reads it: the same refusals and default
    refinement as gspc's decoder on every crafted work file and on the base file, and pair counts that
    differ only by the reference's widened boxes."""
    import amplification_cases as amp
    import spec_reader

    from gspc.codec.attributes import decode_attributes
    from gspc.format import container
    from gspc.format.attribute_section import AttributeSection, attribute_chunks
    from gspc.format.header import FileHeader
    from gspc.format.side_chunk import read_side_views
    from gspc.reconstruct import check_decode_work, decode_work, refine_iterations

    tmp, _, base = work
    # (Not the megabyte of SH-3 Gaussians: the spec reader decodes a symbol per Python call.)
    files = [(n, p) for n, p, _ in amp.work_files(container.read(base).header, tmp) if "SH-3" not in n]
    for name, path in [*files, ("base", base)]:
        data = path.read_bytes()
        c = container.unpack(data)
        header = FileHeader.from_dict(c.header)
        side = read_side_views(header.side_info.legacy_views, c.chunks, len(data))
        scene = decode_attributes(
            attribute_chunks(c.chunks), AttributeSection.from_dict(c.header["attributes"])
        )
        ours = decode_work(scene, [v.camera.to_camera() for v in side.views], side.images, None)
        attributes, views = spec_reader.read_scene(data, residuals=False)
        theirs = [spec_reader.view_pairs(attributes, v) for v in views]
        for a, b in zip(theirs, ours.pairs, strict=True):
            assert a <= b <= 1.01 * a + 64, (name, a, b)
        try:
            check_decode_work(ours, len(data))
            runs = refine_iterations(header.side_info.refine_iterations, ours, len(data))
        except GspcError:
            runs = None
        try:
            spec_runs = spec_reader.decoder_work(data)
        except spec_reader.SpecError:
            spec_runs = None
        assert runs == spec_runs, (name, runs, spec_runs)


def test_precision_files_end_as_expected(work):
    """Version 4 (spec 10.13): 16 classes at the count floor and a chunk's tables at its shared bound decode;
    a widest table in every matrix of 16 classes (a 30 s decode before the shared bound), one entry past the
    bound, 17 classes and a matrix of 2^40 rows are refused at once, in one line."""
    import amplification_cases as amp

    from gspc.format import container

    tmp, _, base = work
    for name, path, ok in amp.precision_files(container.read(base).header, tmp):
        out = tmp / "prec_out.ply"
        res = runner.invoke(app, ["decode", str(path), "-o", str(out), "--no-restore", "--no-refine"])
        assert outcome(Case("", name, [], out, "ok" if ok else "refused"), res.exit_code, res.output) == (
            "ok" if ok else "refused"
        ), (name, res.output)
        out.unlink(missing_ok=True)


def test_both_decoders_refuse_every_version_4_header_mutation(work, tmp_path):
    """Each mutation of a version-4 header's classes is refused by gspc and by tests/spec_reader.py."""
    import spec_reader
    from hostile_cases import precision_base, precision_mutations

    from gspc.format import container

    _, _, base = work
    v4 = container.read(precision_base(base, tmp_path))
    spec_reader.read_scene(container.pack(v4.header, v4.chunks))  # the base itself decodes
    decode(precision_base(base, tmp_path), tmp_path / "ok.ply", DecodeOptions(restore=False, refine=False))
    mutations = list(precision_mutations(v4.header))
    assert len(mutations) > 50
    accepted = []
    for desc, meta in mutations:
        data = container.pack(meta, v4.chunks)
        try:
            spec_reader.read_scene(data)
            accepted.append(f"spec reader: {desc}")
        except spec_reader.SpecError:
            pass
        path = tmp_path / "m.gspc"
        path.write_bytes(data)
        try:
            decode(path, tmp_path / "m.ply", DecodeOptions(restore=False, refine=False))
            accepted.append(f"gspc: {desc}")
        except GspcError:
            pass
    assert not accepted, accepted
