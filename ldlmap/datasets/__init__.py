"""Readers for panoramic localization datasets in their distributed layouts (docs/datasets.md):
OmniScenes (:mod:`.omniscenes`; the synthetic generator writes this layout, so one reader
serves real and synthetic data), Stanford 2D-3D-S (:mod:`.stanford`) and ZInD (:mod:`.zind`).
:func:`open_dataset` picks the reader of a root; every query pose is validated on read
(:mod:`.poses`). The names below are the public API.
"""

from ldlmap.datasets.base import (DATASET_KINDS, DEFAULT_ROOTS, IMAGE_EXTENSIONS, MAP_LEVELS, OMNISCENES_SPLITS,
                                  STANFORD_AREAS, Dataset, Query, check_map_level)
from ldlmap.datasets.catalog import detect_kind, load_manifest, manifest_path, open_dataset
from ldlmap.datasets.omniscenes import OmniScenes
from ldlmap.datasets.poses import read_pose_file, read_pose_txt, read_stanford_pose, stanford_rotation, write_pose_txt
from ldlmap.datasets.stanford import Stanford2D3DS
from ldlmap.datasets.zind import ZInD

__all__ = ["DATASET_KINDS", "DEFAULT_ROOTS", "IMAGE_EXTENSIONS", "MAP_LEVELS", "OMNISCENES_SPLITS", "STANFORD_AREAS",
           "Dataset", "OmniScenes", "Query", "Stanford2D3DS", "ZInD", "detect_kind", "load_manifest", "manifest_path",
           "open_dataset", "read_pose_file", "read_pose_txt", "read_stanford_pose", "stanford_rotation",
           "write_pose_txt", "check_map_level"]
