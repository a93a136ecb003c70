"""Lines on smooth surfaces: facets of a vault give no line; creases, steps and free
edges stay lines."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ldlmap.lines3d import Lines3DParams, SmoothParams, extract_lines
from ldlmap.lines3d.smooth import smooth_lines
from tests._room_cloud import _sample_face

R = 1.5  # vault radius (m); the vault's axis is y, its facets turn 7.5 deg each (below a 20 deg crease)
FACET_DEG = 7.5
LENGTH = 2.0


def _vault_point(deg: float) -> np.ndarray:
    return np.array([R * np.cos(np.radians(deg)), 0.0, 1.0 + R * np.sin(np.radians(deg))])


def _scene(rng: np.random.Generator, density: float = 8000.0) -> np.ndarray:
    """A faceted barrel vault (30-150 deg) on two vertical walls, which it meets at a 30 deg crease,
    a floor, and a wall at x = 4 carrying a board 2 cm proud of it (a door frame's step)."""
    y = np.array([0.0, LENGTH, 0.0])
    parts = []
    for a in np.arange(30.0, 150.0, FACET_DEG):
        p, q = _vault_point(a), _vault_point(a + FACET_DEG)
        parts.append(_sample_face(rng, p, q - p, y, density))
    for deg in (30.0, 150.0):  # side walls up to the vault's springing line
        top = _vault_point(deg)
        parts.append(_sample_face(rng, np.array([top[0], 0.0, 0.0]), np.array([0, 0, top[2]]), y, density))
    parts.append(_sample_face(rng, np.array([-R, 0.0, 0.0]), np.array([4.0 + R, 0, 0]), y, density))  # floor
    parts.append(_sample_face(rng, np.array([4.0, 0.0, 0.0]), np.array([0, 0, 0.8]), y, density))  # wall x = 4 ...
    parts.append(_sample_face(rng, np.array([4.0, 0.0, 1.4]), np.array([0, 0, 0.1]), y, density))  # ... round the board
    parts.append(_sample_face(rng, np.array([3.98, 0.0, 0.8]), np.array([0, 0, 0.6]), y, density))  # board front
    parts.append(_sample_face(rng, np.array([3.98, 0.0, 0.8]), np.array([0.02, 0, 0]), y, density))  # board sides
    parts.append(_sample_face(rng, np.array([3.98, 0.0, 1.4]), np.array([0.02, 0, 0]), y, density))
    P = np.concatenate(parts)
    return P + rng.normal(scale=0.003, size=P.shape)


def _along_y(x: float, z: float) -> np.ndarray:
    return np.array([[x, 0.2, z], [x, LENGTH - 0.2, z]])


@pytest.fixture(scope="module")
def vault() -> np.ndarray:
    return _scene(np.random.default_rng(23))


def test_smooth_lines_tells_facets_from_creases_steps_and_free_edges(vault):
    params = Lines3DParams()
    facet = [_along_y(*_vault_point(a)[[0, 2]]) for a in (30.0 + FACET_DEG * 4, 90.0, 30.0 + FACET_DEG * 11)]
    flat = [_along_y(4.0, 0.4)]  # on the plain wall
    crease = [_along_y(*_vault_point(30.0)[[0, 2]]), _along_y(*_vault_point(150.0)[[0, 2]])]  # vault on wall: 30 deg
    corner = [_along_y(4.0, 0.0)]  # floor on wall: 90 deg
    step = [_along_y(3.98, 0.8), _along_y(4.0, 0.8)]  # the board's lower edge, front and back (2 cm step)
    free = [_along_y(4.0, 1.5)]  # the wall's top: nothing scanned beyond
    lines = np.stack(facet + flat + crease + corner + step + free)
    got = smooth_lines(lines, vault, params)
    assert got.tolist() == [True] * 4 + [False] * 6
    # A crease angle below the facets' bend keeps the facets' lines too; 0 turns the check off.
    assert not smooth_lines(lines, vault, replace(params, smooth=SmoothParams(crease_deg=5.0)))[:3].any()
    assert not smooth_lines(lines, vault, replace(params, smooth=SmoothParams(crease_deg=0.0))).any()


def _near(lines: np.ndarray, x: float, z: float, tol: float = 0.04) -> np.ndarray:
    """Lines along y (within 5 deg) within ``tol`` of the line (x, z), at least 1 m long."""
    d = lines[:, 1] - lines[:, 0]
    length = np.linalg.norm(d, axis=1)
    along = np.abs(d[:, 1]) >= np.cos(np.radians(5.0)) * length
    off = np.hypot(lines[:, :, 0] - x, lines[:, :, 2] - z).max(axis=1)
    return along & (off <= tol) & (length >= 1.0)


def test_extracted_vault_has_lines_only_at_creases_and_steps(vault):
    """The whole extractor: with the check, no long line along the vault between its springing
    lines; without it (``smooth.crease_deg=0``), the facets' meeting lines come out."""

    def on_vault(lines: np.ndarray) -> int:
        mid = lines.mean(axis=1)
        r = np.hypot(mid[:, 0], mid[:, 2] - 1.0)
        ang = np.degrees(np.arctan2(mid[:, 2] - 1.0, mid[:, 0]))
        d = lines[:, 1] - lines[:, 0]
        along = np.abs(d[:, 1]) >= np.cos(np.radians(5.0)) * np.linalg.norm(d, axis=1)
        return int(np.sum(along & (np.abs(r - R) < 0.05) & (ang > 40.0) & (ang < 140.0)
                          & (np.linalg.norm(d, axis=1) >= 0.5)))

    lines = extract_lines(vault)
    assert on_vault(lines) == 0
    for x, z in (_vault_point(30.0)[[0, 2]], _vault_point(150.0)[[0, 2]], (4.0, 0.0)):
        assert _near(lines, x, z).any(), (x, z)  # the creases
    assert _near(lines, 3.99, 0.8).any() and _near(lines, 3.99, 1.4).any()  # the board's step edges
    before = extract_lines(vault, params=Lines3DParams(smooth=SmoothParams(crease_deg=0.0)))
    assert on_vault(before) >= 2
