"""Sampled box rooms with furniture boxes and their true edges (test/bench helper, numpy only).

Used by the 3D line, principal direction and translation tests and by ``bench/bench_lines3d.py``
so that they do not depend on the synthetic scene generator.
"""

from __future__ import annotations

import numpy as np

# Corners of the unit box [0, 1]^3 and its 12 edges / 6 faces (face: origin corner, two axes).
_CORNERS = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], dtype=np.float64)
_EDGES = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7],
                   [0, 4], [1, 5], [2, 6], [3, 7]])


def _box_faces(lo: np.ndarray, hi: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(origin, edge_a, edge_b) for the 6 faces of an axis-aligned box."""
    s = hi - lo
    ex, ey, ez = np.diag(s)
    return [(lo, ex, ey), (lo + ez, ex, ey), (lo, ex, ez), (lo + ey, ex, ez), (lo, ey, ez), (lo + ex, ey, ez)]


def _sample_face(rng: np.random.Generator, origin: np.ndarray, a: np.ndarray, b: np.ndarray,
                 density: float) -> np.ndarray:
    area = np.linalg.norm(np.cross(a, b))
    n = rng.poisson(area * density)
    uv = rng.random((n, 2))
    return origin + uv[:, :1] * a + uv[:, 1:] * b


def box_room(seed: int = 0, size=(6.0, 4.5, 2.8), n_boxes: int = 3, density: float = 6000.0,
             noise: float = 0.005, yaw_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A closed box room with ``n_boxes`` furniture boxes on the floor.

    Returns ``(points (N, 3), edges (E, 2, 3))``: surfaces sampled at ``density`` points per
    square metre with Gaussian ``noise`` (metres), floor under the boxes left empty (as a scanner
    would see it), and the true geometric edges (room edges, box edges including where boxes meet
    the floor). Everything is rotated by ``yaw_deg`` about +z around the room centre.
    """
    rng = np.random.default_rng(seed)
    room = np.asarray(size, dtype=np.float64)
    boxes = []
    for _ in range(n_boxes * 20):
        if len(boxes) == n_boxes:
            break
        bs = np.array([rng.uniform(0.5, 1.4), rng.uniform(0.5, 1.2), rng.uniform(0.5, 1.2)])
        lo = np.array([rng.uniform(0.3, room[0] - bs[0] - 0.3), rng.uniform(0.3, room[1] - bs[1] - 0.3), 0.0])
        hi = lo + bs
        if all(np.any(lo[:2] > h[:2] + 0.3) or np.any(hi[:2] < l[:2] - 0.3) for l, h in boxes):
            boxes.append((lo, hi))
    pts = [_sample_face(rng, o, a, b, density) for o, a, b in _box_faces(np.zeros(3), room)]
    floor = np.concatenate([pts[0]])
    keep = np.ones(len(floor), bool)
    for lo, hi in boxes:
        keep &= ~np.all((floor[:, :2] > lo[:2]) & (floor[:, :2] < hi[:2]), axis=1)
    pts[0] = floor[keep]
    edges = [(_CORNERS[_EDGES] * room)]
    for lo, hi in boxes:
        faces = _box_faces(lo, hi)[1:]  # no bottom face
        pts += [_sample_face(rng, o, a, b, density) for o, a, b in faces]
        edges.append(lo + _CORNERS[_EDGES] * (hi - lo))
    P = np.concatenate(pts)
    P = P + rng.normal(scale=noise, size=P.shape)
    E = np.concatenate(edges)
    c = np.radians(yaw_deg)
    R = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    centre = np.array([room[0] / 2, room[1] / 2, 0.0])
    return (P - centre) @ R.T + centre, (E - centre) @ R.T + centre
