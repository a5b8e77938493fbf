"""Refusing an output path that names one of the command's inputs: a write there would destroy the input
(issue 15: ``encode x.ply -o x.ply`` would replace the source scene) whether or not the command fails."""

from __future__ import annotations

import os
from pathlib import Path

from gspc.errors import InputError


def _same(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)  # hard links and other aliases resolve() does not see
    except OSError:  # one of them does not exist (yet): then they cannot be the same file
        return False


def refuse_output_over_input(output: str | os.PathLike, *inputs: str | os.PathLike | None) -> None:
    """InputError when ``output`` is (or resolves to) the same file as any of ``inputs``."""
    out = Path(output)
    for src in inputs:
        if src is not None and _same(out, Path(src)):
            raise InputError(f"output {out} is the input {src}; choose another output path")
