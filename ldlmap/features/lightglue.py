"""LightGlue (Lindenberger et al. 2023; kornia's network) with packaged weights, matching one
query against many map views.

Two paths, chosen by device (the CPU timings behind the choice: docs/measurements.md#lightglue-paths):

- CUDA: one forward pass per batch of views. The views have different keypoint counts: they
  are padded to the batch's largest and the padding is masked out of the attention and of the
  assignment, so each view matches as it would alone with all layers run (no early stopping or
  pruning, which would make the views of a batch diverge).
- CPU: one adaptive pass per view (early stopping and point pruning on), which the CPU runs
  faster than any batch.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Sequence, TYPE_CHECKING

import numpy as np

from ldlmap.core.errors import InputError
from ldlmap.core.lazy import lazy_module
from ldlmap.features.weights import load_strict, packaged_weights, read_checkpoint

F = lazy_module("torch.nn.functional")
kornia_feature = lazy_module("kornia.feature")
torch = lazy_module("torch")

if TYPE_CHECKING:  # pragma: no cover
    import torch

    from ldlmap.features.base import Features

# Network configuration per detector (kornia LightGlue configuration names; XFeat's is LighterGlue).
_CONFIGS = {
    "aliked": dict(input_dim=128, descriptor_dim=256, n_layers=9, num_heads=4),
    "disk": dict(input_dim=128, descriptor_dim=256, n_layers=9, num_heads=4),
    "xfeat": dict(input_dim=64, descriptor_dim=96, n_layers=6, num_heads=1),
    "superpoint": dict(input_dim=256, descriptor_dim=256, n_layers=9, num_heads=4),
}
# Early stopping and point pruning of the per-view (CPU) path: LightGlue's defaults, LighterGlue's.
_ADAPTIVE = {"aliked": (0.95, 0.99), "disk": (0.95, 0.99), "xfeat": (-1.0, 0.95), "superpoint": (0.95, 0.99)}
_PAD_LOGIT = -1e4  # similarity of a padded map keypoint: never a row's maximum, finite (no NaN)


def _state_dict(name: str, n_layers: int, path: str | None = None) -> dict:
    """The LightGlue weights of ``name`` (packaged, or the file ``path``) with kornia's parameter names."""
    path = path or packaged_weights(f"{name}_lightglue")
    state = read_checkpoint(path, "LightGlue")
    if name == "xfeat":  # the file holds the extractor too; the matcher is under "matcher."
        state = {k[len("matcher."):]: v for k, v in state.items() if k.startswith("matcher.")}
    renamed = {}
    for k, v in state.items():
        if k.startswith("log_assignment.") and k.endswith(".r"):
            continue  # DISK's file keeps an unused constant (1.0) per layer that no LightGlue reads
        for part in ("self_attn", "cross_attn"):
            for i in range(n_layers):
                if k.startswith(f"{part}.{i}."):
                    k = f"transformers.{i}.{part}." + k[len(f"{part}.{i}."):]
        renamed[k] = v
    return renamed


@lru_cache(maxsize=None)
def load_lightglue(name: str, device: str = "cpu", path: str | None = None) -> "LightGlueMatcher":
    """The kornia_feature.LightGlue matcher of detector ``name`` on ``device`` (weights packaged, or from the file
    ``path``: SuperPoint's), loaded once per process."""
    if name not in _CONFIGS:
        raise InputError(f"no kornia_feature.LightGlue weights for {name!r}; known: {', '.join(sorted(_CONFIGS))}")
    conf = _CONFIGS[name]
    depth, width = _ADAPTIVE[name]
    net = kornia_feature.LightGlue(None, **conf, flash=False, depth_confidence=depth, width_confidence=width)
    load_strict(net, _state_dict(name, conf["n_layers"], path), f"{name} kornia_feature.LightGlue",
                derived=("confidence_thresholds",))
    return LightGlueMatcher(net.eval().to(torch.device(device)))


