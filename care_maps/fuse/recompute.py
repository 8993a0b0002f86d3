"""Columns for a new vocabulary or logit scale, without building the map again.

Only the candidate columns depend on the vocabulary and the logit scale; the rest of a map
(its cells or instances, geometry, masks) is kept in place. Each map gets its per-view
features its own way:

- the instance map's ``instance_views.parquet`` keeps every per-view feature (one row per
  instance view, a few thousand at most), fed to the same
  :class:`care_maps.fuse.accumulate.CandidateSums` as the build, a record batch at a time
  (:func:`sums_from_views`);
- the grid's per-view cell features are a function of the store (its views' depth, pose
  and patch features) and the grid's config, and a copy of them cost more to write than
  the fusion (``cell_views.parquet`` lists the samples without features). They are derived
  again by streaming the store's views through the build's own per-view code
  (:func:`care_maps.fuse.grid.fused_columns`), restricted to the map's cells in its
  ``candidate_id`` order, under the config the map records, so the columns equal a fresh
  build's with the same settings bit for bit. That needs the store the map was built from:
  another one (re-ingested, another map frame) is refused in one line.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa

from care_maps.core.config import recorded_fields
from care_maps.core.errors import FuseError
from care_maps.core.keys import LOGIT_SCALE_KEY
from care_maps.core.store import Store, iter_batches, read_table, write_table_atomic
from care_maps.fuse.accumulate import COLUMN_CHUNK, CandidateSums
from care_maps.fuse.build import update_config
from care_maps.fuse.config import GridConfig
from care_maps.fuse.frame import store_stamp
from care_maps.fuse.keys import STORE_KEY, config_json_key
from care_maps.fuse.measures import MAX_TOP_CLASSES, candidate_metadata
from care_maps.fuse.provenance import check_map_files
from care_maps.fuse.sidecar import SidecarWriter, sidecar_path
from care_maps.fuse.vocabulary import vocabulary_text
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution
from care_maps.runtime.threads import Work, threads_for

__all__ = ["grid_config_of", "recompute_candidates", "recompute_grid", "sums_from_views"]

Columns = Callable[[Store, pa.Table, np.ndarray, float], pa.Table]
"""``(store, map table, (n, d) text embeddings, scale)`` -> the common candidate columns;
with ``log_confidence`` among them, the map's query sidecar is written again from them."""

SAMPLE_FIELDS = ("cell_size", "stride", "z_min", "z_max", "sigma_z", "distance_weighting")
"""The grid settings that shape its per-view samples: a recompute needs each recorded."""


def sums_from_views(
    path: Path,
    id_column: str,
    text: np.ndarray,
    scale: float,
    *,
    num_candidates: int,
    weight_column: str | None = None,
) -> CandidateSums:
    """Per-candidate sums from a per-view table (``weight_column=None``: weights 1).

    ``num_candidates`` fixes the row count, so candidates without any view still get a row.
    """
    read_table(path, [id_column])  # checks presence and schema version
    dim = np.asarray(text).shape[1]
    sums = CandidateSums(dim, text, scale, capacity=max(num_candidates, 1))
    sums.ensure(num_candidates)
    columns = [id_column, "feature", *([weight_column] if weight_column else [])]
    for batch in iter_batches(path, 65536, columns):
        ids = batch.column(id_column).to_numpy()
        flat = batch.column("feature").values.to_numpy(zero_copy_only=False)
        if flat.size != ids.size * dim:
            msg = f"{path}: features of length {flat.size // max(ids.size, 1)}, vocabulary embeddings of {dim}"
            raise FuseError(msg)
        weights = batch.column(weight_column).to_numpy() if weight_column else np.ones(ids.size)
        sums.add(ids, weights, flat.reshape(ids.size, dim))
    return sums


def grid_config_of(cells: pa.Table, where: Path) -> GridConfig:
    """The config a grid's cells table records (``care.grid.config_json``); refused in one
    line when it lacks a setting of the samples (:data:`SAMPLE_FIELDS`)."""
    fields = recorded_fields(GridConfig, (cells.schema.metadata or {}).get(config_json_key("grid")))
    missing = [name for name in SAMPLE_FIELDS if name not in fields]
    if missing:
        msg = (
            f"{where}: the grid does not record the settings it was built with "
            f"({', '.join(missing)}); rebuild it with `care fuse grid {where.parent} --overwrite`"
        )
        raise FuseError(msg)
    return GridConfig(**fields)


