"""Shared by ``ldlmap`` and ``ldlloc``: pose and sphere conventions (``geometry``), the map and input
frames (``frame``), one-line errors and atomic outputs (``errors``), the spherical point-to-arc
distance (``sphere_distance``), 2D polygons, image and picture helpers, and the plumbing of both
command-line programs (``cli_common``).
"""
