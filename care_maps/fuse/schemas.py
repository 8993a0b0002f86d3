"""The declared columns of the map tables: one source for the writers and the readers.

``cells.parquet`` (the grid) and ``instances.parquet`` (the instances) share the candidate
columns of :func:`care_maps.fuse.measures.candidate_columns` and add their own. The map-build
skeleton checks every table it commits against its declaration (:mod:`care_maps.fuse.build`), and
:func:`care_maps.query.map.load_map` checks a table against it before reading, so a column renamed
or retyped on one side is one clear line, not a ``KeyError`` deep in a query. A map's
per-view table with a fixed layout (``cell_views.parquet``) is declared here too
(:data:`VIEW_TABLE_SCHEMAS`): one written in another layout (an older grid's, with a copy
of every per-view feature) makes the map out of date, so ``care fuse grid`` rebuilds it.
Only pyarrow is imported: readers of finished maps load this without the fusion.
"""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa

__all__ = [
    "CANDIDATE_FIELDS",
    "CELL_VIEWS_FIELDS",
    "GRID_FIELDS",
    "INSTANCE_FIELDS",
    "MAP_SCHEMAS",
    "QUERY_COLUMNS",
    "VIEW_TABLE_SCHEMAS",
    "schema_problems",
    "view_table_problems",
]

CANDIDATE_FIELDS = (
    pa.field("candidate_id", pa.int32()),
    pa.field("num_views", pa.int32()),
    pa.field("feature", pa.list_(pa.float16())),
    pa.field("log_norm", pa.float32()),
    pa.field("top_classes", pa.list_(pa.int16())),
    pa.field("top_probs", pa.list_(pa.float16())),
    pa.field("entropy", pa.float32()),
    pa.field("stderr", pa.float32()),
    pa.field("pwkl", pa.float32()),
)
"""Every map's candidates, in row order (``candidate_id`` = 0..N-1)."""

GRID_FIELDS = (
    pa.field("ix", pa.int32()),
    pa.field("iy", pa.int32()),
    pa.field("x", pa.float32()),
    pa.field("y", pa.float32()),
    pa.field("z_max", pa.float32()),
    pa.field("weight", pa.float32()),
    pa.field("r", pa.uint8()),
    pa.field("g", pa.uint8()),
    pa.field("b", pa.uint8()),
    pa.field("obstacle", pa.bool_()),
    pa.field("num_pixels", pa.int32()),
)
"""The grid's own columns (see :mod:`care_maps.fuse.grid`)."""

INSTANCE_FIELDS = (
    pa.field("num_points", pa.int32()),
    pa.field("point_indices", pa.list_(pa.int32())),
    pa.field("bbox_min", pa.list_(pa.float32(), 3)),
    pa.field("bbox_max", pa.list_(pa.float32(), 3)),
    pa.field("center", pa.list_(pa.float32(), 3)),
    pa.field("source_id", pa.int64()),
)
"""The instance map's own columns (see :mod:`care_maps.fuse.instances`)."""

CELL_VIEWS_FIELDS = (
    pa.field("cell_id", pa.int32(), nullable=False),
    pa.field("view_id", pa.int32(), nullable=False),
    pa.field("weight", pa.float32(), nullable=False),
    pa.field("num_pixels", pa.int32(), nullable=False),
)
"""``cell_views.parquet``, one row per (view, cell) sample of the grid: the cell's
``candidate_id``, the view, the sample's summed pixel weight and its pixel count. No copy
of the sample's feature: that is a function of the store and the grid's config
(:func:`care_maps.fuse.cells.view_samples`), derived again where needed (:mod:`care_maps.fuse.recompute`)."""

VIEW_TABLE_SCHEMAS: dict[str, pa.Schema] = {"cell_views": pa.schema(CELL_VIEWS_FIELDS)}
"""Per-view table name -> its declared schema (exactly these columns, in this order)."""

MAP_SCHEMAS: dict[str, pa.Schema] = {
    "grid": pa.schema([*CANDIDATE_FIELDS, *GRID_FIELDS]),
    "instances": pa.schema([*CANDIDATE_FIELDS, *INSTANCE_FIELDS]),
}
"""Map kind -> the declared schema of its main table (what the writers must give)."""

_QUERIED = ("candidate_id", "num_views", "feature", "log_norm", "top_classes", "entropy",
            "stderr", "pwkl")  # fmt: skip
QUERY_COLUMNS: dict[str, tuple[str, ...]] = {
    "grid": (*_QUERIED, "x", "y", "z_max"),
    "instances": (*_QUERIED, "center", "point_indices"),
}
"""Map kind -> the declared columns a query reads (:func:`care_maps.query.map.map_from_table`)."""
assert all(set(QUERY_COLUMNS[k]) <= set(MAP_SCHEMAS[k].names) for k in MAP_SCHEMAS)


def schema_problems(
    schema: pa.Schema, kind: str, where: Path, *, columns: tuple[str, ...] | None = None
) -> str | None:
    """What ``schema`` lacks or types otherwise than the ``kind`` map declares (None: all
    there; extra columns are allowed). ``columns``: only those, by name (a reader's
    check: a fixed or variable-length list reads the same)."""
    wrong = []
    for field in MAP_SCHEMAS[kind]:
        if columns is not None and field.name not in columns:
            continue
        index = schema.get_field_index(field.name)
        if index < 0:
            wrong.append(f"{field.name} missing")
        elif columns is None and not schema.field(index).type.equals(field.type):
            wrong.append(f"{field.name} is {schema.field(index).type}, not {field.type}")
    if not wrong:
        return None
    return f"{where}: not a {kind} map table as declared ({'; '.join(wrong)})"


def view_table_problems(schema: pa.Schema, table: str, where: Path) -> str | None:
    """How ``schema`` differs from the declared per-view ``table`` (None: the same columns,
    names and types in order; metadata aside). Tables without a declaration pass."""
    declared = VIEW_TABLE_SCHEMAS.get(table)
    if declared is None:
        return None
    found = [(f.name, f.type) for f in schema]
    if found == [(f.name, f.type) for f in declared]:
        return None
    names = ", ".join(f"{n}: {t}" for n, t in found)
    return f"{where}: not a {table} table as declared (columns {names})"
