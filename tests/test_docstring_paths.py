"""Comments and docstrings under gspc/ name only what exists, and carry no dates or commit hashes.

Every repository path a comment names (gspc/..., bench/..., spec/..., tools/..., tests/..., examples/...,
with a trailing `:NN` line number stripped) must exist, a bare module name (`stages.py`) must be the name of
some module in the repository, and every bench section a comment quotes must be a heading
of that bench file: `bench/FILE.md, "Section"` (or `'Section'`), further sections after it joined by commas,
"and" or semicolons, and a parenthesised `("Section")` later in the same comment, of the bench file named
last. Headings match case-insensitively, the quoted text being a prefix of the heading. History and
measurements belong in bench/*.md: no comment holds a date or a commit hash. Each test reports every
failure at once. Comments are read by tools/comment_audit.py.
"""

from __future__ import annotations

import re
from functools import cache

from comment_audit import COMMIT, DATE, ROOT, comment_blocks, package_files

# Files another change is rewriting, whose comments still break these rules: their failures are listed, not
# counted. Empty it once they comply.
ALLOWED_TO_FAIL: frozenset[str] = frozenset()

PATH = re.compile(r"(?<![\w./-])(?:gspc|bench|spec|tools|tests|examples)/[\w./-]*")
MODULE = re.compile(r"(?<![\w./-])\w+\.py\b")
BENCH = re.compile(r"(?<![\w./-])bench/[\w./-]+\.md")
# A section right after the bench file: `bench/F.md, "S"` or `bench/F.md 'S'`, and more joined to it.
FIRST = re.compile(r"""\A(?:,?\s*"([^"]+)"|(?:,\s*|\s+)'([^']+)')""")
MORE = re.compile(r"""\A\s*(?:,\s*and|,|;|and)\s*"([^"]+)\"""")
# A quoted section later in the same comment, of the bench file named last: `("S")`, `; "S"`, `, "S"`.
LATER = re.compile(r"""(?:\(|;\s|,\s|\band\s)"([A-Z][^"]*)\"""")


def _blocks() -> list[tuple[str, int, str]]:
    out = []
    for path in package_files():
        rel = path.relative_to(ROOT).as_posix()
        out += [(rel, line, text) for line, text in comment_blocks(path.read_text(encoding="utf-8"))]
    return out


@cache
def _headings(bench: str) -> tuple[str, ...]:
    lines = (ROOT / bench).read_text(encoding="utf-8").splitlines()
    return tuple(line.lstrip("#").strip().lower() for line in lines if line.startswith("#"))


def _target(token: str) -> str:
    """A path as a comment writes it, less trailing punctuation and a `:NN` line number."""
    return re.sub(r":\d+$", "", token.rstrip(".,;:)"))


@cache
def _module_names() -> frozenset[str]:
    return frozenset(p.name for top in ("gspc", "tools", "tests") for p in (ROOT / top).rglob("*.py"))


def _sections(text: str) -> list[tuple[str, str]]:
    """(bench file, quoted section) pairs a comment's text names."""
    found: list[tuple[str, str]] = []
    named = list(BENCH.finditer(text))
    for m in named:
        rest = text[m.end() :]
        first = FIRST.match(rest)
        if not first:
            continue
        found.append((m.group(0), first.group(1) or first.group(2)))
        rest = rest[first.end() :]
        while more := MORE.match(rest):
            found.append((m.group(0), more.group(1)))
            rest = rest[more.end() :]
    claimed = {s for _, s in found}
    for q in LATER.finditer(text):
        before = [m for m in named if m.end() <= q.start()]
        if before and q.group(1) not in claimed:
            found.append((before[-1].group(0), q.group(1)))
    return found


@cache
def _problems() -> dict[str, list[str]]:
    """Per rule, every failure as `file:line: what`."""
    problems: dict[str, list[str]] = {"paths": [], "sections": [], "history": []}
    for rel, line, text in _blocks():
        where = f"{rel}:{line}"
        for m in PATH.finditer(text):
            if not (ROOT / _target(m.group(0))).exists():
                problems["paths"].append(f"{where}: {_target(m.group(0))} does not exist")
        for m in MODULE.finditer(text):
            if m.group(0) not in _module_names():
                problems["paths"].append(f"{where}: no module is named {m.group(0)}")
        for bench, section in _sections(text):
            if not (ROOT / bench).is_file():
                continue  # reported above
            if not any(h.startswith(section.lower()) for h in _headings(bench)):
                problems["sections"].append(f'{where}: {bench} has no heading "{section}"')
        for m in (*DATE.finditer(text), *COMMIT.finditer(text)):
            problems["history"].append(f"{where}: {m.group(0)}")
    return problems


def _failures(rule: str) -> list[str]:
    return [p for p in _problems()[rule] if p.split(":", 1)[0] not in ALLOWED_TO_FAIL]


def test_named_paths_exist():
    failures = _failures("paths")
    assert not failures, "comments name paths that do not exist:\n" + "\n".join(failures)


def test_named_bench_sections_exist():
    failures = _failures("sections")
    assert not failures, "comments quote bench sections that are not headings:\n" + "\n".join(failures)


def test_no_dates_or_commit_hashes():
    failures = _failures("history")
    assert not failures, "comments carry dates or commit hashes (history goes in bench/*.md):\n" + "\n".join(
        failures
    )


def test_allowlist_is_still_needed():
    """An allowed file that complies leaves the list (so that it cannot slip back)."""
    failing = {p.split(":", 1)[0] for rule in _problems().values() for p in rule}
    stale = sorted(ALLOWED_TO_FAIL - failing)
    assert not stale, f"these files now comply; remove them from ALLOWED_TO_FAIL: {stale}"


def test_section_references_are_parsed():
    """The reference forms the rules above read, on made-up text."""
    text = (
        'x (bench/a.md, "One" and "Two"; bench/b.md \'Three\', tools/t.py:12). ("Four"); not "lower". '
        '"Five" alone; bench/c.md\'s "Six" is no section'
    )
    assert _sections(text) == [
        ("bench/a.md", "One"),
        ("bench/a.md", "Two"),
        ("bench/b.md", "Three"),
        ("bench/b.md", "Four"),
    ]
    paths = [_target(p) for p in PATH.findall(text)]
    assert paths == ["bench/a.md", "bench/b.md", "tools/t.py", "bench/c.md"]
    assert MODULE.findall("kernels.py and gspc/render/kernels.py") == ["kernels.py"]
