"""The LDL map: its file (``mapfile``: schema, read, write; ``contents``: the map in memory;
``validate``) and the stages that build it (``build``: the pipeline; ``inputs``: what a map is built
from; ``translations``: candidate camera centres; ``visibility``; ``fields3d``: precomputed distance
fields; ``render`` and ``keypoints3d``: views and their features lifted to 3D; ``pictures``).
"""
