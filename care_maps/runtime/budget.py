"""Memory the grid would need, checked before it is allocated.

A cell size far below the data's resolution makes every depth pixel its own cell: the
running sums grow by kilobytes per cell and the top-down raster by the square of the
extent over the cell size. Both are checked against the memory available *before* the
arrays grow, so such a setting fails in one line at once instead of a MemoryError (or the
kernel's OOM killer) minutes later.
"""

from __future__ import annotations

import os

from care_maps.core.errors import FuseError

__all__ = ["available_memory", "check_raster"]

_SHARE = 0.8
"""Fraction of the available memory one structure may take."""


def available_memory() -> int:
    """Bytes of memory available to new allocations (Linux ``MemAvailable``; else free)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def _gib(n: float) -> str:
    return f"{n / 2**30:.1f} GiB"


def check_raster(shape: tuple[int, ...], itemsize: int, cell_size: float | None = None) -> None:
    """Refuse allocating a raster of ``shape`` when it cannot fit in memory."""
    n = 1
    for s in shape:
        n *= int(s)
    need = n * itemsize
    free = available_memory()
    if need > _SHARE * free:
        size = "" if cell_size is None else f"--cell-size {cell_size}: "
        msg = (
            f"{size}the top-down raster of {shape[1]}x{shape[0]} cells needs {_gib(need)}, more "
            f"than the {_gib(free)} of memory available; raise --cell-size"
        )
        raise FuseError(msg)
