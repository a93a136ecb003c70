"""LDL maps: the offline side of the toolkit (``ldlmap``).

Public API (imported on first use, so ``import ldlmap`` stays instant)::

    from ldlmap import BuildParams, build_map, read_map
    report = build_map("scan.ply", "scan.h5", params=BuildParams().replaced(num_translations=400))
    ldl_map = read_map(report.path)          # an LdlMap: lines, principal directions, translations

Also: ``build_lines_map`` (a lines-only map from segments in memory), ``write_map``, ``LdlMap``,
``open_dataset`` / ``Query`` (dataset readers), ``prepare_dataset`` (one map per scene of a
dataset root), ``extract_lines`` (3D lines of a point cloud), ``read_point_cloud``, ``read_lines``
and ``generate_dataset`` (synthetic scenes). Folders: ``core`` (conventions and plumbing shared
with ``ldlloc``), ``io`` (file formats), ``lines3d`` (3D line extraction), ``sfm`` (COLMAP photos:
lines and gravity), ``features`` (local features), ``map`` (the map file and its build stages),
``datasets`` (dataset readers), ``batch`` (whole datasets, Ray), ``synth`` (synthetic scenes).
"""

from ldlmap.core.lazy_api import lazy_api

_API = {
    "BuildParams": "ldlmap.map.params", "BuildReport": "ldlmap.map.build", "build_map": "ldlmap.map.build",
    "build_lines_map": "ldlmap.map.build", "LdlMap": "ldlmap.map.contents", "read_map": "ldlmap.map.mapfile",
    "read_map_header": "ldlmap.map.mapfile", "write_map": "ldlmap.map.mapfile", "open_dataset": "ldlmap.datasets",
    "Query": "ldlmap.datasets", "prepare_dataset": "ldlmap.batch.prepare", "extract_lines": "ldlmap.lines3d",
    "Lines3DParams": "ldlmap.lines3d", "read_point_cloud": "ldlmap.io.pointcloud", "read_lines": "ldlmap.io.linefiles",
    "generate_dataset": "ldlmap.synth.generate", "LdlError": "ldlmap.core.errors",
}
__all__, __getattr__, __dir__ = lazy_api("ldlmap", _API)
