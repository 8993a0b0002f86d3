"""fuse stage."""

from __future__ import annotations

from runtime.lazy import lazy_exports

__all__ = ["fuse_grid", "fuse_instances"]

__getattr__ = lazy_exports(__name__, {"fuse_grid": "fuse.api", "fuse_instances": "fuse.api"})
