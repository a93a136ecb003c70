"""Lines cut to where the planes beside them hold their direction: on a floor meeting a
curved wall (a fine polygon), chords and tangents of the arc are cut down; straight creases stay
whole."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ldlmap.lines3d import AlongParams, Lines3DParams, extract_lines
from ldlmap.lines3d.along import cut_to_edges
from ldlmap.lines3d.planes import segment_planes
from tests._room_cloud import _sample_face

C, R = np.array([1.0, 2.0]), 2.0  # the arc: centre and radius (m), from (1, 0) to (3, 2)
FACETS = 11  # 0.29 m facets turning 8.2 deg each (below the generator's 20 deg crease)
H = 1.0  # wall height


def _arc(n: int) -> np.ndarray:
    a = np.linspace(-np.pi / 2, 0.0, n + 1)
    return C + R * np.stack([np.cos(a), np.sin(a)], axis=1)


def _scene(rng: np.random.Generator, density: float = 8000.0) -> np.ndarray:
    """Floor of the room x in [0, 3], y in [0, 4] inside the arc, a straight wall y = 0 (x <= 1),
    the curved wall as facets, a straight wall x = 3 (y >= 2) and one at x = 0."""
    z = np.array([0.0, 0.0, H])
    parts = []
    V = _arc(FACETS)
    for p, q in zip(V[:-1], V[1:]):
        parts.append(_sample_face(rng, np.r_[p, 0.0], np.r_[q - p, 0.0], z, density))
    parts.append(_sample_face(rng, np.zeros(3), np.array([1.0, 0, 0]), z, density))  # y = 0
    parts.append(_sample_face(rng, np.array([3.0, 2.0, 0]), np.array([0, 2.0, 0]), z, density))  # x = 3
    parts.append(_sample_face(rng, np.zeros(3), np.array([0, 4.0, 0]), z, density))  # x = 0
    F = _sample_face(rng, np.zeros(3), np.array([3.0, 0, 0]), np.array([0, 4.0, 0]), density)
    inside = (F[:, 0] <= 1.0) | (F[:, 1] >= 2.0) | (np.hypot(F[:, 0] - C[0], F[:, 1] - C[1]) <= R)
    P = np.concatenate(parts + [F[inside]])
    return P + rng.normal(scale=0.003, size=P.shape)


@pytest.fixture(scope="module")
def curved() -> np.ndarray:
    return _scene(np.random.default_rng(23))


def test_chord_and_tangent_of_a_curved_crease_are_cut_straight_crease_stays(curved):
    """On the floor's crease with the faceted arc: a chord across two facets (each turned 4 deg
    from it, the chord within 2 cm of them) is cut down, a facet's own crease extended along its
    neighbours (turned 8 deg) is cut back to the facet; the straight crease y = 0 stays whole.
    Without the cut (``along.min_run=0``) all three stay whole."""
    params = Lines3DParams()
    reg = segment_planes(curved, params)
    V = np.c_[_arc(FACETS), np.zeros(FACETS + 1)]
    f = V[5] - V[4]
    chord = np.stack([V[2], V[4]])
    tangent = np.stack([V[4] - 0.8 * f, V[5] + 0.8 * f])
    straight = np.array([[0.1, 0.0, 0.0], [0.9, 0.0, 0.0]])
    lines = np.stack([straight, chord, tangent])
    assert len(cut_to_edges(lines, reg, replace(params, along=AlongParams(min_run=0)))) == 3
    # A chord across three facets, 5 cm off the arc in its middle: the local plane fits cut it
    # (the floor's plane piece and the wall's, fitted across the facets, both hold it).
    chord3 = np.stack([V[2], V[5]])
    left = cut_to_edges(chord3[None], reg, params)
    assert np.linalg.norm(left[:, 1] - left[:, 0], axis=1).sum() < 0.75 * np.linalg.norm(chord3[1] - chord3[0])
    got = cut_to_edges(lines, reg, params)
    length = np.linalg.norm(got[:, 1] - got[:, 0], axis=1)
    assert np.isclose(length, 0.8, atol=0.01).sum() == 1  # the straight crease, whole
    near_chord = np.linalg.norm(got.mean(axis=1) - chord.mean(axis=0), axis=1) < 0.2
    assert length[near_chord].sum() < 0.7 * np.linalg.norm(chord[1] - chord[0])  # the chord cut down
    # What is left of the tangent lies along its own facet (0.29 m), not along the neighbours.
    rest = got[~near_chord & ~np.isclose(length, 0.8, atol=0.01)]
    assert len(rest) >= 1
    t = np.einsum("nkj,j->nk", rest - V[4], f / np.linalg.norm(f))
    assert t.min() > -0.15 and t.max() < np.linalg.norm(f) + 0.15
    assert length[~near_chord].sum() < 0.8 + 0.29 + 0.3


def test_extractor_keeps_the_straight_creases_whole(curved):
    lines = extract_lines(curved)
    length = np.linalg.norm(lines[:, 1] - lines[:, 0], axis=1)
    floor = np.abs(lines[:, :, 2]).max(axis=1) < 0.03
    y0 = floor & (np.abs(lines[:, :, 1]).max(axis=1) < 0.03) & (length >= 0.8)
    x3 = floor & (np.abs(lines[:, :, 0] - 3.0).max(axis=1) < 0.03) & (length >= 1.6)
    assert y0.any() and x3.any()
