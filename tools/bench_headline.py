"""Render gspc's headline figures (bench/headline.json) into README.md's results table and bench/README.md's.

    python tools/bench_headline.py            # rewrite the tables between the marker comments
    python tools/bench_headline.py --check    # exit 1 if either file differs from what this would write

Each figure in the JSON cites its bench file, the section there, the command that made it and the code it was
measured at; the tables are generated from it (between ``<!-- headline:begin -->`` and ``<!-- headline:end
-->``), so the README, bench/README.md and the JSON cannot disagree (tests/test_bench_headline.py runs the
check). To change a figure, edit the JSON and run this.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEADLINE = Path("bench/headline.json")
README = Path("README.md")
BENCH_README = Path("bench/README.md")
BEGIN, END = "<!-- headline:begin -->", "<!-- headline:end -->"


@dataclass(frozen=True)
class Value:
    """One number (or a min-max range) with its unit and what it is of ("vs photos", "encode")."""

    value: float | None = None
    low: float | None = None
    high: float | None = None
    decimals: int = 0
    unit: str = ""
    of: str = ""

    def numbers(self) -> list[str]:
        """The numbers as written (thousands separated for integers), for the table and the source check."""
        vals = [self.value] if self.value is not None else [self.low, self.high]
        return [f"{v:,.{self.decimals}f}" for v in vals]

    def text(self) -> str:
        number = "-".join(self.numbers())
        unit = self.unit if self.unit in ("x", "") else f" {self.unit}"
        return f"{number}{unit}" + (f" {self.of}" if self.of else "")


@dataclass(frozen=True)
class Source:
    file: str  # relative to the repository root
    section: str  # the heading's text, as the file writes it

    @property
    def anchor(self) -> str:
        return slug(self.section)


@dataclass(frozen=True)
class Figure:
    id: str
    group: str
    label: str
    scene: str
    values: tuple[Value, ...]
    sources: tuple[Source, ...]
    command: str
    code: str
    date: str
    note: str = ""
    readme: bool = True


def slug(heading: str) -> str:
    """GitHub's anchor for a Markdown heading: lower case, punctuation dropped, each space a hyphen."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _value(d: dict) -> Value:
    known = {"value", "min", "max", "decimals", "unit", "of"}
    if set(d) - known or ("value" in d) == ("min" in d) or ("min" in d) != ("max" in d):
        raise ValueError(f"a value is one 'value' or a 'min' and 'max' (with decimals, unit, of): {d}")
    return Value(
        d.get("value"), d.get("min"), d.get("max"), d.get("decimals", 0), d.get("unit", ""), d.get("of", "")
    )


def load(path: Path) -> list[Figure]:
    """The figures of a headline JSON file, in its order."""
    doc = json.loads(path.read_text())
    figures = []
    for f in doc["figures"]:
        figures.append(
            Figure(
                id=f["id"],
                group=f["group"],
                label=f["label"],
                scene=f["scene"],
                values=tuple(_value(v) for v in f["values"]),
                sources=tuple(Source(s["file"], s["section"]) for s in f["sources"]),
                command=f["command"],
                code=f["measured"]["code"],
                date=f["measured"]["date"],
                note=f.get("note", ""),
                readme=f.get("readme", True),
            )
        )
    ids = [f.id for f in figures]
    if len(set(ids)) != len(ids):
        raise ValueError(f"{path}: figure ids repeat")
    return figures


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _links(fig: Figure, base: str) -> str:
    """Each source as a link from a file in folder ``base`` (repository-relative; '' for the root)."""
    out = []
    for s in fig.sources:
        target = s.file[len(base) + 1 :] if base and s.file.startswith(base + "/") else s.file
        out.append(f"[{Path(s.file).name}]({target}#{s.anchor})")
    return ", ".join(out)


def _values(fig: Figure) -> str:
    return "; ".join(v.text() for v in fig.values)


def readme_table(figures: list[Figure]) -> str:
    """README.md's results table: the figures marked for it, each linked to its bench section (which names
    the scene, the views and the machine)."""
    rows = ["| Figure | Value | Source |", "|---|---|---|"]
    for f in figures:
        if f.readme:
            rows.append(f"| {_cell(f.label)} | {_cell(_values(f))} | {_links(f, '')} |")
    return "\n".join(rows)


def bench_table(figures: list[Figure]) -> str:
    """bench/README.md's table: every figure with its note, source section, command and code."""
    rows = [
        "| Figure | Scene | Value | Source | Command | Measured at |",
        "|---|---|---|---|---|---|",
    ]
    for f in figures:
        value = _values(f) + (f" — *{f.note}*" if f.note else "")
        cmd = f"`{f.command}`"
        rows.append(
            f"| {_cell(f.label)} | {_cell(f.scene)} | {_cell(value)} | {_links(f, 'bench')} | {_cell(cmd)} "
            f"| {f.code}, {f.date} |"
        )
    return "\n".join(rows)


def with_block(text: str, block: str, name: str) -> str:
    """``text`` with what lies between the markers replaced by ``block``."""
    i, j = text.find(BEGIN), text.find(END)
    if i < 0 or j < i:
        raise ValueError(f"{name}: no '{BEGIN}' ... '{END}' markers")
    return f"{text[: i + len(BEGIN)]}\n{block}\n{text[j:]}"


def rendered(root: Path) -> dict[Path, tuple[str, str]]:
    """Per generated file: (its text now, the text this tool would write)."""
    figures = load(root / HEADLINE)
    out = {}
    for rel, block in ((README, readme_table(figures)), (BENCH_README, bench_table(figures))):
        now = (root / rel).read_text()
        out[rel] = (now, with_block(now, block, str(rel)))
    return out


def stale(root: Path) -> list[Path]:
    """The generated files that differ from what this tool would write."""
    return [rel for rel, (now, new) in rendered(root).items() if now != new]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if a table differs from the JSON's")
    ap.add_argument("--root", type=Path, default=ROOT, help="the repository root")
    args = ap.parse_args(argv)
    try:
        if args.check:
            bad = stale(args.root)
            for rel in bad:
                print(f"{rel}: its headline table differs from {HEADLINE}; run tools/bench_headline.py")
            return 1 if bad else 0
        for rel, (now, new) in rendered(args.root).items():
            if now != new:
                (args.root / rel).write_text(new)
                print(f"wrote {rel}")
    except (OSError, ValueError, KeyError) as e:
        print(f"bench_headline: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
