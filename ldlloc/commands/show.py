"""What ``ldlloc run`` and ``ldlloc report`` print about a set of results: tables, verdicts, the
pose search's own accuracy, failures, and where the results went."""

from __future__ import annotations

from pathlib import Path

from ldlloc.batch.accuracy import has_ground_truth, summarize, summary_table, timing_table, verdict_line
from ldlmap.core.cli_common import console
from ldlmap.core.errors import InputError


def shown(text: str) -> str:
    """``text`` as the terminal can print it: a file name's bytes that are not UTF-8 as escapes."""
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    except UnicodeEncodeError:
        return text.encode("utf-8", "backslashreplace").decode("utf-8")


def say(message: str) -> None:
    """One line of a run (a warning, the resume summary), as the terminal can print it."""
    console.print(shown(message), soft_wrap=True, highlight=False)


def print_run(results: list, label: str, output: Path, max_tilt: float | None) -> None:
    """The tables of a run, its failures and pictures not written, and where the results went; a
    run in which no query could be localized is an error (exit 1) after its failures."""
    failed = [r for r in results if r.status == "failed"]
    if len(failed) < len(results) and not has_ground_truth(results):  # image runs: counts by map, timings
        console.print(summary_table(results, "scene", f"{label} by map"))
        console.print(timing_table(results))
    elif len(failed) < len(results):
        console.print(summary_table(results, "scene", f"{label} by scene"))
        console.print(summary_table(results, "split", f"{label} by split"))
        console.print(timing_table(results))
        print_priors_and_search(results, max_tilt)
        print_own_maps(results)
    print_verdicts(results)
    for r in failed[:10]:
        console.print(f"[yellow]failed[/] {shown(r.name)}: {shown(r.message)}", soft_wrap=True)
    if len(failed) > 10:
        console.print(f"... and {len(failed) - 10} more failures (see {output})", soft_wrap=True)
    no_picture = [r for r in results if r.picture_error]
    if no_picture:
        console.print(f"[yellow]warning:[/] {len(no_picture)} pictures not written (first: {no_picture[0].picture_error}); "
                      f"their results are kept", soft_wrap=True)
    csv_path = output.with_suffix(".csv")
    console.print(f"wrote {output}" + (f" and {csv_path}" if csv_path.exists() else f" ({csv_path} not written)"),
                  soft_wrap=True)
    if results and len(failed) == len(results):
        raise InputError(f"none of the {len(results)} queries could be localized (reasons above, and in {output})")


def print_own_maps(results: list) -> None:
    """--scene-unknown: how often the chosen map is the query's own scene's."""
    chosen = [r for r in results if r.status != "failed" and r.map is not None]
    if chosen:
        own = sum(Path(r.map).stem == Path(r.scene).name for r in chosen)
        console.print(f"scene unknown: the chosen map is the query's own for {own} / {len(chosen)} "
                      "(maps of one folder share a frame: another map's pose can be right)", soft_wrap=True)


def print_priors_and_search(results: list, max_tilt: float | None) -> None:
    """The rotation priors that ran and the pose search's own accuracy."""
    priors = sorted({r.rotation_prior for r in results})
    console.print(f"rotation prior: {', '.join(priors)}" + ("" if max_tilt is None else f" (--max-tilt {max_tilt:g})"),
                  soft_wrap=True)
    print_search_summary(results)


def print_verdicts(results: list) -> None:
    """How many poses are confident, ambiguous, failed (and how right the confident ones are)."""
    line = verdict_line(results)
    if line:
        console.print(line, soft_wrap=True, highlight=False)


def print_search_summary(results: list) -> None:
    """The pose search alone: its best pose, and the best of its top K, within 0.5 m / 10 deg."""
    search, n = summarize(results).get("search"), len(results)
    if search:
        top1, topk = search["top1_0.5m_10deg"], search["topk_0.5m_10deg"]
        console.print(f"pose search: top-1 within 0.5 m / 10 deg {top1:.3f} ({round(top1 * n)} / {n}), "
                      f"best of the top K {topk:.3f} ({round(topk * n)} / {n})", soft_wrap=True)
