"""Where a grid's cells lie: the light description query-time code needs without the fusion.

Kept apart from :mod:`care_maps.fuse.grid` so that readers of a finished grid (goals, occupancy maps)
do not import the fusion machinery (torch).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import pyarrow as pa

from care_maps.core.errors import FuseError
from care_maps.core.keys import GRID_CELL_SIZE_KEY, GRID_ORIGIN_KEY, GRID_SHAPE_KEY

__all__ = ["CELLS_TABLE", "GridLayout"]

CELLS_TABLE = "cells"
"""The grid map's table name in a store directory."""


@dataclass(frozen=True)
class GridLayout:
    """Where the occupied cells lie: the grid origin, cell size and the raster shape."""

    cell_size: float
    origin: tuple[float, float]
    """World (x, y) of the lower corner of cell (ix, iy) = (0, 0)."""
    shape: tuple[int, int]
    """(nx, ny) cells spanned by the occupied cells."""

    @classmethod
    def from_table(cls, table: pa.Table) -> GridLayout:
        md = table.schema.metadata or {}
        try:
            return cls(
                float(md[GRID_CELL_SIZE_KEY]),
                tuple(json.loads(md[GRID_ORIGIN_KEY])),
                tuple(json.loads(md[GRID_SHAPE_KEY])),
            )
        except KeyError as err:
            msg = f"cells table lacks grid metadata {err}; rebuild it with `care fuse grid`"
            raise FuseError(msg) from err

    def metadata(self) -> dict[bytes, bytes]:
        return {
            GRID_CELL_SIZE_KEY: repr(self.cell_size).encode(),
            GRID_ORIGIN_KEY: json.dumps(list(self.origin)).encode(),
            GRID_SHAPE_KEY: json.dumps(list(self.shape)).encode(),
        }
