"""Stage 4 of :class:`ldlloc.pipeline.Localizer`: refining the best candidate poses, by local features
and PnP (``features``, ``pnp``; ``retrieval``: the map's views most like the query, when the
candidates' views give no pose) or by lines alone (``geometric``).
"""
