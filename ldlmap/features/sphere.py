"""Features of a panorama extracted in another frame of the sphere, or on the faces of a cube
around it, and lifted back to its pixels.

The map's views are rendered with the identity rotation (upright, world-aligned). A query taken
tilted or rolled (the extreme split) shows the same surfaces rotated and differently distorted,
which learned detectors and descriptors are not invariant to. Once the pose search has a
candidate rotation, the query is resampled into the map's frame, features are extracted there
and their keypoints are mapped back to the query's own pixels (bearings), so that matching and
PnP are unchanged.

:class:`CubeFaces` runs a backend on the six 90-degree perspective faces of a cube instead of the
equirectangular image (no polar stretch), for the map's views and the queries alike (the map
records which: ``MapFeatures.extraction``).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.geometry import bearing_from_pixel, pixel_centers, pixel_from_bearing
from ldlmap.core.lazy import lazy_module
from ldlmap.features.base import Features, check_image, top_k

cv2 = lazy_module("cv2")


def _remap_maps(uv: np.ndarray, height: int) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV remap maps (float32) sampling a panorama of ``height`` at its pixel coordinates ``uv``
    (..., 2): OpenCV addresses pixel centres with integers, ours are at +0.5; v stays on the image."""
    return ((uv[..., 0] - 0.5).astype(np.float32),
            (np.clip(uv[..., 1], 0.5, height - 0.5) - 0.5).astype(np.float32))


@lru_cache(maxsize=4)
def _pixel_bearings(width: int, height: int) -> np.ndarray:
    """Bearings (H * W, 3) of a panorama's pixel centres (cached: every rotated query needs them)."""
    return bearing_from_pixel(pixel_centers(width, height).reshape(-1, 2), width, height)


def rotate_panorama(image: np.ndarray, rot_cam_from_world: np.ndarray) -> np.ndarray:
    """The panorama ``image`` (taken with rotation ``R``) as seen with the identity rotation:
    the output pixel of world bearing ``d`` samples the input at ``R d`` (bilinear, wrapping in u)."""
    H, W = image.shape[:2]
    uv = pixel_from_bearing(_pixel_bearings(W, H) @ np.asarray(rot_cam_from_world, dtype=np.float64).T, W, H)
    mx, my = _remap_maps(uv.reshape(H, W, 2), H)
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


PANORAMA_EXTRACTIONS = ("equirect", "cube")
# Each backend's default extraction, the more accurate one for it (cube faces only for ALIKED):
# measured in docs/measurements.md#feature-extraction.
_DEFAULT_EXTRACTION = {"aliked": "cube"}


def default_extraction(backend: str) -> str:
    """The panorama feature extraction a backend uses unless told otherwise."""
    return _DEFAULT_EXTRACTION.get(str(backend).strip().lower(), "equirect")


# The cube's faces: (forward, image down) camera-frame axes; image right = down x forward, so the
# four side faces run left to right as the panorama's u does (z is up).
_FACES = np.array([[[1, 0, 0], [0, 0, -1]], [[0, -1, 0], [0, 0, -1]], [[-1, 0, 0], [0, 0, -1]],
                   [[0, 1, 0], [0, 0, -1]], [[0, 0, 1], [1, 0, 0]], [[0, 0, -1], [-1, 0, 0]]], dtype=np.float64)


def _face_directions(face: int, a: np.ndarray) -> np.ndarray:
    """Camera-frame directions (..., 3) of face coordinates ``a`` (..., 2) (right, down; the face's
    own 90 degrees span [-1, 1]); image right = down x forward."""
    fwd, down = _FACES[face]
    return fwd + a[..., :1] * np.cross(down, fwd) + a[..., 1:] * down


@lru_cache(maxsize=4)
def _face_maps(width: int, height: int, n: int, pad: float) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """Remap maps of the six faces (n x n pixels spanning 1 + ``pad`` of their 90 degrees) of a
    panorama of this size (cached: every map view and query of a size shares them)."""
    c = ((np.arange(n) + 0.5) / n * 2.0 - 1.0) * (1.0 + pad)
    a = np.stack(np.meshgrid(c, c), -1)  # (n, n, 2): u along columns, v along rows
    return tuple(_remap_maps(pixel_from_bearing(_face_directions(f, a), width, height), height) for f in range(6))


class CubeFaces:
    """A feature backend run on the six faces of a cube around the panorama (90-degree perspective
    views of a quarter of its width, each rendered ``pad`` wider so that detectors see past its
    edges), keypoints lifted back to the panorama's pixels. Each keypoint is kept by the one face
    whose own 90 degrees hold it, so no bearing is described twice, and the best ``max_keypoints``
    over all faces are kept (None: the wrapped backend's budget for one image). Matching is the
    wrapped backend's."""

    def __init__(self, inner, pad: float = 0.1):
        self.inner = inner
        self.name = inner.name
        self.descriptor_dtype = inner.descriptor_dtype
        self.query_keypoints = inner.query_keypoints
        self.pad = float(pad)

    def __getattr__(self, item):  # the wrapped backend's config, device, ...
        if item == "inner":  # not set yet (unpickling): no recursion
            raise AttributeError(item)
        return getattr(self.inner, item)

    def match_views(self, *args, **kwargs):
        return self.inner.match_views(*args, **kwargs)

    def extract(self, image_rgb: np.ndarray, mask: np.ndarray | None = None,
                max_keypoints: int | None = None) -> Features:
        """Features of the panorama ``image_rgb`` (H, 2H, 3) from its cube faces (``mask``: (H, W))."""
        img, mask = check_image(image_rgb, mask)
        if max_keypoints is None:  # the backend's budget for one image holds for the whole panorama
            max_keypoints = getattr(getattr(self.inner, "config", None), "max_keypoints", None)
        H, W = img.shape[:2]
        n = int(round(max(W // 4, 8) * (1.0 + self.pad)))
        mask8 = None if mask is None else mask.astype(np.uint8)
        parts, empty = [], None
        for face, (mx, my) in enumerate(_face_maps(W, H, n, self.pad)):
            crop = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
            fmask = None if mask8 is None else cv2.remap(mask8, mx, my, cv2.INTER_NEAREST,
                                                         borderMode=cv2.BORDER_WRAP).astype(bool)
            f = self.inner.extract(crop, mask=fmask, max_keypoints=max_keypoints)
            if len(f) == 0:
                empty = f  # keeps the descriptor width
                continue
            a = (f.keypoints.astype(np.float64) / n * 2.0 - 1.0) * (1.0 + self.pad)  # the face's own coordinates
            own = (np.abs(a) <= 1.0).all(1)
            kp = pixel_from_bearing(_face_directions(face, a[own]), W, H)
            kp[:, 0] = np.mod(kp[:, 0], W)
            parts.append(Features(kp.astype(np.float32), f.scores[own], f.descriptors[own]))
        if not parts:
            return empty
        feats = Features(*(np.concatenate([getattr(p, k) for p in parts]) for k in ("keypoints", "scores", "descriptors")))
        return feats.subset(top_k(feats.scores, max_keypoints))


def check_extraction(extraction: str) -> str:
    """``extraction`` when it names a panorama feature extraction, else a one-line InputError."""
    if extraction not in PANORAMA_EXTRACTIONS:
        raise InputError(f"unknown feature extraction {extraction!r}; valid: {', '.join(PANORAMA_EXTRACTIONS)}")
    return extraction


def for_panoramas(backend, extraction: str = "equirect"):
    """``backend`` as it runs on panoramas: on the equirectangular image, or on its cube faces."""
    return CubeFaces(backend) if check_extraction(extraction) == "cube" else backend