class LightGlueMatcher:
    """LightGlue: one query against many map views (batched on CUDA, adaptive per view on the CPU)."""

    def __init__(self, net) -> None:
        self.net = net

    def match_views(self, query: "Features", query_size: tuple[int, int], views: Sequence["Features"],
                    view_size: tuple[int, int], filter_threshold: float = 0.1, batch: int = 8) -> list[np.ndarray]:
        """Matches (M_v, 2) int64 ``(i in query, j in view v)`` of each view: mutual best
        assignments with confidence above ``filter_threshold``; on CUDA ``batch`` views per pass,
        on the CPU one adaptive pass per view (module docstring)."""
        if next(self.net.parameters()).device.type != "cpu" and batch > 1:
            return self.match_batched(query, query_size, views, view_size, filter_threshold, batch)
        return [self.match_pair(query, query_size, v, view_size, filter_threshold) for v in views]

    def match_batched(self, query: "Features", query_size: tuple[int, int], views: Sequence["Features"],
                      view_size: tuple[int, int], filter_threshold: float = 0.1, batch: int = 8) -> list[np.ndarray]:
        """:meth:`match_views` with ``batch`` views per forward pass, all layers run (any device)."""
        out: list[np.ndarray] = [np.zeros((0, 2), np.int64)] * len(views)
        if len(query) == 0:
            return out
        dev = next(self.net.parameters()).device
        todo = [v for v in range(len(views)) if len(views[v])]
        kq = _normalized(query.keypoints, query_size, dev)[None]
        dq = torch.from_numpy(np.asarray(query.descriptors, np.float32)).to(dev)[None]
        for s in range(0, len(todo), max(1, int(batch))):
            ids = todo[s:s + max(1, int(batch))]
            n = max(len(views[v]) for v in ids)
            kv = torch.zeros((len(ids), n, 2), device=dev)
            dv = torch.zeros((len(ids), n, dq.shape[-1]), device=dev)
            valid = torch.zeros((len(ids), n), dtype=torch.bool, device=dev)
            for b, v in enumerate(ids):
                m = len(views[v])
                kv[b, :m] = _normalized(views[v].keypoints, view_size, dev)
                dv[b, :m] = torch.from_numpy(np.asarray(views[v].descriptors, np.float32)).to(dev)
                valid[b, :m] = True
            with torch.inference_mode():
                pairs = self._forward(kq, dq, kv, dv, valid, filter_threshold)
            for b, v in enumerate(ids):
                out[v] = pairs[b]
        return out

    def match_pair(self, a: "Features", size_a: tuple[int, int], b: "Features", size_b: tuple[int, int],
                   filter_threshold: float = 0.1) -> np.ndarray:
        """Matches (M, 2) ``(i in a, j in b)`` of one pair, with early stopping and point pruning."""
        if len(a) == 0 or len(b) == 0:
            return np.zeros((0, 2), np.int64)
        dev = next(self.net.parameters()).device

        def side(f, size):
            uv = np.clip(np.asarray(f.keypoints, np.float32) - 0.5, 0.0, [size[0], size[1]])  # inside the image
            return {"keypoints": torch.from_numpy(uv.astype(np.float32)).to(dev)[None],
                    "descriptors": torch.from_numpy(np.asarray(f.descriptors, np.float32)).to(dev)[None],
                    "image_size": torch.tensor([[float(size[0]), float(size[1])]], device=dev)}

        self.net.conf.filter_threshold = float(filter_threshold)
        with torch.inference_mode():
            m0 = self.net({"image0": side(a, size_a), "image1": side(b, size_b)})["matches0"][0]
        i = torch.nonzero(m0 > -1).squeeze(1)
        return torch.stack([i, m0[i]], 1).cpu().numpy().astype(np.int64)

    def _forward(self, kq, dq, kv, dv, valid, th: float) -> list[np.ndarray]:
        """Query (1, M, .) against views (B, N, .) with ``valid`` (B, N): the network's layers with
        the padding masked, then the dual-softmax assignment and the mutual check."""
        net, B = self.net, len(kv)
        enc_q = net.posenc(kq)  # (2, 1, 1, M, head_dim): cosines and sines, one head axis
        enc_q = enc_q.expand(enc_q.shape[0], B, *enc_q.shape[2:])
        enc_v = net.posenc(kv)
        x0 = net.input_proj(dq).expand(B, -1, -1)
        x1 = net.input_proj(dv)
        mask0 = torch.ones((B, 1, x0.shape[1], 1), dtype=torch.bool, device=x0.device)  # (B, heads, N, 1)
        mask1 = valid[:, None, :, None]
        for layer in net.transformers:
            x0, x1 = layer(x0, x1, enc_q, enc_v, mask0=mask0, mask1=mask1)
        head = net.log_assignment[-1]
        m0, m1 = head.final_proj(x0), head.final_proj(x1)
        d = m0.shape[-1]
        sim = torch.einsum("bmd,bnd->bmn", m0 / d ** 0.25, m1 / d ** 0.25)
        sim = sim.masked_fill(~valid[:, None, :], _PAD_LOGIT)
        z0, z1 = head.matchability(x0), head.matchability(x1)
        scores = F.log_softmax(sim, 2) + F.log_softmax(sim, 1) + F.logsigmoid(z0) + F.logsigmoid(z1).transpose(1, 2)
        best0 = scores.max(2)  # per query keypoint
        best1 = scores.max(1).indices  # per view keypoint
        i = torch.arange(scores.shape[1], device=scores.device)[None]
        ok = (best1.gather(1, best0.indices) == i) & (best0.values.exp() > th)
        ok &= valid.gather(1, best0.indices)
        out = []
        for b in range(B):
            q = torch.nonzero(ok[b]).squeeze(1)
            out.append(torch.stack([q, best0.indices[b, q]], 1).cpu().numpy().astype(np.int64))
        return out


def _normalized(uv: np.ndarray, size: tuple[int, int], dev) -> "torch.Tensor":
    """Our pixel coordinates (centre +0.5) to LightGlue's normalised ones: the detectors' pixel
    centres are integers, scaled by ``max(W, H) / 2`` about the image centre."""
    w, h = float(size[0]), float(size[1])
    k = torch.from_numpy(np.clip(np.asarray(uv, np.float32) - 0.5, 0.0, [w, h]).astype(np.float32)).to(dev)
    return (k - torch.tensor([w / 2, h / 2], device=dev)) / (max(w, h) / 2)
