"""SfM-like 3D line sets from true room edges (test/bench helper, numpy only).

Line3D++ on photos gives a room's or building's edges as many short, noisy pieces (a real
building's: 2503 segments, 0.8 % longer than the paper's threshold), plus clutter
(texture, furniture seen from few views) and a few far outliers, in the SfM frame: any rotation,
any unit, any origin. :func:`sfm_like_lines` makes such a set from metric, z-up true edges (e.g.
``tests._room_cloud.box_room`` or a synthetic scene's ``gt_lines``) and returns the truth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def rotation_with_up(up_axis: np.ndarray, yaw_deg: float = 0.0) -> np.ndarray:
    """A rotation R (input = R @ map) that sends map +z to ``up_axis`` after a yaw about z."""
    u = np.asarray(up_axis, dtype=np.float64)
    u = u / np.linalg.norm(u)
    a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, u)
    x /= np.linalg.norm(x)
    B = np.stack([x, np.cross(u, x), u], axis=1)  # columns: images of map x, y, z
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return B @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def fragment(edges: np.ndarray, rng: np.random.Generator, piece_mean: float = 0.12, gap=(0.0, 0.15),
             noise: float = 0.01) -> np.ndarray:
    """Each edge as consecutive pieces (lengths 3 cm plus an exponential of mean ``piece_mean``:
    mostly short, a few long; gaps ``gap``, metres) with Gaussian end-point ``noise``."""
    out = []
    for a, b in np.asarray(edges, dtype=np.float64):
        length = float(np.linalg.norm(b - a))
        d = (b - a) / max(length, 1e-12)
        s = rng.uniform(0, gap[1])
        while s < length:
            e = min(length, s + 0.03 + rng.exponential(piece_mean))
            out.append([a + s * d, a + e * d])
            s = e + rng.uniform(*gap)
    P = np.asarray(out)
    return P + rng.normal(scale=noise, size=P.shape)


def clutter(bmin: np.ndarray, bmax: np.ndarray, n: int, rng: np.random.Generator, length=(0.03, 0.25)) -> np.ndarray:
    """``n`` short segments of random direction inside the box."""
    a = rng.uniform(bmin, bmax, size=(n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.stack([a, a + rng.uniform(*length, (n, 1)) * d], axis=1)


def sfm_like_lines(edges: np.ndarray, rng: np.random.Generator, rotation: np.ndarray = np.eye(3),
                   units_per_metre: float = 1.0, offset=(0.0, 0.0, 0.0), clutter_ratio: float = 0.3,
                   far_outliers: int = 8, fragmented: bool = True, noise: float = 0.01) -> np.ndarray:
    """Metric z-up ``edges`` (E, 2, 3) as an SfM line set: fragmented, noisy, with clutter and
    ``far_outliers`` segments 30-60 m away, then ``X_in = units_per_metre * rotation @ X + offset``."""
    L = fragment(edges, rng, noise=noise) if fragmented else np.asarray(edges, dtype=np.float64)
    lo, hi = L.reshape(-1, 3).min(0), L.reshape(-1, 3).max(0)
    parts = [L, clutter(lo, hi, int(clutter_ratio * len(L)), rng)]
    if far_outliers:
        c = rng.normal(size=(far_outliers, 3))
        c = (lo + hi) / 2 + c / np.linalg.norm(c, axis=1, keepdims=True) * rng.uniform(30, 60, (far_outliers, 1))
        parts.append(np.stack([c, c + rng.uniform(-0.5, 0.5, (far_outliers, 3))], axis=1))
    L = np.concatenate(parts)
    L = L[rng.permutation(len(L))]
    return units_per_metre * L @ np.asarray(rotation).T + np.asarray(offset, dtype=np.float64)


def write_line3dpp_txt(path: str | Path, segs: np.ndarray) -> Path:
    """Line3D++ ``.txt``: one segment per row with one made-up 2D observation."""
    rows = [f"1 {' '.join(f'{v:.6f}' for v in s.ravel())} 1 0 {i} 10 10 20 20" for i, s in enumerate(segs)]
    Path(path).write_text("\n".join(rows) + "\n")
    return Path(path)
