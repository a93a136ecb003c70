"""2D line extraction on panoramas (ldlloc.lines2d)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import (bearing_from_pixel, cam_from_world, normalize, pixel_centers,
                                  rotation_from_axis_angle)
from ldlloc.search import ldf
from ldlloc import lines2d

LO, HI = np.array([-3.0, -2.0, 0.0]), np.array([3.0, 2.0, 3.0])


def render_box_room(R, t, width, height, ss=3, seed=0):
    """Analytic panorama of a box room: one grey level per face plus a poster on the x = 3 wall."""
    uv = pixel_centers(width * ss, height * ss) / ss
    d = bearing_from_pixel(uv, width, height) @ R  # world directions R^T p
    with np.errstate(divide="ignore", invalid="ignore"):
        tt = (np.where(d > 0, HI, LO) - t) / d
    tt = np.where(np.isfinite(tt) & (tt > 0), tt, np.inf)
    axis = np.argmin(tt, axis=-1)
    face = 2 * axis + (np.take_along_axis(d, axis[..., None], -1)[..., 0] > 0)
    img = np.array([60, 200, 110, 240, 30, 160], dtype=np.float64)[face]
    hit = t + np.take_along_axis(tt, axis[..., None], -1) * d
    poster = (face == 1) & (np.abs(hit[..., 1]) < 0.6) & (hit[..., 2] > 1.0) & (hit[..., 2] < 2.0)
    img = np.where(poster, 90.0, img).reshape(height, ss, width, ss).mean(axis=(1, 3))
    img = img + np.random.default_rng(seed).normal(scale=2.0, size=img.shape)
    return np.repeat(np.clip(img, 0, 255).astype(np.uint8)[..., None], 3, axis=2)


def box_room_edges():
    c = np.array([[x, y, z] for x in (LO[0], HI[0]) for y in (LO[1], HI[1]) for z in (LO[2], HI[2])])
    edges = [[c[i], c[j]] for i in range(8) for j in range(i + 1, 8) if np.sum(c[i] != c[j]) == 1]
    p = [[HI[0], -0.6, 1.0], [HI[0], 0.6, 1.0], [HI[0], 0.6, 2.0], [HI[0], -0.6, 2.0]]
    edges += [[p[k], p[(k + 1) % 4]] for k in range(4)]
    return np.array(edges, dtype=np.float64)


def _arc_samples(arcs, k=20):
    ts = np.linspace(0.0, 1.0, k)[None, :, None]
    return normalize(arcs[:, None, 0] * (1 - ts) + arcs[:, None, 1] * ts).reshape(-1, 3)


def _arc(s, axis, deg):
    a = np.radians(deg)
    s, axis = normalize(np.asarray(s, float)), normalize(np.asarray(axis, float))
    return np.stack([s, np.cos(a) * s + np.sin(a) * np.cross(axis, s)])


def test_views_cover_the_sphere():
    dirs = lines2d.view_directions("cube26")
    assert dirs.shape == (26, 3)
    pts = normalize(np.random.default_rng(0).normal(size=(20000, 3)))
    B = lines2d._view_bases(dirs)  # (V, 3, 3) forward, right, down
    f = pts @ B[:, 0].T
    with np.errstate(divide="ignore", invalid="ignore"):
        x, y = (pts @ B[:, 1].T) / f, (pts @ B[:, 2].T) / f
    inner = np.where(f > 0, np.maximum(np.abs(x), np.abs(y)), np.inf).min(1)
    # Every direction lies inside some crop, away from its border (half-width tan 30 = 0.577).
    assert inner.max() < 0.85 * np.tan(np.radians(30.0))
    assert lines2d.view_directions("cube14").shape == (14, 3)


@pytest.mark.parametrize("size,seed", [((1024, 512), 0), ((512, 256), 1)])
def test_detect_lines_on_rendered_box_room(size, seed):
    rng = np.random.default_rng(seed)
    R = rotation_from_axis_angle(rng.normal(size=3), rng.uniform(0.2, 1.5))
    t = rng.uniform([-1.5, -1.0, 0.8], [1.5, 1.0, 2.2])
    img = render_box_room(R, t, *size)
    arcs = lines2d.detect_lines(img)
    assert arcs.ndim == 3 and arcs.shape[1:] == (2, 3) and len(arcs) >= 12
    assert np.allclose(np.linalg.norm(arcs, axis=-1), 1.0)
    true = normalize(cam_from_world(box_room_edges(), R, t))
    # Detected arcs lie on the true projected edges.
    d = ldf.distance_function(torch.tensor(_arc_samples(arcs)), torch.tensor(true)).numpy()
    tol = 0.01 if size[0] >= 1024 else 0.02
    assert np.median(d) < tol / 3
    assert np.percentile(d, 90) < tol
    # And cover them: points along the true edges are near a detected arc.
    cov = ldf.distance_function(torch.tensor(_arc_samples(true, 100)), torch.tensor(arcs)).numpy()
    assert np.mean(cov < tol) > 0.9
    # Merging leaves about one arc per edge (16 edges), not one per crop.
    assert len(arcs) <= 30


def test_merge_arcs_joins_overlapping_pieces_only():
    rng = np.random.default_rng(2)
    full = _arc([1, 0.2, 0.1], [0.1, -0.3, 1], 120.0)
    n = normalize(np.cross(full[0], full[1]))
    u, w = full[0], np.cross(n, full[0])
    pieces = []
    for lo, hi in [(0, 40), (35, 80), (79.8, 120)]:  # overlapping / touching pieces
        a, b = np.radians([lo, hi])
        p = np.stack([np.cos(a) * u + np.sin(a) * w, np.cos(b) * u + np.sin(b) * w])
        pieces.append(normalize(p + rng.normal(scale=1e-4, size=p.shape)))
    pieces[1] = pieces[1][::-1].copy()  # opposite orientation
    far = _arc(np.cos(np.radians(150)) * u + np.sin(np.radians(150)) * w, n, 20.0)  # same circle, gap
    shifted = normalize(full + 0.05 * n)  # a parallel circle ~3 degrees away
    merged = lines2d.merge_arcs(np.stack(pieces + [far, shifted]))
    assert len(merged) == 3
    lens = np.sort(np.degrees(lines2d.arc_lengths(merged)))
    np.testing.assert_allclose(lens[-1], 120.0, atol=0.1)
    np.testing.assert_allclose(lens[0], 20.0, atol=0.1)


def test_filter_by_length():
    arcs = np.stack([_arc([1, 0, 0], [0, 0, 1], d) for d in [5, 50, 10, 30, 20]])
    kept = lines2d.filter_by_length(arcs, 0.4)
    np.testing.assert_allclose(np.degrees(lines2d.arc_lengths(kept)), [50, 30])
    assert len(lines2d.filter_by_length(arcs, 1.0)) == 5
    assert len(lines2d.filter_by_length(arcs, 0.01)) == 1
    with pytest.raises(InputError):
        lines2d.filter_by_length(arcs, 0.0)


def test_bad_and_empty_images():
    with pytest.raises(InputError, match="uint8"):
        lines2d.detect_lines(np.zeros((256, 512, 3), np.float32))
    with pytest.raises(InputError, match="W = 2 H"):
        lines2d.detect_lines(np.zeros((256, 300, 3), np.uint8))
    assert lines2d.detect_lines(np.full((128, 256, 3), 128, np.uint8)).shape == (0, 2, 3)


# ------------------------------------------------------------------------------ pole masks, ratio


def _nadir_deg(arcs, zenith=False):
    c = np.array([0.0, 0.0, 1.0 if zenith else -1.0])
    return np.degrees(np.arccos(np.clip(lines2d.arc_max_dot(arcs, c), -1.0, 1.0)))


NO_MASK = lines2d.Lines2DParams(nadir_mask_deg=0.0, detect_pole_bands=False)
UPRIGHT = (np.eye(3), np.array([0.4, 0.3, 1.3]))  # nearest wall's foot 53 deg from the nadir


def test_black_band_at_the_bottom_gives_no_lines_and_keeps_the_others():
    img = render_box_room(*UPRIGHT, 512, 256)
    band = img.copy()
    band[-int(256 * 30 / 180):] = 0  # a black band over the 30 degrees around the nadir
    raw = lines2d.detect_lines(band, NO_MASK)
    assert np.sum(_nadir_deg(raw) < 31) >= 1  # the band's boundary is a line when unmasked
    ext, top = lines2d.pole_band_extents(lines2d._gray(band, lines2d.Lines2DParams()))
    assert 29 <= ext <= 31 and top == 0
    arcs = lines2d.detect_lines(band)
    assert np.all(_nadir_deg(arcs) >= ext + lines2d.Lines2DParams().band_margin_deg - 1e-6)
    # The lines above the band survive: those of the plain image beyond 40 deg are found again.
    plain = lines2d.detect_lines(img, NO_MASK)
    plain = plain[_nadir_deg(plain) > 40]
    d = ldf.distance_function(torch.tensor(_arc_samples(plain)), torch.tensor(arcs)).numpy()
    assert len(plain) >= 10 and np.mean(d < 0.01) > 0.9
    # The same band at the top (the image upside down) masks the zenith.
    flipped = lines2d.detect_lines(np.ascontiguousarray(band[::-1]))
    assert np.all(_nadir_deg(flipped, zenith=True) >= ext) and len(flipped) >= 10


def test_bright_textured_blob_at_the_nadir_gives_no_lines():
    img = render_box_room(*UPRIGHT, 512, 256)
    uv = pixel_centers(512, 256)
    polar = np.degrees(np.arccos(-bearing_from_pixel(uv, 512, 256)[..., 2]))  # from the nadir
    stripes = np.where((uv[..., 0] // 6) % 2 == 0, 250, 140).astype(np.uint8)  # a tripod's legs
    blob = img.copy()
    blob[polar < 12] = stripes[polar < 12, None]
    raw = lines2d.detect_lines(blob, NO_MASK)
    assert np.sum(_nadir_deg(raw) < 12) >= 5
    params = lines2d.Lines2DParams()
    arcs = lines2d.detect_lines(blob, params)
    assert np.all(_nadir_deg(arcs) >= params.nadir_mask_deg)
    plain = lines2d.detect_lines(img, NO_MASK)
    plain = plain[_nadir_deg(plain) > params.nadir_mask_deg + 2]
    d = ldf.distance_function(torch.tensor(_arc_samples(plain)), torch.tensor(arcs)).numpy()
    assert len(plain) >= 10 and np.mean(d < 0.01) > 0.9


def test_untextured_floor_is_not_a_band():
    import cv2

    img = cv2.GaussianBlur(render_box_room(*UPRIGHT, 512, 256), (0, 0), 2.0)  # flat floor, ceiling
    assert lines2d.pole_band_extents(lines2d._gray(img, lines2d.Lines2DParams())) == (0.0, 0.0)
    assert lines2d.pole_caps(lines2d._gray(img, lines2d.Lines2DParams())) == (18.0, 0.0)


def test_arc_max_dot_against_dense_samples():
    rng = np.random.default_rng(3)
    s = normalize(rng.normal(size=(200, 3)))
    e = normalize(s + rng.uniform(0.05, 1.5, (200, 1)) * normalize(rng.normal(size=(200, 3))))
    arcs = np.stack([s, e], axis=1)
    c = normalize(np.array([0.2, -0.1, -1.0]))
    dense = (_arc_samples(arcs, 2001).reshape(200, 2001, 3) @ c).max(1)
    np.testing.assert_allclose(lines2d.arc_max_dot(arcs, c), dense, atol=1e-6)


def test_query_keep_ratio_clips_both_ways():
    p = lines2d.Lines2DParams(keep_ratio_bounds=(0.05, 0.5))
    assert lines2d.query_keep_ratio(0.008, p) == 0.05  # a Line3D++ map
    assert lines2d.query_keep_ratio(0.9, p) == 0.5  # a room-layout map
    assert lines2d.query_keep_ratio(0.2, p) == 0.2
    assert lines2d.query_keep_ratio(0.15) == 0.15 and lines2d.query_keep_ratio(0.9) == 0.2  # default bounds
    for bad in (0.0, -0.1, 1.5, float("nan")):
        with pytest.raises(InputError):
            lines2d.query_keep_ratio(bad, p)
    with pytest.raises(InputError):
        lines2d.query_keep_ratio(0.3, lines2d.Lines2DParams(keep_ratio_bounds=(0.6, 0.5)))


def _real_panoramas():
    import os
    from pathlib import Path

    root = Path(os.environ.get("LDL_REAL_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))
    return sorted(root.glob("zind/*/panos/*.jpg")), root


def test_real_panoramas_have_no_arc_in_the_nadir_cap():
    import cv2

    files, root = _real_panoramas()
    if not files:
        pytest.skip(f"no real panoramas under {root} (set LDL_REAL_DATA)")
    params = lines2d.Lines2DParams()
    for f in files:  # at 1024 x 512 to stay fast
        img = cv2.resize(cv2.imread(str(f)), (1024, 512), interpolation=cv2.INTER_AREA)[..., ::-1]
        arcs = lines2d.detect_lines(np.ascontiguousarray(img), params)
        assert len(arcs) >= 100, f.name
        assert _nadir_deg(arcs).min() >= params.nadir_mask_deg, f.name
