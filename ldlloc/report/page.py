"""The HTML page of ``ldlloc report --html``: one self-contained file (inline CSS, SVG plots, JPEG
thumbnails as data URIs; no script, no network), sections in this order:

1. the summary: counts, statuses, verdicts, and with ground truth the paper's accuracies and median errors;
2. per split (ground truth): the accuracy table;
3. plots: the confidence histogram (records with ``confidence``), error CDFs per split (ground truth);
4. the median seconds of each stage;
5. one row per query, worst first (:func:`worst_first`), with its thumbnail (:mod:`.thumbnails`) and,
   beside its verdict, why each competing pose competes (an identical room's copy: its map and place).
"""

from __future__ import annotations

from datetime import datetime, timezone
from html import escape
from pathlib import Path
from typing import Any

import numpy as np

from ldlloc.batch.accuracy import STAGES, THRESHOLDS, group_by, summarize
from ldlloc.record import QueryResult
from ldlloc.batch.results import unfinished_note
from ldlloc.report.plots import cdf_svg, histogram_svg
from ldlloc.report.walk import map_lines_xy, walk_svg

MARK = "<!-- ldlloc report -->"  # second line of every page: a page this command may replace
PAGE_HEAD = f"<!DOCTYPE html>\n{MARK}\n"  # how every page begins; a file that begins otherwise is not ours
VERDICT_COLORS = {"confident": "#2e8540", "ambiguous": "#c77700", "failed": "#b3261e", "none": "#8a8a8a"}
STATUS_COLORS = {"ok": "#2e8540", "coarse": "#c77700", "failed": "#b3261e"}

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:24px;color:#222;background:#fafafa}
h1{font-size:22px;margin:0 0 4px} h2{font-size:17px;margin:26px 0 8px;border-bottom:1px solid #ddd;padding-bottom:4px}
.meta{color:#666;font-size:13px}
.cards{display:flex;flex-wrap:wrap;gap:10px;margin-top:12px}
.card{background:#fff;border:1px solid #ddd;border-radius:6px;padding:8px 14px;min-width:110px}
.card b{display:block;font-size:20px} .card span{color:#666;font-size:12px}
table{border-collapse:collapse;background:#fff;font-size:13px}
th,td{border:1px solid #ddd;padding:4px 8px;text-align:right;vertical-align:middle}
th{background:#f0f0f0} td.l,th.l{text-align:left}
.plots{display:flex;flex-wrap:wrap;gap:12px} .plots svg{background:#fff;border:1px solid #ddd}
.badge{display:inline-block;color:#fff;border-radius:4px;padding:1px 6px;font-size:12px;margin:1px 0}
.bar{display:inline-block;height:10px;background:#4e79a7;vertical-align:middle}
img.thumb{display:block;width:384px;height:192px}
.note{color:#8a4b00;font-size:12px;text-align:left}
.unfinished{background:#fff3e0;border:1px solid #c77700;border-radius:6px;padding:8px 12px;color:#8a4b00;
font-weight:600}
td.q{max-width:260px;overflow-wrap:break-word}
td.c{white-space:nowrap;font-variant-numeric:tabular-nums} td.c i{color:#666;font-style:normal}
.nothumb{width:384px;height:60px;display:flex;align-items:center;justify-content:center;color:#b3261e;
background:#fff3f2;font-size:12px;text-align:center}
"""


def has_ground_truth(records: list[dict]) -> bool:
    return any(q.get("t_error_m") is not None for q in records)


def normalized_error(q: dict) -> float:
    """A query's error as a multiple of the headline threshold (0.1 m, 5 deg): the larger of
    ``t_error / 0.1 m`` and ``r_error / 5 deg``; infinite for a failed query or without errors."""
    _, t_max, r_max = THRESHOLDS[1]
    t, r = q.get("t_error_m"), q.get("r_error_deg")
    if q.get("status") == "failed" or t is None or r is None:
        return float("inf")
    return max(t / t_max, r / r_max)


def worst_first(records: list[dict]) -> list[dict]:
    """The records worst first: with ground truth by :func:`normalized_error`, largest first;
    without it failed ones first, then by confidence, lowest first (then coarse before ok)."""
    if has_ground_truth(records):
        return sorted(records, key=lambda q: (-normalized_error(q), q["name"]))

    def key(q: dict):
        c = q.get("confidence")
        return (q.get("status") != "failed", -1.0 if c is None else c, q.get("status") != "coarse", q["name"])

    return sorted(records, key=key)


def breakable(name: str) -> str:
    """``name`` escaped for HTML, with a line-break opportunity after each ``/`` and ``_`` so a long
    query name wraps between its parts, not inside a word."""
    return escape(name).replace("/", "/<wbr>").replace("_", "_<wbr>")


def _fmt(x: float | None, spec: str) -> str:
    return "–" if x is None or not np.isfinite(x) else format(x, spec)


def _badge(text: str, color: str) -> str:
    return f'<span class="badge" style="background:{color}">{escape(text)}</span>'


def _cards(records: list[dict], results: list[QueryResult]) -> str:
    s = summarize(results)
    statuses = {k: sum(q.get("status") == k for q in records) for k in ("ok", "coarse", "failed")}
    cards = [(str(len(records)), "queries"), (str(statuses["ok"]), "refined (ok)"),
             (str(statuses["coarse"]), "coarse only"), (str(statuses["failed"]), "failed")]
    verdicts = [q.get("verdict") for q in records]
    if any(v is not None for v in verdicts):
        cards += [(str(sum(v == k for v in verdicts)), f"verdict {k}") for k in ("confident", "ambiguous", "failed")]
    if has_ground_truth(records):
        cards += [(_fmt(s["accuracy"][name], ".2f"), f"within {m:g} m, {d:g}°") for name, m, d in THRESHOLDS]
        cards += [(_fmt(s["median_t_error_m"], ".3f") + " m", "median t error"),
                  (_fmt(s["median_r_error_deg"], ".2f") + "°", "median R error")]
    return '<div class="cards">' + "".join(f'<div class="card"><b>{escape(v)}</b><span>{escape(k)}</span></div>'
                                           for v, k in cards) + "</div>"


def _split_table(results: list[QueryResult]) -> str:
    groups = list(group_by(results, "split").items())
    rows = groups + ([("all", results)] if len(groups) > 1 else [])
    head = "".join(f"<th>{escape(c)}</th>" for c in ("n", "failed", "median t (m)", "median R (°)",
                                                      *[f"{m:g} m, {d:g}°" for _, m, d in THRESHOLDS], "median s"))
    body = []
    for name, rs in rows:
        s = summarize(rs)
        cells = [str(s["count"]), str(s["failed"]), _fmt(s["median_t_error_m"], ".3f"),
                 _fmt(s["median_r_error_deg"], ".2f"), *[_fmt(s["accuracy"][k], ".2f") for k, _, _ in THRESHOLDS],
                 _fmt(s["median_seconds"].get("total"), ".2f")]
        body.append(f'<tr><td class="l">{escape(name)}</td>' + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return f'<table><tr><th class="l">split</th>{head}</tr>{"".join(body)}</table>'


def _plots(records: list[dict], results: list[QueryResult]) -> str:
    svgs = []
    conf = [(q.get("confidence"), q.get("verdict") or "none") for q in records if q.get("confidence") is not None]
    if conf:
        edges = np.linspace(0.0, 1.0, 11)
        labels = [k for k in ("confident", "ambiguous", "failed", "none") if any(v == k for _, v in conf)]
        stacks = {k: np.histogram([c for c, v in conf if v == k], bins=edges)[0] for k in labels}
        svgs.append(histogram_svg(stacks, edges, VERDICT_COLORS, f"confidence ({len(conf)} queries)",
                                  "confidence"))
    if has_ground_truth(records):
        _, t_max, r_max = THRESHOLDS[1]
        by_split = group_by(results, "split")
        inf = float("inf")
        t_series = {k: np.array([inf if r.t_error_m is None else r.t_error_m for r in rs]) for k, rs in by_split.items()}
        r_series = {k: np.array([inf if r.r_error_deg is None else r.r_error_deg for r in rs])
                    for k, rs in by_split.items()}
        svgs.append(cdf_svg(t_series, "translation error, per split", "metres (log)", 0.001, 10.0, t_max))
        svgs.append(cdf_svg(r_series, "rotation error, per split", "degrees (log)", 0.01, 180.0, r_max))
    if not svgs:
        return '<p class="meta">no confidences and no ground truth in this file: nothing to plot</p>'
    return '<div class="plots">' + "".join(svgs) + "</div>"


def _timings(results: list[QueryResult]) -> str:
    ok = [r for r in results if r.status != "failed"]
    med = summarize(ok)["median_seconds"] if ok else {}
    stages = [s for s in STAGES if med.get(s) is not None] + sorted(s for s in med if s not in STAGES and med[s] is not None)
    if not stages:
        return '<p class="meta">no timings (no query was localized)</p>'
    longest = max(med[s] for s in stages) or 1.0
    rows = "".join(f'<tr><td class="l">{escape(s)}</td><td>{med[s]:.3f}</td><td class="l"><span class="bar" '
                   f'style="width:{max(1, round(240 * med[s] / longest))}px"></span></td></tr>' for s in stages)
    return (f'<table><tr><th class="l">stage</th><th>median s</th><th class="l"></th></tr>{rows}</table>'
            f'<p class="meta">medians over the {len(ok)} localized queries</p>')


def _query_rows(records: list[dict], thumbs: dict, limit: int) -> str:
    gt = has_ground_truth(records)
    with_verdict = any(q.get("verdict") is not None for q in records)
    with_conf = any(q.get("confidence") is not None for q in records)
    head = ["#", "thumbnail: the map's lines at the estimated pose", "query", "status"]
    head += (["verdict"] if with_verdict else []) + (["confidence"] if with_conf else [])
    head += ["t error (m)", "R error (°)"] if gt else []
    head += ["camera centre (m)", "matches / inliers", "s"]
    rows = []
    for i, q in enumerate(records, start=1):
        th = thumbs.get(q["name"])
        if th is None:
            pic = f'<div class="nothumb">thumbnail left out (--max-thumbnails {limit})</div>'
        elif th.data_uri is None:
            pic = f'<div class="nothumb">{escape(th.note)}</div>'
        else:
            img = f'<img class="thumb" alt="{escape(q["name"])}" src="{th.data_uri}">'
            pic = img if th.href is None else (f'<a href="{escape(th.href)}" target="_blank" '
                                               f'title="open the panorama">{img}</a>')
        note = [th.note] if th is not None and th.data_uri is not None and th.note else []
        if q.get("message"):
            note.append(q["message"])
        verdict = q.get("verdict")
        t = q.get("t")
        cells = [f"<td>{i}</td>", f'<td class="l">{pic}</td>',
                 f'<td class="l q"><b>{breakable(q["name"])}</b><br><span class="meta">{escape(q["scene"])} · '
                 f'{escape(q["split"])} · {escape(Path(q["image"]).name)}</span>'
                 + "".join(f'<div class="note">{escape(n)}</div>' for n in note) + "</td>",
                 f'<td>{_badge(q.get("status", "ok"), STATUS_COLORS.get(q.get("status", "ok"), "#8a8a8a"))}</td>']
        if with_verdict:
            named = "".join(f'<div class="note">{escape(str(c.get("why", "")))}</div>' for c in q.get("competitors") or [])
            cells.append(f'<td>{_badge(verdict or "none", VERDICT_COLORS.get(verdict or "none", "#8a8a8a"))}{named}</td>')
        if with_conf:
            cells.append(f'<td>{_fmt(q.get("confidence"), ".2f")}</td>')
        if gt:
            cells += [f'<td>{_fmt(q.get("t_error_m"), ".3f")}</td>', f'<td>{_fmt(q.get("r_error_deg"), ".2f")}</td>']
        centre = "–" if t is None else "<br>".join(f"<i>{a}</i> {v:.2f}" for a, v in zip("xyz", t))
        cells += [f'<td class="c">{centre}</td>', f'<td>{q.get("num_matches", 0)} / {q.get("num_inliers", 0)}</td>',
                  f'<td>{_fmt((q.get("seconds") or {}).get("total"), ".2f")}</td>']
        rows.append(f'<tr class="query">{"".join(cells)}</tr>')
    header = "".join(f'<th class="l">{escape(h)}</th>' if h.startswith(("thumbnail", "query")) else
                     f"<th>{escape(h)}</th>" for h in head)
    return f'<table id="queries"><tr>{header}</tr>{"".join(rows)}</table>'


def render_page(results_path: Path, records: list[dict], meta: dict[str, Any], thumbs: dict, limit: int) -> str:
    """The whole page (``records`` in the order shown: :func:`worst_first`)."""
    results = [QueryResult.from_dict(q) for q in records]
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    show = lambda v: ", ".join(map(str, v)) if isinstance(v, (list, tuple)) else str(v)  # noqa: E731
    info = " · ".join(f"{k} {escape(show(meta[k]))}" for k in ("dataset", "root", "splits", "maps", "device")
                      if meta.get(k) not in (None, ""))
    order = ("worst first: by the larger of t error / 0.1 m and R error / 5°" if has_ground_truth(records) else
             "worst first: failed, then by confidence (lowest first)")
    unfinished = unfinished_note(records, meta)
    sections = [f"<h1>Localization report: {escape(results_path.name)}</h1>",
                f'<p class="meta">{escape(str(results_path))} · {info} · written {when}</p>',
                *([f'<p class="unfinished">{escape(unfinished)}</p>'] if unfinished else []),
                "<h2>Summary</h2>", _cards(records, results)]
    if has_ground_truth(records):
        sections += ["<h2>Accuracy per split</h2>", _split_table(results)]
    walk = walk_svg(records, VERDICT_COLORS, map_lines_xy(records))  # a walk's top view (ldlloc/report/walk.py)
    if walk is not None:
        sections += ["<h2>Walk (top view, coloured by verdict)</h2>", walk]
    sections += ["<h2>Plots</h2>", _plots(records, results), "<h2>Seconds per stage</h2>", _timings(results),
                 f'<h2>Queries ({len(records)}, {order})</h2>',
                 '<p class="meta">lines coloured by the map\'s principal direction: red, green, blue; grey: none</p>',
                 _query_rows(records, thumbs, limit)]
    body = "\n".join(sections)
    return (f'{PAGE_HEAD}<html lang="en"><head><meta charset="utf-8">'
            f"<title>ldlloc report: {escape(results_path.name)}</title><style>{CSS}</style></head>"
            f"<body>\n{body}\n</body></html>\n")
