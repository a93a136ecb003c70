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

import numpy as np

from ldlmap.features.base import Features, check_image, top_k
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


PANORAMA_EXTRACTIONS = ("equirect", "cube")
# Each backend's default, measured (bench_features.py, seed 23, 32 queries, full pipeline; README): with
# the hard appearance gap, ALIKED on cube faces reached 0.78 at 0.05 m / 5 deg against 0.69 on the whole
# panorama, refining 16 % faster; XFeat (0.81 against 0.97) and SIFT (0.88 against 0.94) lost there.
_DEFAULT_EXTRACTION = {"aliked": "cube"}


def default_extraction(backend: str) -> str:
    """The panorama feature extraction a backend uses unless told otherwise."""
    return _DEFAULT_EXTRACTION.get(str(backend).strip().lower(), "equirect")

# The cube's faces: (forward, image down) camera-frame axes; image right = down x forward, so the
# four side faces run left to right as the panorama's u does (z is up).
_FACES = np.array([[[1, 0, 0], [0, 0, -1]], [[0, -1, 0], [0, 0, -1]], [[-1, 0, 0], [0, 0, -1]],
                   [[0, 1, 0], [0, 0, -1]], [[0, 0, 1], [1, 0, 0]], [[0, 0, -1], [-1, 0, 0]]], dtype=np.float64)


def _face_axes(face: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    fwd, down = _FACES[face]
    return fwd, np.cross(down, fwd), down


class CubeFaces:
    """A feature backend run on the six faces of a cube around the panorama (90-degree perspective
    views, each rendered ``pad`` wider so that detectors see past its edges), keypoints lifted back
    to the panorama's pixels. Each keypoint is kept by the one face whose own 90 degrees hold it,
    so no bearing is described twice, and the best ``max_keypoints`` over all faces are kept (None:
    the wrapped backend's budget for one image). Matching is the wrapped backend's."""

    def __init__(self, inner, face_size: int | None = None, pad: float = 0.1):
        self.inner = inner
        self.name = inner.name
        self.descriptor_dtype = inner.descriptor_dtype
        self.query_keypoints = inner.query_keypoints
        self.face_size = face_size
        self.pad = float(pad)

    def __getattr__(self, item):  # the wrapped backend's config, device, ...
        return getattr(self.inner, item)

    def match_views(self, *args, **kwargs):
        return self.inner.match_views(*args, **kwargs)

    def _grid(self, face: int, n: int) -> np.ndarray:
        """Camera-frame directions (n, n, 3) of the padded face's pixel centres."""
        fwd, right, down = _face_axes(face)
        a = ((np.arange(n) + 0.5) / n * 2.0 - 1.0) * (1.0 + self.pad)
        return fwd + a[None, :, None] * right + a[:, None, None] * down

    def extract(self, image_rgb: np.ndarray, mask: np.ndarray | None = None,
                max_keypoints: int | None = None) -> Features:
        """Features of the panorama ``image_rgb`` (H, 2H, 3) from its cube faces (``mask``: (H, W))."""
        import cv2

        img, mask = check_image(image_rgb, mask)
        if max_keypoints is None:  # the backend's budget for one image holds for the whole panorama
            max_keypoints = getattr(getattr(self.inner, "config", None), "max_keypoints", None)
        H, W = img.shape[:2]
        side = int(self.face_size or max(W // 4, 8))
        n = int(round(side * (1.0 + self.pad)))
        parts, empty = [], None
        for face in range(6):
            uv = pixel_from_bearing(self._grid(face, n), W, H)
            mx = (uv[..., 0] - 0.5).astype(np.float32)
            my = (np.clip(uv[..., 1], 0.5, H - 0.5) - 0.5).astype(np.float32)
            crop = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
            fmask = None if mask is None else cv2.remap(mask.astype(np.uint8), mx, my, cv2.INTER_NEAREST,
                                                        borderMode=cv2.BORDER_WRAP).astype(bool)
            f = self.inner.extract(crop, mask=fmask, max_keypoints=max_keypoints)
            if len(f) == 0:
                empty = f  # keeps the descriptor width
                continue
            a = f.keypoints.astype(np.float64) / n * 2.0 - 1.0  # padded-face coordinates, then the face's own
            a *= 1.0 + self.pad
            own = (np.abs(a) <= 1.0).all(1)
            fwd, right, down = _face_axes(face)
            d = fwd + a[own, :1] * right + a[own, 1:] * down
            kp = pixel_from_bearing(d, W, H)
            kp[:, 0] = np.mod(kp[:, 0], W)
            parts.append(Features(kp.astype(np.float32), f.scores[own], f.descriptors[own]))
        if not parts:
            return empty
        feats = Features(*(np.concatenate([getattr(p, k) for p in parts]) for k in ("keypoints", "scores", "descriptors")))
        return feats.subset(top_k(feats.scores, max_keypoints))


def check_extraction(extraction: str) -> str:
    """``extraction`` when it names a panorama feature extraction, else a one-line InputError."""
    if extraction not in PANORAMA_EXTRACTIONS:
        from ldlmap.errors import InputError

        raise InputError(f"unknown feature extraction {extraction!r}; valid: {', '.join(PANORAMA_EXTRACTIONS)}")
    return extraction


def for_panoramas(backend, extraction: str = "equirect"):
    """``backend`` as it runs on panoramas: on the equirectangular image, or on its cube faces."""
    return CubeFaces(backend) if check_extraction(extraction) == "cube" else backend
