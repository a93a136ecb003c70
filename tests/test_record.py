"""The results record is declared once (ldlloc/record.py): the checks, the docs and the writer come
from that declaration."""

from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path

import numpy as np

from ldlloc.batch.results import validate_results
from ldlloc.pipeline import Localization
from ldlloc.record import (FIELD_CHECKS, REQUIRED_FIELDS, QueryResult, failed_record, fields_table, printed_record,
                           record_json, record_of)

ROOT = Path(__file__).resolve().parents[1]


def test_docs_hold_the_table_of_the_record_fields():
    """docs/formats.md lists every field, as ldlloc/record.py declares it (regenerate the table with
    `python -m ldlloc.record` after a field changes)."""
    text = (ROOT / "docs" / "formats.md").read_text()
    begin, end = "<!-- record fields: begin -->\n", "\n<!-- record fields: end -->"
    assert begin in text and end in text
    table = text[text.index(begin) + len(begin):text.index(end)]
    assert table == fields_table()
    for f in fields(QueryResult):
        assert f"| `{f.name}`" in table


def test_every_field_has_a_check_a_meaning_and_a_source():
    assert list(FIELD_CHECKS) == [f.name for f in fields(QueryResult)]
    assert set(REQUIRED_FIELDS) == {"image", "scene", "split", "name", "status", "t_error_m", "r_error_deg"}
    for f in fields(QueryResult):
        assert f.metadata["meaning"] and f.metadata["what"] and callable(f.metadata["check"])


def _localization() -> Localization:
    R = np.eye(3)
    return Localization(rot_cam_from_world=R, center=np.array([1.0, 2.0, 0.5]), coarse_rot=R,
                        coarse_center=np.zeros(3), candidates_rot=np.stack([R, R]),
                        candidates_center=np.array([[1.0, 2.0, 0.5], [3.0, 0.0, 0.0]]),
                        seconds={"search": 0.123456, "total": 0.5}, num_rotations=4, num_lines=50, refined=True,
                        num_matches=10, num_inliers=8, refine_method="geometric",
                        candidates_loss=np.array([-20.0, -15.0]), confidence=0.9, verdict="confident",
                        confidence_signals={"margin": 0.5})


def test_a_written_record_reads_back_and_passes_the_checks():
    loc = _localization()
    rec = record_of(loc, "a.jpg", "room_1", "robot", "robot/a", truth=(np.eye(3), np.array([1.0, 2.0, 0.6])))
    assert abs(rec.t_error_m - 0.1) < 1e-9
    assert rec.first_good_rank == 1 and rec.best_candidate_t_error_m is not None
    line = json.loads(record_json(rec))
    assert list(line) == [f.name for f in fields(QueryResult)]
    back, _ = validate_results({"queries": [line]})
    assert back == [rec]
    failed = failed_record("b.jpg", "room_1", "robot", "robot/b", "too few lines", {}, "free")
    back, _ = validate_results({"queries": [json.loads(record_json(failed))]})
    assert back[0].status == "failed" and back[0].verdict == "failed" and back[0].confidence == 0.0


def test_localize_prints_the_record_rounded():
    loc = _localization()
    rec = record_of(loc, "a.jpg", "m", "images", "a", map="m.h5")
    out = printed_record(rec, loc.num_lines, {"read_map": 0.01})
    assert list(out)[:9] == ["image", "map", "R", "t", "status", "refined", "message", "num_rotations", "num_lines"]
    assert out["num_lines"] == 50 and out["map"] == "m.h5" and out["seconds"]["search"] == 0.1235
    assert [c["loss"] for c in out["candidates"]] == [-20.0, -15.0] and "input_frame" not in out
