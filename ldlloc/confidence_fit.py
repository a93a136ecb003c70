"""Fitting the confidence model (:data:`ldlloc.confidence.MODEL`) and judging the fit on kinds of
data it never saw (``bench/bench_confidence.py`` runs both; docs/measurements.md#confidence).

A *row* is one localized query: ``{"signals": its confidence_signals ({} without a pose),
"competitors": the named competitors (any list), "good": within 0.25 m / 5 deg}`` and optionally
``"wrong_copy"`` (the pose lies in another copy of an identical room). Rows are grouped by *kind*
(demo rooms, multiroom, a layout shape, the building, the real home): :func:`leave_one_kind_out`
fits on every kind but one and counts what the fit marks ``confident`` on that one.
"""

from __future__ import annotations

import numpy as np

from ldlmap.core.lazy import lazy_module
from ldlloc.confidence import MODEL, ConfidenceModel, effective_signals, judge

optimize = lazy_module("scipy.optimize")

TARGET_PRECISION = 0.98  # the threshold keeps >= 98 % of the fitted confident poses right (the confidence's target)
L2 = 0.1  # ridge weight on the standardized signals (the logistic must not chase a few queries)
MIN_CONFIDENT = 10  # the threshold stops falling once this many fitted poses above it miss the target


def judged(rows: list[dict], model: ConfidenceModel = MODEL) -> list[dict]:
    """The rows with ``confidence`` and ``verdict`` of ``model`` (:func:`ldlloc.confidence.judge`);
    a query without a pose is failed."""
    out = []
    for r in rows:
        conf, verdict = judge(r["signals"], r["competitors"], model) if r["signals"] else (0.0, "failed")
        out.append({**r, "confidence": conf, "verdict": verdict})
    return out


def fit(rows: list[dict], signals: tuple[str, ...]) -> dict:
    """L2-regularized logistic with non-negative weights on the standardized ``signals`` as the
    model weighs them (:func:`ldlloc.confidence.effective_signals`), folded back to raw weights, and
    the smallest threshold at which the confident poses are >= :data:`TARGET_PRECISION` right in
    every kind of data (``row["kind"]``; one pool when the rows name none): pooled, an easy kind
    with many right poses lowers the threshold below what a harder kind holds.
    Poses the rules that need no fitting judge (``physical`` 0: no camera there; ``tie`` or
    ``copies``: never confident) are left out of the threshold's choice, and the unphysical ones out of the fit.
    Non-negative: no signal may lower the confidence as it grows (explainable, and a quirk of one
    kind of data cannot be learnt backwards)."""
    rows = [r for r in rows if r["signals"] and float(r["signals"].get("physical", 1.0)) >= 0.5]
    eligible = np.array([float(r["signals"].get("tie", 0.0)) == 0 and float(r["signals"].get("copies", 0.0)) == 0
                         for r in rows], dtype=bool)
    X = np.array([[effective_signals(r["signals"]).get(k, 0.0) for k in signals] for r in rows], float).reshape(
        len(rows), len(signals))
    y = np.array([r["good"] for r in rows], float)
    mu, sd = X.mean(0), X.std(0).clip(1e-6)
    Z = (X - mu) / sd

    def nll(w):
        z = w[0] + Z @ w[1:]
        return float(np.sum(np.logaddexp(0, z) - y * z) + L2 * np.sum(w[1:] ** 2))

    bounds = [(None, None)] + [(0.0, None)] * X.shape[1]
    w = optimize.minimize(nll, np.zeros(X.shape[1] + 1), method="L-BFGS-B", bounds=bounds).x
    weights = w[1:] / sd
    bias = w[0] - float(np.sum(w[1:] * mu / sd))
    p = 1 / (1 + np.exp(-(bias + X @ weights)))
    kind = np.array([str(r.get("kind", "")) for r in rows])
    threshold = 1.0
    for t in np.unique(p[eligible])[::-1]:  # lower the threshold while the confident ones stay right enough
        sel = (p >= t) & eligible
        if all(np.mean(y[sel & (kind == k)]) >= TARGET_PRECISION for k in np.unique(kind[sel])):
            threshold = float(t)
        elif sel.sum() >= MIN_CONFIDENT:
            break
    return {"bias": round(float(bias), 3), "weights": {k: round(float(v), 3) for k, v in zip(signals, weights)},
            "confident_at": round(threshold, 3), "n": int(len(y)), "right": int(y.sum())}


def model_of(fitted: dict) -> ConfidenceModel:
    """The :class:`ldlloc.confidence.ConfidenceModel` of a :func:`fit` result."""
    return ConfidenceModel(bias=fitted["bias"], weights=dict(fitted["weights"]), confident_at=fitted["confident_at"])


def held_out_counts(rows: list[dict]) -> dict:
    """Of judged rows: poses, right ones, confident, confident right, precision (None without a
    confident pose) and confident poses in a wrong copy."""
    conf = [r for r in rows if r["verdict"] == "confident"]
    right = sum(bool(r["good"]) for r in conf)
    return {"poses": len(rows), "right": sum(bool(r["good"]) for r in rows), "confident": len(conf),
            "confident_right": right, "precision": right / len(conf) if conf else None,
            "confident_wrong_copy": sum(bool(r.get("wrong_copy")) for r in conf)}


def leave_one_kind_out(kinds: dict[str, list[dict]], signals: tuple[str, ...],
                       check_only: tuple[str, ...] = ()) -> dict[str, dict]:
    """For each kind (``{kind: rows}``) not named in ``check_only`` (prefixes): the model fitted on
    every other fitted kind (:func:`fit`) and its counts on this one (:func:`held_out_counts`,
    with ``confident_at``, the fitted threshold); a check-only kind is counted with the fit on
    every fitted kind."""
    fitted = [k for k in kinds if not k.startswith(check_only)] if check_only else list(kinds)
    out = {}
    for kind, rows in kinds.items():
        f = fit([{**r, "kind": k} for k in fitted if k != kind for r in kinds[k]], signals)
        out[kind] = {**held_out_counts(judged(rows, model_of(f))), "confident_at": f["confident_at"]}
    return out
