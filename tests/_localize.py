"""Shared assertions of the localization tests: demo queries localized by a map's features, and
panoramas rendered from a mesh at chosen poses localized on its map."""

from __future__ import annotations


def assert_refined_by_features(loc, ds, scene: str) -> None:
    """A robot and two extreme queries of ``scene`` each end within 0.1 m / 5 deg, refined by features."""
    from ldlmap.core.geometry import rotation_error_deg, translation_error
    from ldlloc.pipeline import load_image

    queries = ds.queries("robot", scene=scene)[:1] + ds.queries("extreme", scene=scene)[:2]
    for q in queries:
        r = loc.localize(load_image(q.image))
        t_err = translation_error(r.center, q.center)
        r_err = rotation_error_deg(r.rot_cam_from_world, q.rot_cam_from_world)
        assert r.refine_method == "features" and t_err < 0.1 and r_err < 5.0, (q.name, t_err, r_err, r.message)


def localize_rendered(loc, mesh, poses) -> list:
    """Render ``mesh`` at each ``(center, yaw_deg, tilt_deg)`` of ``poses`` (512 px wide), localize
    it with ``loc`` and assert it ends within 0.1 m / 5 deg; returns the localizations."""
    import numpy as np

    from ldlmap.core.geometry import rotation_error_deg, rotation_from_axis_angle
    from ldlmap.synth.render import Renderer

    render, out = Renderer(mesh), []
    for center, yaw, tilt in poses:
        R = rotation_from_axis_angle(np.array([1.0, 0, 0]), np.radians(tilt)) @ \
            rotation_from_axis_angle(np.array([0, 0, 1.0]), np.radians(yaw))
        r = loc.localize(render.render(R, np.array(center), 512).rgb)
        t_err, r_err = np.linalg.norm(r.center - center), rotation_error_deg(r.rot_cam_from_world, R)
        assert t_err < 0.1 and r_err < 5.0, (center, t_err, r_err, r.message)
        out.append(r)
    return out
