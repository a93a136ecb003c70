"""Small results files written by hand for the output tests: panoramas of a few pixels and records
with a pose, no map and no localization (export, report and pictures read only these)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np


def write_panorama(path: Path, width: int = 128) -> Path:
    """A 2:1 JPEG with a few edges, written through Python's file I/O (any file name)."""
    img = np.full((width // 2, width, 3), 200, np.uint8)
    img[:, ::16] = 40
    img[width // 4] = 90
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(cv2.imencode(".jpg", img)[1].tobytes())
    return path


def record(name: str, image: str | Path, t: tuple[float, float, float] = (0.5, 0.2, 1.5), **extra) -> dict:
    """A localized record of query ``name`` (identity rotation, camera centre ``t``), confident."""
    q = {"image": str(image), "scene": "room", "split": "images", "name": name, "status": "ok", "refined": True,
         "R": np.eye(3).tolist(), "t": list(t), "t_error_m": None, "r_error_deg": None, "seconds": {"total": 0.5},
         "confidence": 0.9, "verdict": "confident"}
    q.update(extra)
    return q


def write_results(path: Path, records: list[dict], **meta) -> Path:
    """A results file holding ``records`` and ``meta`` (``finished`` true unless given)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"format_version": 1, "meta": {"finished": True, **meta}, "queries": records}))
    return path


def without_timings(path: Path) -> dict:
    """Results file ``path`` parsed, without what two runs of the same work differ by: the seconds."""
    data = json.loads(path.read_text())
    for q in data["queries"]:
        q.pop("seconds")
    data["summary"].pop("median_seconds")
    return data
