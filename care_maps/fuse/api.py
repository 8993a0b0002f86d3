"""The fuse stage as two functions: a store in, its grid or instance map added to it.

Each takes the map's config (what the map is made from) and the run's
:class:`care_maps.runtime.execution.Execution` (how the build runs: read-ahead, memory, batch sizes,
rebuilding a current map, progress bars).
"""

from __future__ import annotations

from pathlib import Path

from care_maps.core.store import Store
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.fuse.instances import InstanceConfig, build_instances
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution

__all__ = ["fuse_grid", "fuse_instances"]


def _path(store: Store | Path) -> Path:
    return store.path if isinstance(store, Store) else Path(store)


def fuse_grid(
    store: Store | Path, config: GridConfig, *, run: Execution = DEFAULT_EXECUTION
) -> Path:
    """Fuse the store's views into its grid map (``cells.parquet``); returns that path.

    A grid built from the same store content with the same config is kept as it is (unless
    ``run.overwrite``).
    """
    return build_grid(_path(store), config, run=run)


def fuse_instances(
    store: Store | Path, config: InstanceConfig, *, run: Execution = DEFAULT_EXECUTION
) -> Path:
    """Build the store's instance map (``instances.parquet``); returns that path.

    A map built from the same store content with the same config is kept as it is (unless
    ``run.overwrite``).
    """
    return build_instances(_path(store), config, run=run)
