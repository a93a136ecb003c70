"""``ldlloc report``: the tables of a results file again, and its HTML page (:mod:`ldlloc.report`)."""

from __future__ import annotations

from pathlib import Path

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from ldlloc.batch.accuracy import has_ground_truth, summary_table, timing_table
from ldlloc.batch.results import load_results, unfinished_note
from ldlloc.commands.show import print_own_maps, print_search_summary, print_verdicts
from ldlloc.report import check_html_path, write_html_report
from ldlmap.core.cli_common import check_range, console


def report(results: Path, html: Path | None, max_thumbnails: int) -> None:
    """The command (its options: :func:`ldlloc.cli.report`)."""
    check_range(max_thumbnails, "--max-thumbnails", 0, 100000, integer=True)
    if html is not None:
        check_html_path(html)  # before the results are read (write_html_report checks it again)
    rs, meta = load_results(results)
    unfinished = unfinished_note(rs, meta)
    if unfinished:
        console.print(f"[yellow]warning:[/] {results}: {unfinished}", soft_wrap=True, highlight=False)
    console.print(summary_table(rs, "scene", f"{results} by scene"))
    console.print(summary_table(rs, "split", f"{results} by split"))
    console.print(timing_table(rs))
    print_search_summary(rs)
    if has_ground_truth(rs):
        print_own_maps(rs)
    print_verdicts(rs)
    if html is not None:
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), console=console,
                      transient=True) as bar:
            task = bar.add_task("thumbnails", total=None)
            write_html_report(results, html, max_thumbnails,
                              progress=lambda done, total: bar.update(task, completed=done, total=total))
        console.print(f"wrote {html}", soft_wrap=True, highlight=False)
