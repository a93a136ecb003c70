"""LDL localization: the online side of the toolkit (``ldlloc``).

Public API (imported on first use, so ``import ldlloc`` stays instant)::

    from ldlmap import read_map
    from ldlloc import LocalizeParams, Localizer, load_image
    loc = Localizer(read_map("room.h5"), LocalizeParams(), device="cpu")
    res = loc.localize(load_image("pano.jpg"))   # res.rot_cam_from_world, res.center

Also ``run_queries`` (a batch of dataset queries with a results file), ``load_results``,
``export_results`` (poses for COLMAP, nerfstudio, a viewer) and ``write_html_report``.
Stages of :class:`Localizer`, one module or folder each: ``lines2d`` (2D line segments),
``rotation`` (principal directions and candidate rotations), ``search`` (line distance functions
and the pose search), ``refine`` (by features or by lines alone); ``batch`` runs many queries,
writes results and spreads them over Ray.
"""

from ldlmap.core.lazy_api import lazy_api

_API = {
    "Localizer": "ldlloc.pipeline", "LocalizeParams": "ldlloc.pipeline", "Localization": "ldlloc.pipeline",
    "load_image": "ldlloc.pipeline", "run_queries": "ldlloc.batch.run", "load_results": "ldlloc.batch.results",
    "QueryResult": "ldlloc.record", "summarize": "ldlloc.batch.accuracy",
    "export_results": "ldlloc.export", "write_html_report": "ldlloc.report",
}
__all__, __getattr__, __dir__ = lazy_api("ldlloc", _API)
