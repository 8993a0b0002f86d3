"""Stage functions exported by their package without importing them at package import.

``from fuse import fuse_grid`` should work, but ``import care_maps.fuse.layout`` (a query reading a
finished grid) must not pull in the fusion's torch. A package names its exports and the
module each lives in; the module is imported on first access (PEP 562).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(package: str, exports: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package`` that imports ``exports[name]`` on first use."""

    def attribute(name: str) -> Any:
        if name in exports:
            return getattr(importlib.import_module(exports[name]), name)
        msg = f"module {package!r} has no attribute {name!r}"
        raise AttributeError(msg)

    return attribute
