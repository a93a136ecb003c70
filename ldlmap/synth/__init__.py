"""Synthetic indoor scenes with ground-truth poses (docs/synthetic.md).

Pipeline: a TOML spec (:mod:`.spec`) -> textured triangle mesh (:mod:`.scene`) -> panoramas
ray-cast with open3d (:mod:`.render`) at sampled poses (:mod:`.poses`), a scanner-like colored
point cloud (:mod:`.scan`), ground-truth edges (:mod:`.edges`), all written in the OmniScenes
layout by :mod:`.generate`.
"""
