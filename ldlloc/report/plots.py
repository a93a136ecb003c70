"""Small SVG plots written by hand for the HTML report: a (stacked) histogram and cumulative
distributions. Plain SVG text needs no plotting library (matplotlib is not a dependency of the
toolkit), stays sharp at any zoom and inlines into the page as it is.
"""

from __future__ import annotations

from html import escape

import numpy as np

HEIGHT = 240  # the plot's height in CSS pixels
PLOT_W = 196  # the axes' width: three plots of legends up to 21 characters side by side in a 1280-pixel window
LEFT, TOP, BOTTOM = 48, 26, 40  # margins: axes' labels and the title; the legend on the right (:func:`_right`)
LEGEND_CHAR_W = 5.8  # width of a character of the legend (font size 10, sans-serif: 5.7 measured in Chromium)
# Series colours (one per split, in order); none is close to the line colours of the thumbnails.
PALETTE = ("#4e79a7", "#f28e2b", "#76b7b2", "#b07aa1", "#9c755f", "#edc948", "#bab0ac", "#ff9da7", "#59a14f",
           "#e15759")
GRID = "#e3e3e3"
AXIS = "#555"


def _right(labels: list[str]) -> int:
    """The right margin that holds the legend of ``labels`` whole (swatch, gap, the longest label)."""
    return int(np.ceil(34 + LEGEND_CHAR_W * max((len(label) for label in labels), default=0)))


def _frame(title: str, xlabel: str, ylabel: str, body: list[str], right: int) -> str:
    """An ``<svg>`` with the title, the axis labels and ``body`` (elements in pixel coordinates);
    ``right``: the legend's margin (:func:`_right`)."""
    width = LEFT + PLOT_W + right
    x0, y0, x1 = LEFT, HEIGHT - BOTTOM, LEFT + PLOT_W
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{HEIGHT}" '
             f'viewBox="0 0 {width} {HEIGHT}" role="img" aria-label="{escape(title)}">',
             f'<text x="{width / 2:.0f}" y="16" text-anchor="middle" font-size="13" font-weight="bold">'
             f'{escape(title)}</text>',
             *body,
             f'<line x1="{x0}" y1="{y0}" x2="{x1}" y2="{y0}" stroke="{AXIS}"/>',
             f'<line x1="{x0}" y1="{TOP}" x2="{x0}" y2="{y0}" stroke="{AXIS}"/>',
             f'<text x="{(x0 + x1) / 2:.0f}" y="{HEIGHT - 6}" text-anchor="middle" font-size="11">{escape(xlabel)}</text>',
             f'<text x="12" y="{(TOP + y0) / 2:.0f}" text-anchor="middle" font-size="11" '
             f'transform="rotate(-90 12 {(TOP + y0) / 2:.0f})">{escape(ylabel)}</text>',
             "</svg>"]
    return "\n".join(parts)


def _ticks_y(top_value: float, fmt: str) -> list[str]:
    """Horizontal grid lines and labels at 0, 1/4, ..., 1 of ``top_value``."""
    out = []
    for k in range(5):
        y = HEIGHT - BOTTOM - k / 4 * (HEIGHT - BOTTOM - TOP)
        out.append(f'<line x1="{LEFT}" y1="{y:.1f}" x2="{LEFT + PLOT_W}" y2="{y:.1f}" stroke="{GRID}"/>')
        out.append(f'<text x="{LEFT - 4}" y="{y + 4:.1f}" text-anchor="end" font-size="10">'
                   f'{format(top_value * k / 4, fmt)}</text>')
    return out


