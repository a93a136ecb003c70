"""SuperPoint (DeTone, Malisiewicz, Rabinovich 2018), implemented here in PyTorch.

Top-down: post-processing helpers, the network (parameter names match the official MagicLeap
``superpoint_v1.pth`` state dict so it loads with ``strict=True``), checkpoint loading, and the
feature backend. Weights are resolved by :mod:`ldlmap.features.weights`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.features.base import DescriptorMatching, Features, backend_config, check_image, mutual_nn_match
from ldlmap.features.lightglue import load_lightglue
from ldlmap.features.weights import key_diff, read_checkpoint, resolve_weights

F = lazy_module("torch.nn.functional")
cv2 = lazy_module("cv2")
nn = lazy_module("torch.nn")
torch = lazy_module("torch")

if TYPE_CHECKING:  # pragma: no cover
    import torch

CELL = 8  # the encoder downsamples by 8; the detector predicts one of 64 positions or "no point"


# ----------------------------------------------------------------------------------- helpers


def nms_keep(scores: "torch.Tensor", radius: int) -> "torch.Tensor":
    """Boolean map of local maxima of ``scores`` (B, H, W) in (2 r + 1)^2 windows.

    Equal maxima within a window are resolved by keeping the one with the largest linear index,
    so no two kept pixels are closer than ``radius + 1`` in the max norm.
    """
    k, r = 2 * radius + 1, radius
    pooled = F.max_pool2d(scores[:, None], k, stride=1, padding=r)[:, 0]
    cand = (scores == pooled) & (scores > 0)
    B, H, W = scores.shape
    lin = torch.arange(H * W, device=scores.device, dtype=torch.float64).view(1, H, W).expand(B, H, W)
    lin = torch.where(cand, lin, torch.full_like(lin, -1.0))
    top = F.max_pool2d(lin[:, None], k, stride=1, padding=r)[:, 0]
    return cand & (lin == top)


def sample_descriptors(desc_map: "torch.Tensor", uv: "torch.Tensor") -> "torch.Tensor":
    """Bilinearly sample a (1, D, Hc, Wc) descriptor map at continuous pixel coordinates (K, 2).

    Cell ``j`` covers pixels ``[8 j, 8 j + 8)``, so its centre is at ``8 j + 4`` in our
    continuous coordinates; grid_sample with ``align_corners=True`` addresses cell centres.
    Returns (K, D) unit vectors.
    """
    _, _, hc, wc = desc_map.shape
    gx = (uv[:, 0] / CELL - 0.5) / max(wc - 1, 1) * 2.0 - 1.0
    gy = (uv[:, 1] / CELL - 0.5) / max(hc - 1, 1) * 2.0 - 1.0
    grid = torch.stack([gx, gy], dim=-1).view(1, 1, -1, 2)
    d = F.grid_sample(desc_map, grid, mode="bilinear", align_corners=True, padding_mode="border")
    return F.normalize(d[0, :, 0].T, dim=1)


# ----------------------------------------------------------------------------------- network


def _superpoint_net():
    """Build the network class lazily (keeps torch out of import time)."""
    class SuperPointNet(nn.Module):
        """Shared VGG encoder + detector head (65 channels) + descriptor head (256 channels).

        ``forward(image)`` takes (B, 1, H, W) grayscale in [0, 1], H and W multiples of 8, and
        returns ``(prob, desc)``: ``prob`` (B, H, W) keypoint probability per pixel (softmax over
        65 classes, dustbin dropped, pixel-shuffled to full resolution) and ``desc``
        (B, 256, H / 8, W / 8) L2-normalised dense descriptors.
        """

        def __init__(self) -> None:
            super().__init__()
            c1, c2, c3, c4, c5, d1 = 64, 64, 128, 128, 256, 256

            def conv(cin: int, cout: int, k: int = 3) -> nn.Conv2d:
                return nn.Conv2d(cin, cout, kernel_size=k, stride=1, padding=k // 2)

            self.conv1a, self.conv1b = conv(1, c1), conv(c1, c1)
            self.conv2a, self.conv2b = conv(c1, c2), conv(c2, c2)
            self.conv3a, self.conv3b = conv(c2, c3), conv(c3, c3)
            self.conv4a, self.conv4b = conv(c3, c4), conv(c4, c4)
            self.convPa, self.convPb = conv(c4, c5), conv(c5, CELL * CELL + 1, 1)
            self.convDa, self.convDb = conv(c4, c5), conv(c5, d1, 1)

        def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            x = F.relu(self.conv1a(image))
            x = F.max_pool2d(F.relu(self.conv1b(x)), 2)
            x = F.relu(self.conv2a(x))
            x = F.max_pool2d(F.relu(self.conv2b(x)), 2)
            x = F.relu(self.conv3a(x))
            x = F.max_pool2d(F.relu(self.conv3b(x)), 2)
            x = F.relu(self.conv4a(x))
            x = F.relu(self.conv4b(x))
            logits = self.convPb(F.relu(self.convPa(x)))
            prob = F.pixel_shuffle(F.softmax(logits, dim=1)[:, :-1], CELL)[:, 0]
            desc = F.normalize(self.convDb(F.relu(self.convDa(x))), dim=1)
            return prob, desc

    return SuperPointNet


def build_superpoint() -> "torch.nn.Module":
    """A randomly initialised SuperPoint network (use :func:`load_superpoint` for weights)."""
    return _superpoint_net()()


def load_superpoint(path: str | Path, device: str = "cpu") -> "torch.nn.Module":
    """SuperPoint with the checkpoint at ``path`` loaded strictly, in eval mode, on ``device``."""
    path = Path(path)
    state = read_checkpoint(path, "SuperPoint")
    if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise InputError(f"SuperPoint weights {path} do not hold a state dict")
    net = build_superpoint()
    missing, unexpected = key_diff(net.state_dict().keys(), state.keys())
    if missing or unexpected:
        raise InputError(f"SuperPoint weights {path} do not match the network: missing {missing[:4]}, "
                         f"unexpected {unexpected[:4]}")
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise InputError(f"SuperPoint weights {path} do not match the network: "
                         f"{str(exc).splitlines()[-1].strip()}") from None
    try:
        return net.eval().to(torch.device(device))
    except (RuntimeError, AssertionError) as exc:
        raise InputError(f"torch device {device!r} is not available: {exc}") from None


# ----------------------------------------------------------------------------------- backend


@dataclass(frozen=True)
class SuperPointConfig:
    """Options of the SuperPoint backend (SuperGlue's public defaults)."""

    nms_radius: int = 4  # non-maximum suppression radius in pixels
    keypoint_threshold: float = 0.005  # minimum detector probability
    max_keypoints: int = 4096  # keep the highest-scoring keypoints (0: all)
    remove_borders: int = 4  # drop detections this close to the image border (pixels)
    weights: str | None = None  # checkpoint path (else $LDL_SUPERPOINT_WEIGHTS, cache, download)
    allow_download: bool = True  # first-use download into the cache folder
    lightglue_weights: str | None = None  # SuperPoint LightGlue checkpoint (else
    # $LDL_SUPERPOINT_LIGHTGLUE_WEIGHTS, else the cache; never downloaded): matching by LightGlue when found
    device: str = "cpu"  # torch device


class SuperPointBackend(DescriptorMatching):
    """SuperPoint detector/descriptor; descriptors stored as float16, matched by LightGlue when its
    SuperPoint weights are present, else mutual nearest neighbours on cosine similarity."""

    name = "superpoint"
    descriptor_dtype = np.dtype(np.float16)

    @property
    def query_keypoints(self) -> int:
        """Nearest neighbours are cheap (8192 query keypoints); LightGlue takes the map's count."""
        return self.config.max_keypoints if self.matcher is not None else 8192

    def __init__(self, config: SuperPointConfig | dict | None = None, *, net: "torch.nn.Module | None" = None,
                 **opts) -> None:
        self.config = c = backend_config(SuperPointConfig, config, opts, "SuperPoint")
        if net is not None:
            self.weights_path = None
            self.net = net.eval().to(c.device)
        else:
            self.weights_path = resolve_weights("superpoint", c.weights, allow_download=c.allow_download)
            self.net = load_superpoint(self.weights_path, c.device)
        self.matcher = None  # LightGlue when its SuperPoint weights are present, else nearest neighbours
        # optional: absent, nearest neighbours match; named by path or environment but missing, an error
        lg_path = resolve_weights("superpoint_lightglue", c.lightglue_weights, allow_download=False, required=False)
        if lg_path is not None:
            self.matcher = load_lightglue("superpoint", c.device, str(lg_path))

    @property
    def matcher_name(self) -> str:
        return "lightglue" if self.matcher is not None else "mutual-nn"

    def match_views(self, query: Features, query_size: tuple[int, int], views, view_size: tuple[int, int],
                    ratio: float = 0.8) -> list[np.ndarray]:
        """LightGlue when its weights are present (``ratio`` unused), else mutual nearest neighbours."""
        if self.matcher is None:
            return DescriptorMatching.match_views(self, query, query_size, views, view_size, ratio)
        return self.matcher.match_views(query, query_size, views, view_size)

    def extract(self, image_rgb: np.ndarray, mask: np.ndarray | None = None,
                max_keypoints: int | None = None) -> Features:
        """Detect and describe; keypoints at pixel centres (continuous coordinates, +0.5)."""
        img, mask = check_image(image_rgb, mask)
        c = self.config
        k = c.max_keypoints if max_keypoints is None else max_keypoints
        H, W = img.shape[:2]
        gray = cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
        dev = next(self.net.parameters()).device
        x = torch.from_numpy(gray).to(dev)[None, None]
        ph, pw = (-H) % CELL, (-W) % CELL  # pad bottom/right to a multiple of 8
        if ph or pw:
            x = F.pad(x, (0, pw, 0, ph), mode="replicate")
        with torch.no_grad():
            prob, desc = self.net(x)
            prob = prob[:, :H, :W].clone()
            b = c.remove_borders
            if b > 0:
                prob[:, :b] = 0
                prob[:, H - b:] = 0
                prob[:, :, :b] = 0
                prob[:, :, W - b:] = 0
            if mask is not None:
                prob[0][~torch.from_numpy(mask).to(dev)] = 0
            prob = torch.where(prob > c.keypoint_threshold, prob, torch.zeros_like(prob))
            keep = nms_keep(prob, c.nms_radius)[0]
            rows, cols = torch.nonzero(keep, as_tuple=True)
            scores = prob[0, rows, cols]
            if k and len(scores) > k:
                scores, top = torch.topk(scores, k)
                rows, cols = rows[top], cols[top]
            else:
                scores, order = torch.sort(scores, descending=True)
                rows, cols = rows[order], cols[order]
            uv = torch.stack([cols, rows], dim=1).to(torch.float32) + 0.5
            d = sample_descriptors(desc, uv) if len(uv) else torch.zeros((0, desc.shape[1]), device=dev)
        return Features(uv.cpu().numpy(), scores.float().cpu().numpy(),
                        d.cpu().numpy().astype(np.float16))

    def match(self, desc_a: np.ndarray, desc_b: np.ndarray, ratio: float = 0.8,
              mutual: bool = True) -> np.ndarray:
        """Mutual nearest neighbours on cosine similarity passing the (chordal distance) ratio test."""
        return mutual_nn_match(desc_a, desc_b, metric="cosine", ratio=ratio, mutual=mutual,
                               device=self.config.device)
