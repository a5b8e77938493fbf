"""Light entry points stay light: the container, `gspc --help` and `gspc info FILE.gspc` import no torch."""

import subprocess
import sys

from scenes import random_scene

from gspc.io import write_ply
from gspc.pipeline import EncodeOptions, encode

PROBE = """
import sys
{body}
heavy = sorted(m for m in ("torch", "gspc.pipeline", "gspc.restore.nafnet") if m in sys.modules)
print("HEAVY:" + ",".join(heavy))
"""

CLI = """
from gspc.cli import app
sys.argv = ["gspc", *{args!r}]
try:
    app()
except SystemExit:
    pass
"""


def heavy_modules(body: str) -> str:
    res = subprocess.run(
        [sys.executable, "-c", PROBE.format(body=body)], capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr
    return res.stdout.rsplit("HEAVY:", 1)[1].strip()


def test_container_import_needs_no_torch():
    assert heavy_modules("import gspc.format.container\nimport gspc") == ""


def test_help_and_info_on_a_gspc_file_need_no_torch(tmp_path):
    scene, out = tmp_path / "s.ply", tmp_path / "s.gspc"
    write_ply(random_scene(200, sh_degree=0, seed=2), scene)
    encode(scene, out, opts=EncodeOptions(side_info=False, synth_views=4))
    assert heavy_modules(CLI.format(args=["--help"])) == ""
    assert heavy_modules(CLI.format(args=["info", str(out)])) == ""


def test_public_api_still_resolves_lazily():
    assert "torch" in heavy_modules("import gspc\nassert callable(gspc.encode) and gspc.GaussianScene")
