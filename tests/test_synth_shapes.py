"""Rooms that are not boxes: ceilings (shed, gable, stepped, vault), angled and curved walls, the
shape presets, and their true edges."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ldlmap.core import polygon as pg
from ldlmap.core.errors import InputError
from ldlmap.synth.edges import mesh_edges
from ldlmap.synth.presets import random_spec
from ldlmap.synth.render import Renderer
from ldlmap.synth.scene import build_scene
from ldlmap.synth.shapes import SHAPE_KINDS, classify_room
from ldlmap.synth.spec import CeilingSpec, SceneSpec, dump_spec_toml, spec_from_dict, validate_spec

import tomllib

RECT = ((0.0, 0.0), (5.0, 0.0), (5.0, 4.0), (0.0, 4.0))


def _room(ceiling: CeilingSpec, footprint=RECT, height: float = 2.4) -> SceneSpec:
    return SceneSpec("t", footprint, height, ceiling=ceiling)


def _has_edge(edges: np.ndarray, p: np.ndarray, q: np.ndarray, tol: float = 1e-6) -> bool:
    """An edge from p to q (either way) among (E, 2, 3), possibly split into collinear pieces that
    cover it."""
    d = q - p
    length = np.linalg.norm(d)
    u = d / length
    covered = []
    for a, b in edges:
        for x in (a, b):
            if np.linalg.norm(np.cross(x - p, u)) > tol:
                break
        else:
            ta, tb = sorted(((a - p) @ u, (b - p) @ u))
            covered.append((ta, tb))
    covered.sort()
    reach = 0.0
    for ta, tb in covered:
        if ta > reach + tol:
            return False
        reach = max(reach, tb)
    return reach >= length - tol


def _closed(mesh, points: np.ndarray, n: int = 400) -> bool:
    """Rays from each point in ``n`` directions all hit the room (no gap in the shell)."""
    rng = np.random.default_rng(0)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    r = Renderer(mesh)
    for p in points:
        hit = r.cast(np.repeat(p[None], n, axis=0), dirs)
        if not np.all(hit["tri"] >= 0):
            return False
    return True


def test_gable_ridge_and_eaves_are_true_edges():
    slope = 30.0
    mesh = build_scene(_room(CeilingSpec("gable", direction_deg=90.0, slope_deg=slope)))
    ridge = 2.4 + math.tan(math.radians(slope)) * 2.0  # run of one slope: half of 4 m
    edges = mesh_edges(mesh)
    assert mesh.vertices[:, 2].max() == pytest.approx(ridge)
    assert _has_edge(edges, np.array([0, 2.0, ridge]), np.array([5, 2.0, ridge]))  # the ridge
    assert _has_edge(edges, np.array([0, 0, 2.4]), np.array([5, 0, 2.4]))  # eaves
    assert _has_edge(edges, np.array([0, 0, 2.4]), np.array([0, 2.0, ridge]))  # a gable end's rake
    assert mesh.ceiling_height == pytest.approx(2.4)


def test_shed_rises_along_its_axis_and_the_room_is_closed():
    spec = _room(CeilingSpec("shed", direction_deg=0.0, slope_deg=20.0))
    mesh = build_scene(spec)
    top = 2.4 + math.tan(math.radians(20.0)) * 5.0
    edges = mesh_edges(mesh)
    assert _has_edge(edges, np.array([5, 0, top]), np.array([5, 4, top]))
    assert _has_edge(edges, np.array([0, 0, 2.4]), np.array([5, 0, top]))  # the slope meets a side wall
    assert _closed(mesh, np.array([[0.5, 0.5, 2.2], [4.5, 3.5, 3.9], [2.5, 2.0, 1.2]]))


def test_stepped_ceiling_has_the_step_face_edges():
    mesh = build_scene(_room(CeilingSpec("stepped", direction_deg=0.0, step=0.5, step_at=0.4)))
    edges = mesh_edges(mesh)
    # The step stands at x = 2 (0.4 of 5 m): its lower and upper edges run across the room.
    assert _has_edge(edges, np.array([2, 0, 2.4]), np.array([2, 4, 2.4]))
    assert _has_edge(edges, np.array([2, 0, 2.9]), np.array([2, 4, 2.9]))
    assert _has_edge(edges, np.array([0, 0, 2.9]), np.array([0, 4, 2.9]))  # the high part meets its wall
    assert _closed(mesh, np.array([[1.0, 2.0, 2.8], [4.0, 2.0, 2.3]]))


def test_vault_crown_and_springing():
    mesh = build_scene(_room(CeilingSpec("vault", direction_deg=0.0, rise=0.8, segments=8)))
    assert mesh.vertices[:, 2].max() == pytest.approx(3.2)
    edges = mesh_edges(mesh)
    # Facets turn by under 20 degrees: no crease runs along the vault between them.
    along = [e for e in edges if abs(e[0, 0] - e[1, 0]) < 1e-9 and e[0, 2] > 2.45 and e[1, 2] > 2.45]
    assert not along
    # The arch meets the end walls along its facets: true edges there.
    assert _has_edge(edges, np.array([0, 0, 2.4]), np.array([0, 4, 2.4]))
    assert sum(1 for e in edges if abs(e[0, 1]) < 1e-9 and abs(e[1, 1]) < 1e-9 and min(e[:, 2]) > 2.39) == 8


def test_curved_wall_gives_no_vertical_edges_along_the_arc():
    spec = random_spec("curved", 0, 2)  # a bay or rounded corner, with straight walls too
    mesh = build_scene(spec)
    fp = np.asarray(spec.footprint)
    turns = pg.corner_turns_deg(fp)
    edges = mesh_edges(mesh)
    vertical = [e for e in edges if np.linalg.norm(np.cross(e[1] - e[0], [0, 0, 1])) < 1e-6 * np.linalg.norm(e[1] - e[0])
                and min(e[:, 2]) < 1e-6]
    corners = {tuple(np.round(fp[i], 3)) for i in np.flatnonzero(turns >= 20.0)}
    wall_corners = [tuple(np.round(e[np.argmin(e[:, 2]), :2], 3)) for e in vertical]
    on_arc = [c for c in wall_corners if c not in corners and any(np.allclose(c, v, atol=1e-3) for v in fp)]
    assert not on_arc


@pytest.mark.parametrize("kind", SHAPE_KINDS)
def test_presets_make_valid_rooms_of_their_kind(kind):
    for i in (1, 2, 3):
        spec = random_spec(kind, 5, i)
        validate_spec(spec)
        assert classify_room(spec) == kind
        assert spec.objects, "furnished"
        if kind == "angled":
            turns = pg.corner_turns_deg(spec.footprint)
            assert 5 <= len(spec.footprint) <= 8 and np.any(np.abs(turns - 90) > 1)
    assert [classify_room(random_spec("shapes", 1, i)) for i in range(1, 6)] == list(SHAPE_KINDS)


def test_shape_room_is_closed_and_cameras_fit_under_the_ceiling():
    spec = random_spec("sloped", 0, 1)
    mesh = build_scene(spec)
    c = np.r_[np.asarray(spec.footprint).mean(axis=0), 1.5]
    assert _closed(mesh, c[None])


def test_ceiling_round_trips_through_toml():
    spec = _room(CeilingSpec("vault", direction_deg=30.0, rise=0.9, segments=10))
    again = spec_from_dict(tomllib.loads(dump_spec_toml(spec)))
    assert again.ceiling == spec.ceiling


@pytest.mark.parametrize("ceiling, footprint, message", [
    ({"kind": "dome"}, RECT, "ceiling.kind"),
    ({"kind": "shed", "slope_deg": 70}, RECT, "ceiling.slope_deg"),
    ({"kind": "stepped", "step_at": 1.2}, RECT, "ceiling.step_at"),
    ({"kind": "vault", "segments": 1}, RECT, "ceiling.segments"),
    ({"kind": "gable"}, ((0, 0), (4, 0), (4, 2), (2, 2), (2, 4), (0, 4)), "convex footprint"),
    ({"kind": "shed", "slope_deg": 59}, ((0, 0), (30, 0), (30, 4), (0, 4)), "highest point"),
])
def test_bad_ceilings_are_refused_naming_the_field(ceiling, footprint, message):
    d = {"name": "t", "footprint": [list(p) for p in footprint], "ceiling_height": 2.4, "ceiling": ceiling}
    with pytest.raises(InputError, match=message):
        validate_spec(spec_from_dict(d))
