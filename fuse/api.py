"""The fuse stage as two functions: a store in, its grid or instance map added to it."""

from __future__ import annotations

from pathlib import Path

from care.store import Store
from care.threads import Work, threads_for
from fuse.grid import GridConfig, build_grid
from fuse.instances import InstanceConfig, build_instances

__all__ = ["fuse_grid", "fuse_instances"]


def _path(store: Store | Path) -> Path:
    return store.path if isinstance(store, Store) else Path(store)


def fuse_grid(store: Store | Path, config: GridConfig, *, rrd: Path | None = None) -> Path:
    """Fuse the store's views into its grid map (``cells.parquet``); returns that path.

    A grid built from the same store content with the same config is kept as it is. Runs
    on the thread pools of :attr:`care.threads.Work.FUSE`, whoever calls it: torch sums the
    views in an order that depends on its thread count, so a caller's pools would change
    the map's last bits (a pool worker and a notebook would build different bytes).
    """
    with threads_for(Work.FUSE):
        return build_grid(_path(store), config, rrd)


def fuse_instances(store: Store | Path, config: InstanceConfig, *, rrd: Path | None = None) -> Path:
    """Build the store's instance map (``instances.parquet``); returns that path.

    A map built from the same store content with the same config is kept as it is. Runs
    on the thread pools of :attr:`care.threads.Work.FUSE` (see :func:`fuse_grid`).
    """
    with threads_for(Work.FUSE):
        return build_instances(_path(store), config, rrd)
