"""Stage 3 of :class:`ldlloc.pipeline.Localizer`: line distance functions (``ldf``, paper eqs. 2-5),
look-ups in the map's precomputed fields (``fields``) and the pose search over candidate poses
(``pose_search``).
"""