def histogram_svg(stacks: dict[str, np.ndarray], edges: np.ndarray, colors: dict[str, str], title: str,
                  xlabel: str) -> str:
    """A stacked histogram: ``stacks`` maps a label to its counts per bin (``edges``: bin edges),
    drawn bottom-up in the order given, with a legend."""
    edges = np.asarray(edges, dtype=np.float64)
    counts = np.array([np.asarray(c, dtype=np.float64) for c in stacks.values()]).reshape(len(stacks), -1)
    peak = max(1.0, float(counts.sum(axis=0).max(initial=0.0)))
    top = float(np.ceil(peak / 4) * 4)
    sx = PLOT_W / (edges[-1] - edges[0])
    sy = (HEIGHT - BOTTOM - TOP) / top
    body = _ticks_y(top, ".0f")
    base = np.zeros(counts.shape[1])
    for (label, _), row in zip(stacks.items(), counts):
        for b, n in enumerate(row):
            if n > 0:
                x = LEFT + (edges[b] - edges[0]) * sx
                y = HEIGHT - BOTTOM - (base[b] + n) * sy
                body.append(f'<rect x="{x + 1:.1f}" y="{y:.1f}" width="{(edges[b + 1] - edges[b]) * sx - 2:.1f}" '
                            f'height="{n * sy:.1f}" fill="{colors.get(label, PALETTE[0])}"><title>{escape(label)}: '
                            f'{int(n)} in [{edges[b]:g}, {edges[b + 1]:g})</title></rect>')
        base += row
    for e in edges[:: max(1, (len(edges) - 1) // 5)]:
        x = LEFT + (e - edges[0]) * sx
        body.append(f'<text x="{x:.1f}" y="{HEIGHT - BOTTOM + 14}" text-anchor="middle" font-size="10">{e:g}</text>')
    body += _legend(list(stacks), colors)
    return _frame(title, xlabel, "queries", body, _right(list(stacks)))


def _legend(labels: list[str], colors: dict[str, str]) -> list[str]:
    """A swatch and the whole label per entry, right of the axes."""
    out = []
    for i, label in enumerate(labels):
        y = TOP + 6 + 14 * i
        out.append(f'<rect x="{LEFT + PLOT_W + 10}" y="{y - 8}" width="10" height="10" '
                   f'fill="{colors.get(label, PALETTE[i % len(PALETTE)])}"/>')
        out.append(f'<text x="{LEFT + PLOT_W + 24}" y="{y + 1}" font-size="10">{escape(label)}</text>')
    return out


def log_axis(values: list[np.ndarray], lo: float, hi: float, threshold: float | None = None) -> tuple[float, float]:
    """The decades a log axis spans to show the finite positive ``values`` and the ``threshold``:
    from the decade below the smallest to the decade above the largest, within ``[lo, hi]``."""
    v = np.concatenate([np.asarray(x, dtype=np.float64).ravel() for x in values] or [np.zeros(0)])
    v = v[np.isfinite(v) & (v > 0)]
    shown = np.concatenate([v, [threshold] if threshold is not None else []])
    if shown.size == 0:
        return lo, hi
    a = max(lo, 10.0 ** np.floor(np.log10(shown.min())))
    b = min(hi, 10.0 ** np.ceil(np.log10(shown.max())))
    if b <= a:  # every value on one power of ten: the decade above it
        b = min(hi, a * 10.0)
        a = min(a, b / 10.0)
    return float(a), float(b)


def cdf_svg(series: dict[str, np.ndarray], title: str, xlabel: str, lo: float, hi: float,
            threshold: float | None = None) -> str:
    """Cumulative distributions on a log x axis fitted to the values and ``threshold``
    (:func:`log_axis`, within ``lo`` to ``hi``): for each label, the fraction of its values at most
    x (non-finite values, failed queries, never count); a dashed line at ``threshold``."""
    lo, hi = log_axis(list(series.values()), lo, hi, threshold)
    lx0, lx1 = np.log10(lo), np.log10(hi)
    sx = PLOT_W / (lx1 - lx0)
    sy = HEIGHT - BOTTOM - TOP

    def px(v: float) -> float:
        return LEFT + (np.log10(np.clip(v, lo, hi)) - lx0) * sx

    body = _ticks_y(1.0, ".2f")
    for e in range(int(np.ceil(lx0)), int(np.floor(lx1)) + 1):
        x = px(10.0 ** e)
        body.append(f'<line x1="{x:.1f}" y1="{TOP}" x2="{x:.1f}" y2="{HEIGHT - BOTTOM}" stroke="{GRID}"/>')
        body.append(f'<text x="{x:.1f}" y="{HEIGHT - BOTTOM + 14}" text-anchor="middle" font-size="10">'
                    f'{10.0 ** e:g}</text>')
    if threshold is not None:
        x = px(threshold)
        body.append(f'<line x1="{x:.1f}" y1="{TOP}" x2="{x:.1f}" y2="{HEIGHT - BOTTOM}" stroke="{AXIS}" '
                    f'stroke-dasharray="4 3"><title>threshold {threshold:g}</title></line>')
    colors = {label: PALETTE[i % len(PALETTE)] for i, label in enumerate(series)}
    for label, values in series.items():
        v = np.asarray(values, dtype=np.float64)
        n = len(v)
        v = np.sort(v[np.isfinite(v)])
        if n == 0:
            continue
        pts, frac = [(px(lo), HEIGHT - BOTTOM)], 0.0
        for k, x in enumerate(v, start=1):  # a step up at each value
            pts.append((px(x), HEIGHT - BOTTOM - frac * sy))
            frac = k / n
            pts.append((px(x), HEIGHT - BOTTOM - frac * sy))
        pts.append((px(hi), HEIGHT - BOTTOM - frac * sy))
        path = " ".join(f"{x:.1f},{y:.1f}" for x, y in pts)
        body.append(f'<polyline points="{path}" fill="none" stroke="{colors[label]}" stroke-width="2">'
                    f'<title>{escape(label)}: {frac:.2f} of {n} within {hi:g}</title></polyline>')
    body += _legend(list(series), colors)
    return _frame(title, xlabel, "fraction of queries", body, _right(list(series)))
