"""The HTML report of a results file (``ldlloc report R.json --html FILE.html``): one self-contained
page (:mod:`.page`) with SVG plots (:mod:`.plots`) and a thumbnail per query (:mod:`.thumbnails`)."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from ldlloc.export.poses import read_records, resolve_path
from ldlloc.report.page import PAGE_HEAD, render_page, worst_first
from ldlloc.report.thumbnails import make_thumbnails
from ldlmap.core.errors import InputError, atomic_file, refuse_overwriting_inputs, refuse_replacing_other_files
from ldlmap.io.imagefile import printable

MAX_THUMBNAILS = 200  # default --max-thumbnails: the worst queries get one (~25 kB each in the page)
HTML_SUFFIXES = (".html", ".htm")


def check_html_path(path: str | Path) -> Path:
    """``path`` as an HTML output: a ``.html`` name that is not a folder, nor a file other than a page
    of this command (one-line errors, before any work)."""
    p = Path(path)
    if p.suffix.lower() not in HTML_SUFFIXES:
        raise InputError(f"--html must name a .html file, got {p}")

    def is_ours(q: Path) -> bool:  # the page's first two lines as render_page writes them, nothing else
        try:
            with open(q, "rb") as f:
                head = f.read(len(PAGE_HEAD) + 2)
        except OSError:
            return False
        return head.replace(b"\r\n", b"\n").startswith(PAGE_HEAD.encode())

    refuse_replacing_other_files(p, is_ours, "an HTML report of `ldlloc report`",  # report has no --overwrite
                                 remedy="remove it first, or give another name")
    return p


def write_html_report(results: str | Path, html: str | Path, max_thumbnails: int = MAX_THUMBNAILS,
                      progress: Callable[[int, int], None] | None = None) -> Path:
    """Write the report of ``results`` to ``html`` (atomically). ``max_thumbnails``: the worst
    queries that get a thumbnail; ``progress(done, total)`` after each thumbnail."""
    results, html = Path(results), check_html_path(html)
    records, meta = read_records(results)
    refuse_overwriting_inputs([results, *(resolve_path(q["image"], meta) for q in records)], [html])
    ordered = worst_first(records)
    shown = ordered[:max(0, max_thumbnails)]
    count = [0]

    def tick() -> None:
        count[0] += 1
        if progress is not None:
            progress(count[0], len(shown))

    thumbs = make_thumbnails(shown, meta, tick)
    page = render_page(results, ordered, meta, thumbs, max_thumbnails)
    with atomic_file(html) as tmp:
        tmp.write_text(printable(page), encoding="utf-8")  # names that are not UTF-8 shown as \xff
    return html


__all__ = ["MAX_THUMBNAILS", "check_html_path", "write_html_report"]
