"""The schema-metadata keys the store's and the maps' Parquet tables carry: one spelling for
whatever writes a key and whatever reads it back.

Only the standard library: the CLI reads a map's metadata on every call.
"""

from __future__ import annotations

__all__ = [
    "ENCODER_DIM_KEY",
    "ENCODER_NAME_KEY",
    "ENCODER_VERSION_KEY",
    "GOAL_FRAME_KEY",
    "GRID_CELL_SIZE_KEY",
    "GRID_ORIGIN_KEY",
    "GRID_SHAPE_KEY",
    "LOGIT_SCALE_KEY",
    "SCHEMA_VERSION_KEY",
    "VOCABULARY_KEY",
]

SCHEMA_VERSION_KEY = b"care.schema_version"
"""The layout version of the table (``care_maps.core.store.SCHEMA_VERSION``)."""
ENCODER_NAME_KEY = b"care.encoder.name"
"""The encoder that made the features."""
ENCODER_VERSION_KEY = b"care.encoder.version"
"""That encoder's version (its weights and settings)."""
ENCODER_DIM_KEY = b"care.encoder.dim"
"""The feature dimension."""
VOCABULARY_KEY = b"care.vocabulary"
"""The class names of the table's class columns (JSON list)."""
LOGIT_SCALE_KEY = b"care.logit_scale"
"""The logit scale a map's class distributions were made with."""
GRID_CELL_SIZE_KEY = b"care.grid.cell_size"
"""A grid's cell edge (m)."""
GRID_ORIGIN_KEY = b"care.grid.origin"
"""A grid's origin, the lower corner of cell (0, 0) (JSON [x, y])."""
GRID_SHAPE_KEY = b"care.grid.shape"
"""A grid's size in cells (JSON [nx, ny])."""
GOAL_FRAME_KEY = b"care.goal.frame"
"""The frame of a table's goal columns (JSON: ``frame_id``, ``world_frame`` and the 16
values of ``world_from_frame``, row-major): the world-frame goal is that matrix times the
goal's pose (:mod:`care_maps.query.publish`)."""
