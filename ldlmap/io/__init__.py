"""Readers and writers of external file formats (point clouds, meshes, COLMAP models, 3D line files)."""
