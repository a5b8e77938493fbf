"""gspc/__init__.py lists its public API once (_LAZY); __all__ and the imports static checkers see agree."""

import ast
import importlib
from pathlib import Path

import gspc

INIT = Path(gspc.__file__)


def _type_checking_imports() -> dict[str, str]:
    """public name -> "module:attr" (or "module") of the imports under ``if TYPE_CHECKING:``."""
    tree = ast.parse(INIT.read_text())
    block = next(n for n in tree.body if isinstance(n, ast.If) and ast.unparse(n.test) == "TYPE_CHECKING")
    out = {}
    for node in block.body:
        for alias in node.names:
            out[alias.asname] = node.module if alias.asname == alias.name else f"{node.module}:{alias.name}"
    return out


def test_all_is_the_lazy_table_and_the_version():
    assert gspc.__all__ == sorted([*gspc._LAZY, "__version__"])


def test_static_imports_name_the_same_modules():
    assert _type_checking_imports() == gspc._LAZY


def test_every_public_name_resolves_to_its_module():
    import gspc.pipeline  # noqa: F401  (imports the subpackages whose names could shadow public ones)

    for name, where in gspc._LAZY.items():
        module, _, attr = where.partition(":")
        assert getattr(gspc, name) is getattr(importlib.import_module(module), attr or name), name


def test_the_version_has_one_source():
    """pyproject.toml reads it from gspc/__init__.py (the encoder writes it into every file's header)."""
    text = (INIT.parents[1] / "pyproject.toml").read_text()
    assert 'dynamic = ["version"]' in text and 'attr = "gspc.__version__"' in text
    assert "\nversion =" not in text.split("[tool.setuptools.dynamic]")[0]
