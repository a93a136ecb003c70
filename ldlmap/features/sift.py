"""SIFT features (OpenCV) with mutual-nearest-neighbour + ratio matching: needs no weights.

Panoramas are described directly on the equirectangular image (simple; the distortion near
the poles only lowers the number of repeatable keypoints there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ldlmap.core.imageproc import stretch_contrast
from ldlmap.core.lazy import lazy_module
from ldlmap.features.base import DescriptorMatching, Features, backend_config, check_image, mutual_nn_match, top_k

cv2 = lazy_module("cv2")


@dataclass(frozen=True)
class SiftConfig:
    """Options of the SIFT backend."""

    max_keypoints: int = 4096  # keep the strongest responses (0: all)
    contrast_threshold: float = 0.04  # OpenCV contrastThreshold (its default; divided by the layers)
    edge_threshold: float = 10.0  # OpenCV edgeThreshold
    n_octave_layers: int = 3  # OpenCV nOctaveLayers
    root_sift: bool = True  # match Hellinger-normalised descriptors (RootSIFT, Arandjelovic 2012)
    normalize_contrast: bool = True  # stretch grey levels (1st-99th percentile) before detection
    device: str = "cpu"  # torch device of the matcher


class SiftBackend(DescriptorMatching):
    """OpenCV SIFT on the grayscale image; descriptors stored as uint8."""

    name = "sift"
    descriptor_dtype = np.dtype(np.uint8)
    query_keypoints = 8192  # nearest-neighbour matching is cheap: more query keypoints than map ones

    def __init__(self, config: SiftConfig | dict | None = None, **opts) -> None:
        self.config = backend_config(SiftConfig, config, opts, "SIFT")

    def extract(self, image_rgb: np.ndarray, mask: np.ndarray | None = None,
                max_keypoints: int | None = None) -> Features:
        """Detect and describe; keypoints in continuous pixel coordinates (centre = +0.5)."""
        img, mask = check_image(image_rgb, mask)
        c = self.config
        k = c.max_keypoints if max_keypoints is None else max_keypoints
        gray = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)
        if c.normalize_contrast:
            gray = stretch_contrast(gray)
        sift = cv2.SIFT_create(nfeatures=0, nOctaveLayers=c.n_octave_layers,
                               contrastThreshold=c.contrast_threshold, edgeThreshold=c.edge_threshold)
        cv_mask = None if mask is None else mask.astype(np.uint8) * 255
        kps, desc = sift.detectAndCompute(gray, cv_mask)
        if not kps or desc is None:
            return Features(np.zeros((0, 2), np.float32), np.zeros(0, np.float32), np.zeros((0, 128), np.uint8))
        # OpenCV puts pixel centres on integers; ours are at +0.5.
        uv = np.array([kp.pt for kp in kps], dtype=np.float32) + 0.5
        scores = np.array([kp.response for kp in kps], dtype=np.float32)
        # OpenCV scales SIFT descriptors to [0, 255] (x512 after the 0.2 clip); round to uint8.
        desc_u8 = np.clip(np.round(desc), 0, 255).astype(np.uint8)
        # OpenCV may duplicate a keypoint with several orientations: keep them (distinct descriptors).
        order = top_k(scores, k)
        return Features(uv[order], scores[order], desc_u8[order])

    def match(self, desc_a: np.ndarray, desc_b: np.ndarray, ratio: float = 0.8,
              mutual: bool = True) -> np.ndarray:
        """Mutual nearest neighbours on L2 (RootSIFT when configured) passing the ratio test."""
        a, b = np.asarray(desc_a, np.float32), np.asarray(desc_b, np.float32)
        if self.config.root_sift:
            a, b = _root_sift(a), _root_sift(b)
        return mutual_nn_match(a, b, metric="l2", ratio=ratio, mutual=mutual, device=self.config.device)


def _root_sift(desc: np.ndarray) -> np.ndarray:
    """Hellinger kernel mapping: L1-normalise, square root (then unit L2 norm)."""
    if desc.ndim != 2:
        return desc
    d = np.maximum(desc, 0.0)
    return np.sqrt(d / np.maximum(d.sum(axis=1, keepdims=True), 1e-12))
