"""The JavaScript decoder's own tests (web/test/*.test.mjs: the conformance vectors, tiles, hostile files,
the PLY writer, the command line) run under node from pytest, so that CI runs them with the rest. Skips where
node or web/node_modules (`npm ci --prefix web`) is missing."""

import shutil
import subprocess
from pathlib import Path

import pytest

WEB = Path(__file__).resolve().parents[1] / "web"
NODE = shutil.which("node")


@pytest.mark.skipif(
    NODE is None or not (WEB / "node_modules" / "fzstd").is_dir(),
    reason="node, or web/node_modules (run `npm ci --prefix web`), is missing",
)
def test_the_javascript_decoders_tests_pass():
    files = sorted(str(p.relative_to(WEB)) for p in (WEB / "test").glob("*.test.mjs"))
    assert files
    res = subprocess.run([NODE, "--test", *files], cwd=WEB, capture_output=True, text=True, timeout=1200)
    failed = [line for line in res.stdout.splitlines() if line.startswith("not ok")]
    assert res.returncode == 0, "\n".join(failed) or res.stdout[-4000:] + res.stderr[-2000:]
