"""Features of a panorama extracted in another frame of the sphere and lifted back to its pixels.

The map's views are rendered with the identity rotation (upright, world-aligned). A query taken
tilted or rolled (the extreme split) shows the same surfaces rotated and differently distorted,
which learned detectors and descriptors are not invariant to. Once the pose search has a
candidate rotation, the query is resampled into the map's frame, features are extracted there
and their keypoints are mapped back to the query's own pixels (bearings), so that matching and
PnP are unchanged.
"""

from __future__ import annotations

import numpy as np

from ldlmap.features.base import Features
from ldlmap.geometry import bearing_from_pixel, pixel_centers, pixel_from_bearing


def rotate_panorama(image: np.ndarray, rot_cam_from_world: np.ndarray) -> np.ndarray:
    """The panorama ``image`` (taken with rotation ``R``) as seen with the identity rotation:
    the output pixel of world bearing ``d`` samples the input at ``R d`` (bilinear, wrapping in u)."""
    import cv2

    H, W = image.shape[:2]
    d_world = bearing_from_pixel(pixel_centers(W, H).reshape(-1, 2), W, H)
    uv = pixel_from_bearing(d_world @ np.asarray(rot_cam_from_world, dtype=np.float64).T, W, H)
    # OpenCV addresses pixel centres with integers; ours are at +0.5.
    mx = (uv[:, 0] - 0.5).reshape(H, W).astype(np.float32)
    my = (np.clip(uv[:, 1], 0.5, H - 0.5) - 0.5).reshape(H, W).astype(np.float32)
    return cv2.remap(np.ascontiguousarray(image), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)


def extract_in_map_frame(backend, image: np.ndarray, rot_cam_from_world: np.ndarray,
                         max_keypoints: int | None = None) -> Features:
    """Features of the panorama rotated into the map's frame by ``rot_cam_from_world``, with
    keypoints in the pixels of the panorama as taken."""
    H, W = image.shape[:2]
    feats = backend.extract(rotate_panorama(image, rot_cam_from_world), max_keypoints=max_keypoints)
    if len(feats) == 0:
        return feats
    d_cam = bearing_from_pixel(feats.keypoints, W, H) @ np.asarray(rot_cam_from_world, dtype=np.float64).T
    uv = pixel_from_bearing(d_cam, W, H).astype(np.float32)
    uv[:, 0] = np.mod(uv[:, 0], W)
    return Features(uv, feats.scores, feats.descriptors)
