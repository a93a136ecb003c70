"""Maps from structure-from-motion: 3D lines reconstructed from a COLMAP model's photos
(``photo_lines``) and the up axis from cameras or lines (``gravity``).
"""
