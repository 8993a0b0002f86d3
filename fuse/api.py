"""The fuse stage as two functions: a store in, its grid or instance map added to it."""

from __future__ import annotations

from pathlib import Path

from care.store import Store
from fuse.grid import GridConfig, build_grid
from fuse.instances import InstanceConfig, build_instances

__all__ = ["fuse_grid", "fuse_instances"]


def _path(store: Store | Path) -> Path:
    return store.path if isinstance(store, Store) else Path(store)


def fuse_grid(store: Store | Path, config: GridConfig) -> Path:
    """Fuse the store's views into its grid map (``cells.parquet``); returns that path.

    A grid built from the same store content with the same config is kept as it is.
    """
    return build_grid(_path(store), config)


def fuse_instances(store: Store | Path, config: InstanceConfig) -> Path:
    """Build the store's instance map (``instances.parquet``); returns that path.

    A map built from the same store content with the same config is kept as it is.
    """
    return build_instances(_path(store), config)
