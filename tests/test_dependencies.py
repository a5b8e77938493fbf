"""Every third-party import is declared in pyproject.toml, where a fresh machine's install will find it:
gspc/ in the runtime dependencies (or an extra it imports optionally), tests/ in those plus [dev], tools/ in
those plus [dev] and [tools]. `.ci/run` proves the same on a clean virtual environment."""

import ast
import re
import sys
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python 3.11+

ROOT = Path(__file__).resolve().parent.parent
# Import names whose distribution is named otherwise, for packages that may not be installed here.
KNOWN = {"PIL": "pillow", "yaml": "pyyaml", "sklearn": "scikit-learn", "cv2": "opencv-python"}
# Extras gspc/ may import, always behind a guard that turns their absence into a clear error.
OPTIONAL_IN_PACKAGE = ("cuda", "ray")


def normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def declared() -> dict[str, set[str]]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    groups = {"runtime": project.get("dependencies", []), **project.get("optional-dependencies", {})}
    return {k: {normalise(re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0]) for r in v} for k, v in groups.items()}


def third_party_imports(folder: str) -> dict[str, str]:
    """Top-level third-party module -> a file importing it."""
    local = {p.stem for d in ("gspc", "tests", "tools") for p in (ROOT / d).rglob("*.py")} | {"gspc"}
    found: dict[str, str] = {}
    for f in sorted((ROOT / folder).rglob("*.py")):
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                names = [node.module]
            else:
                continue
            for n in names:
                top = n.split(".")[0]
                if top not in sys.stdlib_module_names and top not in local:
                    found.setdefault(top, str(f.relative_to(ROOT)))
    return found


def distribution(module: str) -> str:
    dists = packages_distributions().get(module)
    return normalise(dists[0] if dists else KNOWN.get(module, module))


@pytest.mark.parametrize(
    ("folder", "groups"),
    [
        ("gspc", ("runtime", *OPTIONAL_IN_PACKAGE)),
        ("tests", ("runtime", "dev")),
        ("tools", ("runtime", "dev", "tools")),
    ],
)
def test_every_import_is_declared(folder, groups):
    decl = declared()
    allowed = set().union(*(decl.get(g, set()) for g in groups))
    missing = {m: f for m, f in third_party_imports(folder).items() if distribution(m) not in allowed}
    assert not missing, f"imported in {folder}/ but not declared in {' / '.join(groups)}: {missing}"


def test_the_checker_sees_an_undeclared_import():
    assert distribution("not_a_real_package") == "not-a-real-package"
    assert "not-a-real-package" not in set().union(*declared().values())
