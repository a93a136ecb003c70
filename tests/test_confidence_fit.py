"""Fitting the confidence and judging it leave-one-kind-out (ldlloc/confidence_fit.py) on small
constructed tables: a kind calibrated like the others keeps its precision when held out; a kind
whose poses are right only at larger margins shows the miscalibration that a fit including it
would hide; the rules that need no fitting hold whatever the fit."""

from __future__ import annotations

import numpy as np
import pytest

from ldlloc.confidence_fit import TARGET_PRECISION, fit, held_out_counts, judged, leave_one_kind_out, model_of

SIGNALS = ("gap", "margin", "refined")


def _kind(seed: int, right_above: float, n: int = 60, **extra) -> list[dict]:
    """``n`` refined line poses with margins spread over [0, 0.5]; right where the margin exceeds
    ``right_above``; a competitor named for each (an ``ambiguous`` verdict is possible)."""
    rng = np.random.default_rng(seed)
    margin = rng.uniform(0.0, 0.5, n)
    return [{"signals": {"gap": 0.5, "margin": float(m), "refined": 1.0, "physical": 1.0, "tie": 0.0, **extra},
             "competitors": ["other position (2.0 m)"], "good": bool(m > right_above)} for m in margin]


def test_fit_orders_the_signal_and_puts_the_threshold_at_the_target():
    rows = _kind(1, 0.2) + _kind(2, 0.2)
    f = fit(rows, SIGNALS)
    assert f["weights"]["margin"] > 0 and f["n"] == 120
    out = judged(rows, model_of(f))
    conf = [r for r in out if r["verdict"] == "confident"]
    assert len(conf) > 30 and np.mean([r["good"] for r in conf]) >= TARGET_PRECISION
    assert all(r["confidence"] < f["confident_at"] for r in out if r["verdict"] != "confident")


def test_leave_one_kind_out_finds_the_kind_the_fit_does_not_hold_on():
    kinds = {"rooms": _kind(1, 0.2), "floors": _kind(2, 0.2), "shells": _kind(3, 0.2),
             "copies": _kind(4, 0.35),  # right only at larger margins: the others' threshold is too low for it
             "real": _kind(5, 0.2, n=20)}
    table = leave_one_kind_out(kinds, SIGNALS, check_only=("real",))
    assert set(table) == set(kinds)
    for kind in ("rooms", "floors", "shells", "real"):
        c = table[kind]
        assert c["poses"] == len(kinds[kind]) and c["confident"] > 0
        assert c["precision"] >= TARGET_PRECISION, kind
    assert table["copies"]["precision"] < 0.9  # held out, its miscalibration shows
    # fitted with every kind, the threshold rises (the copies' wrong poses are in the fit), so the
    # in-sample precision of the copies looks better than what a new kind of data would get
    both = judged(kinds["copies"], model_of(fit([r for k in ("rooms", "floors", "shells", "copies") for r in kinds[k]],
                                                SIGNALS)))
    conf = [r for r in both if r["verdict"] == "confident"]
    assert np.mean([r["good"] for r in conf]) > table["copies"]["precision"]


def test_rules_without_fitting_hold_after_the_fit():
    """Unphysical poses are failed and tied ones never confident, whatever their margin; confident
    poses in a wrong copy are counted."""
    rows = _kind(1, 0.2) + _kind(2, 0.2)
    model = model_of(fit(rows, SIGNALS))
    odd = [{"signals": {"gap": 1.0, "margin": 0.5, "refined": 1.0, "physical": 0.0}, "competitors": [], "good": False},
           {"signals": {"gap": 1.0, "margin": 0.5, "refined": 1.0, "physical": 1.0, "tie": 1.0},
            "competitors": ["180-degree twin, refined"], "good": False},
           {"signals": {"gap": 1.0, "margin": 0.5, "refined": 1.0, "physical": 1.0}, "competitors": [], "good": False,
            "wrong_copy": True},
           {"signals": {}, "competitors": [], "good": False}]
    out = judged(odd, model)
    assert [r["verdict"] for r in out] == ["failed", "ambiguous", "confident", "failed"]
    assert out[0]["confidence"] == 0.0
    c = held_out_counts(out)
    assert (c["confident"], c["confident_right"], c["confident_wrong_copy"]) == (1, 0, 1)
    assert c["precision"] == pytest.approx(0.0)


def test_threshold_holds_in_every_kind():
    """Pooled, many easy right poses let the threshold fall below where a harder kind is right;
    with the kinds named, the threshold keeps every kind at the target."""
    easy = [{**r, "kind": "easy"} for r in _kind(1, 0.1, n=200)]
    hard = [{**r, "kind": "hard"} for r in _kind(2, 0.3, n=40)]
    pooled = fit([{k: v for k, v in r.items() if k != "kind"} for r in easy + hard], SIGNALS)
    per_kind = fit(easy + hard, SIGNALS)
    assert per_kind["confident_at"] > pooled["confident_at"]
    for rows in (easy, hard):
        conf = [r for r in judged(rows, model_of(per_kind)) if r["verdict"] == "confident"]
        assert conf and np.mean([r["good"] for r in conf]) >= TARGET_PRECISION
