"""Whole datasets: one map per scene (``prepare``), on this machine or as Ray tasks (``ray_prepare``;
Ray plumbing shared with ``ldlloc run --ray`` in ``ray_cluster``).
"""
