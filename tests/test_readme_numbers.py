"""The README's "Numbers last measured" table holds one current figure per row, dated once; the
earlier figures live in docs/benchmarks.md (its readme-history section), so the table never
grows into a log."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")


def headline_rows(text: str) -> list[list[str]]:
    """The cells of the body rows of the table under the "Numbers last measured" heading."""
    section = text.split("## Numbers last measured", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("|")]
    return [[c.strip() for c in row.strip("|").split(" | ")] for row in rows[2:]]


def log_like_rows(text: str) -> list[str]:
    """Rows whose result names a date (an earlier run kept beside the current one) or whose
    "measured" cell names none or several days."""
    return [cells[0] for cells in headline_rows(text)
            if DATE.search(cells[1]) or len(set(DATE.findall(cells[2]))) != 1]


def test_a_dated_log_in_a_row_is_caught():
    table = ("## Numbers last measured\n\n| what | result | measured |\n|---|---|---|\n"
             "| `make test` | 1247 tests, 7 min (2026-11-25); 1246 tests, 9 min (2026-11-24) | 2026-11-25 |\n"
             "| demo | 48 / 48 | 2026-11-22; 2026-11-24 |\n| startup | 1.85 s | 2026-11-22 |\n")
    assert log_like_rows(table) == ["`make test`", "demo"]


def test_readme_rows_hold_one_current_figure_and_point_at_the_history():
    text = (REPO / "README.md").read_text(encoding="utf-8")
    rows = headline_rows(text)
    assert len(rows) >= 10 and all(len(cells) == 3 for cells in rows)
    assert log_like_rows(text) == []
    assert "docs/benchmarks.md#readme-history" in text
    assert '<a id="readme-history"></a>' in (REPO / "docs" / "benchmarks.md").read_text(encoding="utf-8")
