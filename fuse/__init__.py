"""fuse stage."""

from __future__ import annotations

from typing import Any

__all__ = ["fuse_grid", "fuse_instances"]


def __getattr__(name: str) -> Any:
    """The stage function(s) (``fuse_grid``, ``fuse_instances``), imported on first use: the
    package's light modules stay light to import."""
    if name in __all__:
        from fuse.api import fuse_grid, fuse_instances  # noqa: F401

        return locals()[name]
    msg = f"module {__name__!r} has no attribute {name!r}"
    raise AttributeError(msg)
