"""The one way this package imports lazily: a module object that imports on first use.

Modules import their dependencies at the top. Two kinds are named there through
:func:`lazy_module` instead of ``import``, so that they load only when a command needs them:

- heavy libraries (torch, open3d, pycolmap, pymeshlab, Ray, kornia, cv2, h5py, scipy and
  numpy in modules the CLIs import), which would cost seconds at ``--help`` time or are optional;
- in ``ldlmap/cli.py`` and ``ldlloc/cli.py``, the modules that carry out a command (the CLIs
  parse options without loading numpy; ``tests/test_cli_ux.py`` checks it).

``torch = lazy_module("torch")`` at the top of a module, then ``torch.zeros(...)`` as usual: the
first attribute access imports the library and copies its namespace into the module object, so
later accesses cost what a normal module's do. An optional library that is not installed raises
:class:`~ldlmap.core.errors.MissingDependency` (an ImportError) at first use, with ``hint`` as
the way to install it. ``import X`` inside a function is left for code that must catch a missing
optional library at a precise point (``ray_cluster.require_ray``).

The package's own public names (``ldlmap.Localizer`` and friends) load through
:mod:`ldlmap.core.lazy_api` (PEP 562).
"""

from __future__ import annotations

import sys
import types
from importlib import import_module
from typing import Any


class MissingDependency(ImportError):
    """An optional library a command needs is not installed."""


class LazyModule(types.ModuleType):
    """Stands for module ``name`` until an attribute is read, then holds that module's namespace."""

    def __init__(self, name: str, hint: str | None = None):
        super().__init__(name)
        self.__dict__["_lazy_hint"] = hint

    def _load(self) -> types.ModuleType:
        try:
            module = import_module(self.__name__)
        except ImportError as exc:
            hint = self.__dict__["_lazy_hint"]
            if hint is None:
                raise
            raise MissingDependency(f"{self.__name__} is not installed ({exc}); {hint}") from exc
        self.__dict__.update(module.__dict__)
        self.__dict__["_lazy_loaded"] = module
        return module

    def __getattr__(self, attr: str) -> Any:
        if attr.startswith("__") and attr.endswith("__") and "_lazy_loaded" not in self.__dict__:
            raise AttributeError(attr)  # copy, pickle and inspect probe dunders: do not import for them
        return getattr(self._load(), attr)

    def __dir__(self) -> list[str]:
        return dir(self._load())

    @property
    def loaded(self) -> bool:
        """Whether the module has been imported (here or by anyone: then it is used as is)."""
        return "_lazy_loaded" in self.__dict__ or self.__name__ in sys.modules


def lazy_module(name: str, hint: str | None = None) -> types.ModuleType:
    """Module ``name``, imported at its first attribute access (``sys.modules``'s entry when it is
    already imported). ``hint``: how to install it, for the error when it is missing."""
    return sys.modules.get(name) or LazyModule(name, hint)