def recompute_grid(
    store_path: Path,
    vocabulary: Sequence[str] | None = None,
    logit_scale: float | None = None,
    *,
    run: Execution = DEFAULT_EXECUTION,
) -> Path:
    """Rewrite the candidate columns of ``cells.parquet`` for another vocabulary or scale.

    The grid's own columns (position, colour, obstacle...) are kept; ``None`` keeps the
    current logit scale, and the store's cached names when ``vocabulary`` is None. The
    per-view cell features come from the store's views again (see the module docstring),
    fused as a build with the same ``run`` would be (its ``memory_budget``, or
    ``cells_per_pass``; its read-ahead), on the thread pools of
    :attr:`care_maps.runtime.threads.Work.FUSE` like :func:`fuse.fuse_grid`.
    """
    from care_maps.fuse.grid import CELLS_TABLE, cell_keys, fused_columns

    def columns(store: Store, cells: pa.Table, text: np.ndarray, scale: float) -> pa.Table:
        path = store.table_path(CELLS_TABLE)
        config = grid_config_of(cells, path)
        if (cells.schema.metadata or {}).get(STORE_KEY) != store_stamp(store):
            msg = (
                f"{path}: built from another version of the store (its views or map frame "
                f"changed since); rebuild it with `care fuse grid {store.path} --overwrite`"
            )
            raise FuseError(msg)
        config = replace(config, logit_scale=scale)
        return fused_columns(
            store, config, text, cell_keys(cells), run=run, with_log_confidence=True
        )

    return _recompute(store_path, CELLS_TABLE, "grid", columns, vocabulary, logit_scale)


def recompute_candidates(
    store_path: Path,
    table_name: str,
    views_table: str,
    id_column: str,
    kind: str,
    *,
    weight_column: str | None = None,
    vocabulary: Sequence[str] | None = None,
    logit_scale: float | None = None,
) -> Path:
    """Rewrite the common candidate columns of a map table from its per-view table of
    features (the instance map's ``instance_views.parquet``, :func:`sums_from_views`)."""

    def columns(store: Store, table: pa.Table, text: np.ndarray, scale: float) -> pa.Table:
        # this store's map and its own build's per-view rows, before anything is rewritten
        check_map_files(store, [table_name, views_table], sidecar=False, error=FuseError)
        sums = sums_from_views(
            store.table_path(views_table),
            id_column,
            text,
            scale,
            num_candidates=table.num_rows,
            weight_column=weight_column,
        )
        return sums.columns()

    return _recompute(store_path, table_name, kind, columns, vocabulary, logit_scale)


@threads_for(
    Work.FUSE
)  # the same bytes as a build, whoever calls it (care_maps.fuse.build.build_map)
def _recompute(
    store_path: Path,
    table_name: str,
    kind: str,
    columns: Columns,
    vocabulary: Sequence[str] | None,
    logit_scale: float | None,
) -> Path:
    """Replace the common candidate columns of a map table by ``columns``' for the new
    vocabulary and scale.

    Shared by both maps so a grid and an instance map recompute the same way: the map's
    own columns (geometry, masks) are kept in place, the metadata and the map's config
    (``care.<kind>.config``) record the new vocabulary and scale.
    """
    store = Store(store_path)
    path = store.table_path(table_name)
    table = read_table(path)
    md = dict(table.schema.metadata or {})
    scale = float(md[LOGIT_SCALE_KEY]) if logit_scale is None else float(logit_scale)
    names, text = vocabulary_text(store, vocabulary)
    common = columns(store, table, text, scale)
    new = pa.table(
        {
            n: (common.column(n) if n in common.column_names else table.column(n))
            for n in table.column_names
        }
    )
    md.update(candidate_metadata(names, scale, store.encoder.name))
    update_config(
        md, kind, vocabulary=None if vocabulary is None else list(names), logit_scale=scale
    )
    shutil.rmtree(sidecar_path(path), ignore_errors=True)  # it described the map before
    write_table_atomic(new, path, md)
    if "log_confidence" in common.column_names:
        _write_sidecar(path, common, text, md)
    return path


def _write_sidecar(
    path: Path, common: pa.Table, text: np.ndarray, metadata: dict[bytes, bytes]
) -> None:
    """The query sidecar of the rewritten map table ``path`` (:mod:`care_maps.fuse.sidecar`), as its
    build writes it, so a whole-building query opens the recomputed map as fast as a new
    one. Written after the table: an interrupted recompute leaves a table without a
    sidecar (queries decode the table), never a sidecar of other columns."""
    n, d = text.shape
    writer = SidecarWriter(
        sidecar_path(path), common.num_rows, d, min(n, MAX_TOP_CLASSES), n, metadata
    )
    try:
        for batch in common.to_batches(max_chunksize=COLUMN_CHUNK):
            writer.write(pa.Table.from_batches([batch]))
        writer.commit()
    finally:
        writer.abort()
