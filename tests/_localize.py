"""Shared assertion of the feature-refinement tests: demo queries localized by a map's features."""

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
