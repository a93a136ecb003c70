"""Many queries at once: dataset runs (``run``), their results file (``results``), accuracy summaries
and tables (``accuracy``), and Ray distribution (``ray_run``).
"""
