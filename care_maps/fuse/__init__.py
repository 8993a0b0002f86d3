"""fuse stage."""

from __future__ import annotations

from care_maps.runtime.lazy import lazy_exports

__all__ = ["fuse_grid", "fuse_instances"]

__getattr__ = lazy_exports(
    __name__, {"fuse_grid": "care_maps.fuse.api", "fuse_instances": "care_maps.fuse.api"}
)
