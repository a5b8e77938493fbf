"""Hostile inputs through the CLI (tests/hostile.py): each is refused in one typed line, leaves no output, and
costs memory bounded by its size (issue 15)."""

import tracemalloc

import pytest
from hostile import (
    Case,
    camera_cases,
    gspc_cases,
    gspc_files,
    option_cases,
    scene_value_cases,
    sog_cases,
    unneeded_bomb,
)
from scenes import random_scene
from sog_files import make_sog
from typer.testing import CliRunner

from gspc.cli import app
from gspc.errors import GspcError
from gspc.io import write_ply
from gspc.pipeline import DecodeOptions, EncodeOptions, decode, encode

runner = CliRunner()


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A tiny scene and a valid .gspc file of it that carries residual side information."""
    tmp = tmp_path_factory.mktemp("hostile")
    scene = tmp / "scene.ply"
    write_ply(random_scene(300, sh_degree=1, seed=0), scene)
    base = tmp / "base.gspc"
    encode(scene, base, opts=EncodeOptions(lam=200, synth_views=6, max_side=48, check_iterations=0))
    return tmp, scene, base


def refusal_problem(case: Case, res) -> str | None:
    """Why the run is not a clean refusal (exit 1, one last ``error:`` line, no output), or None."""
    text = res.output
    lines = text.strip().splitlines() or [""]
    if res.exit_code != 1:
        return f"exit {res.exit_code}"
    if "Traceback" in text or "internal error" in text:
        return "internal error"
    if not lines[-1].startswith("error:") or not all(x.startswith("gspc: ") for x in lines[:-1]):
        return "not one error line"
    if case.output is not None and case.output.exists():
        return "output left behind"
    return None


@pytest.mark.slow
def test_hostile_inputs_are_refused_in_one_line(work):
    tmp, scene, base = work
    scene_bytes, base_bytes = scene.read_bytes(), base.read_bytes()
    # Control: the file every hostile one is made from decodes.
    ok = runner.invoke(app, ["decode", str(base), "-o", str(tmp / "ok.ply"), "--iterations", "2"])
    assert ok.exit_code == 0, ok.output
    cases = [
        *option_cases(scene, base, tmp),
        *camera_cases(scene, tmp),
        *scene_value_cases(scene, tmp),
        *gspc_cases(base, tmp),
        *sog_cases(tmp, make_sog),
    ]
    assert len(cases) > 300
    problems = []
    for case in cases:
        if case.output is not None and case.output.is_file():
            case.output.unlink()  # left by a case that wrongly succeeded: reported once, not again
        res = runner.invoke(app, case.args)
        why = refusal_problem(case, res)
        if why:
            problems.append(f"{case.category}: {case.name}: {why}: {res.output.strip()[-200:]!r}")
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
            with pytest.raises(GspcError):
                decode(path, tmp / "mem_out.ply", DecodeOptions(restore=False, refine=False))
            peak = tracemalloc.get_traced_memory()[1] - before
            size = path.stat().st_size
            # 4 MiB for the interpreter's own work (imports on first use, tracebacks), then 64 x the file.
            assert peak <= (4 << 20) + 64 * size, (name, peak, size)
    finally:
        tracemalloc.stop()


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
