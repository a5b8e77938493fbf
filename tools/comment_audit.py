"""Which comment lines under gspc/ carry a measured figure, a date or a commit hash.

    PYTHONPATH=. python tools/comment_audit.py            # the share, over all of gspc/
    PYTHONPATH=. python tools/comment_audit.py --list     # and every line that counts, file:line: text
    mkdir -p /tmp/base && git archive 4051322 gspc | tar -x -C /tmp/base
    PYTHONPATH=. python tools/comment_audit.py --root /tmp/base    # the same, for commit 4051322's gspc/

A comment line is a `#` comment or one line of a module, class or function docstring (blank lines not
counted). It carries a figure when FIGURE matches it: a number with a unit of measurement (dB, %, seconds,
KB/MB/GB, a ratio written "1.5x" or "3 times"; zooms written "1x", "2x" count too), a PSNR/SSIM/LPIPS
score, a date (2026-11-28) or a commit hash (7-40 hex digits with at least one digit and one letter). Sizes
the format fixes ("4 bytes", "16 bits") are not measurements and do not count.
tests/test_docstring_paths.py reads comments with these functions.
"""

from __future__ import annotations

import ast
import io
import re
import sys
import tokenize
from collections.abc import Iterator
from pathlib import Path

import typer

ROOT = Path(__file__).resolve().parent.parent

NUMBER = r"\d(?:[\d,]*\d)?(?:\.\d+)?"
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")
COMMIT = re.compile(r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b")
FIGURE = re.compile(
    rf"{NUMBER}(?:x\b|×|\s*(?:dB\b|%|times\b|s\b|ms\b|us\b|µs\b|seconds?\b|minutes?\b|min\b|hours?\b|[kKMG]i?B\b))"
    rf"|\b(?:PSNR|SSIM|LPIPS)\s+(?:of\s+)?{NUMBER}"
    rf"|{DATE.pattern}|{COMMIT.pattern}"
)


def comment_lines(source: str) -> Iterator[tuple[int, str]]:
    """(line number, text) of each non-blank `#` comment and docstring line of one module's source."""
    yield from _hash_comments(source)
    for first, doc in _docstrings(source):
        for i, text in enumerate(doc.splitlines()):
            if text.strip():
                yield first + i, text.strip()


def comment_blocks(source: str) -> list[tuple[int, str]]:
    """(first line, text) of each comment as a reader takes it in: a run of ``#`` comments on consecutive
    lines joined into one text, and each docstring whole, its lines joined by single spaces."""
    blocks: list[tuple[int, str]] = []
    last = -2
    for line, text in sorted(_hash_comments(source)):
        if line == last + 1:
            blocks[-1] = (blocks[-1][0], f"{blocks[-1][1]} {text}")
        else:
            blocks.append((line, text))
        last = line
    for line, text in _docstrings(source):
        blocks.append((line, " ".join(text.split())))
    return sorted(blocks)


def _hash_comments(source: str) -> Iterator[tuple[int, str]]:
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string.lstrip("#").strip()


def _docstrings(source: str) -> Iterator[tuple[int, str]]:
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        body = node.body
        if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
            if isinstance(body[0].value.value, str):
                yield body[0].lineno, body[0].value.value


def package_files(root: Path = ROOT) -> list[Path]:
    return sorted((root / "gspc").rglob("*.py"))


def audit(root: Path = ROOT) -> tuple[int, list[tuple[str, int, str]]]:
    """The number of comment lines under gspc/ and those among them that FIGURE matches."""
    total, hits = 0, []
    for path in package_files(root):
        rel = path.relative_to(root).as_posix()
        for line, text in comment_lines(path.read_text(encoding="utf-8")):
            total += 1
            if FIGURE.search(text):
                hits.append((rel, line, text))
    return total, sorted(hits)


def main(
    show: bool = typer.Option(False, "--list", help="Print every line that carries a figure."),
    root: Path = typer.Option(ROOT, help="The source tree to audit (e.g. an older commit's, git archive'd)."),
) -> None:
    total, hits = audit(root)
    if show:
        for rel, line, text in hits:
            print(f"{rel}:{line}: {text}")
    share = 100 * len(hits) / max(total, 1)
    print(f"{len(hits)} of {total} comment lines under gspc/ carry a figure ({share:.2f}%)", file=sys.stderr)


if __name__ == "__main__":
    typer.run(main)
