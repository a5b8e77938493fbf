"""bench/headline.json, README.md's results table and bench/README.md's table agree (tools/bench_headline.py),
and every headline figure points at a section its bench file has and quotes numbers that file states."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from bench_headline import (
    BEGIN,
    BENCH_README,
    END,
    HEADLINE,
    README,
    Value,
    load,
    main,
    slug,
    stale,
    with_block,
)

ROOT = Path(__file__).resolve().parents[1]
FIGURES = load(ROOT / HEADLINE)


def _section(path: Path, heading: str) -> str:
    """The text under ``heading`` up to the next heading of its level or above ('' if the file has none)."""
    lines = path.read_text().splitlines()
    for i, line in enumerate(lines):
        m = re.match(r"(#+) (.+)$", line)
        if m and m.group(2).strip() == heading:
            level, body = len(m.group(1)), []
            for rest in lines[i + 1 :]:
                n = re.match(r"(#+) ", rest)
                if n and len(n.group(1)) <= level:
                    break
                body.append(rest)
            return "\n".join(body)
    return ""


def test_the_tables_are_what_the_json_makes():
    assert stale(ROOT) == [], "run: python tools/bench_headline.py"
    assert main(["--check", "--root", str(ROOT)]) == 0


def test_check_fails_on_a_hand_edited_table(tmp_path):
    for rel in (HEADLINE, README, BENCH_README):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text((ROOT / rel).read_text())
    edited = (tmp_path / README).read_text().replace("467,536 B", "400,000 B")
    (tmp_path / README).write_text(edited)
    assert stale(tmp_path) == [README]
    assert main(["--check", "--root", str(tmp_path)]) == 1
    assert main(["--root", str(tmp_path)]) == 0  # rewrites it
    assert stale(tmp_path) == []


@pytest.mark.parametrize("fig", FIGURES, ids=[f.id for f in FIGURES])
def test_each_figure_cites_a_section_its_file_has_and_numbers_it_states(fig):
    """Every number of a figure is written in the section it cites (or in one of them)."""
    texts = []
    for src in fig.sources:
        path = ROOT / src.file
        assert path.is_file(), src.file
        texts.append(_section(path, src.section))
        assert texts[-1], f"{src.file} has no heading {src.section!r}"
    text = "\n".join(texts)
    for v in fig.values:
        for number in v.numbers():
            # bench tables write large integers with or without thousands separators
            assert number in text or number.replace(",", "") in text, f"{fig.id}: {number} not in its source"
    assert fig.command and fig.code and re.fullmatch(r"\d{4}-\d{2}-\d{2}", fig.date), fig.id


def test_a_figure_in_the_readme_is_linked_to_its_section():
    readme = (ROOT / README).read_text()
    shown = {f"({s.file}#{s.anchor})" for fig in FIGURES if fig.readme for s in fig.sources}
    for fig in FIGURES:
        for src in fig.sources:
            link = f"({src.file}#{src.anchor})"
            # A figure left out of the README may share its section with one in it.
            assert (link in readme) == (fig.readme or link in shown), fig.id


def test_github_anchors():
    assert slug("Against SPZ v4: gspc's bytes at SPZ v4's PSNR / SPZ v4's bytes") == (
        "against-spz-v4-gspcs-bytes-at-spz-v4s-psnr--spz-v4s-bytes"
    )
    assert slug("After c3b56d0: positions in cubic voxels (2026-11-28)") == (
        "after-c3b56d0-positions-in-cubic-voxels-2026-11-28"
    )
    assert slug("The high preset's classes past 2^-3") == "the-high-presets-classes-past-2-3"


def test_values_are_written_as_the_bench_files_write_them():
    assert Value(value=467536, unit="B").text() == "467,536 B"
    assert Value(value=47.2, decimals=2, unit="dB", of="vs photos").text() == "47.20 dB vs photos"
    assert Value(low=0.41, high=0.496, decimals=3, unit="x").text() == "0.410-0.496x"


def test_markers_are_required():
    with pytest.raises(ValueError, match="markers"):
        with_block("no markers here", "| a |", "X.md")
    assert with_block(f"a\n{BEGIN}\nold\n{END}\nb", "new", "X.md") == f"a\n{BEGIN}\nnew\n{END}\nb"
