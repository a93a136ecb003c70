"""Stage 4 of :class:`ldlloc.pipeline.Localizer`: refining the best candidate poses, by local features
and PnP (``features``, ``pnp``) or by lines alone (``geometric``).
"""
