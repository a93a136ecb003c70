"""A package's public API imported on first use (PEP 562), so that ``import ldlmap`` and the CLIs'
``--help`` stay instant."""

from __future__ import annotations

from importlib import import_module
from typing import Any, Callable


def lazy_api(package: str, api: dict[str, str]) -> tuple[list[str], Callable[[str], Any], Callable[[], list[str]]]:
    """``(__all__, __getattr__, __dir__)`` for ``package`` whose names ``api`` maps to their modules."""
    names = sorted(api)

    def getattr_(name: str) -> Any:
        if name not in api:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(import_module(api[name]), name)

    return names, getattr_, lambda: names
