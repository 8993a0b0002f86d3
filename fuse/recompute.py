"""Columns for a new vocabulary or logit scale, from the per-view tables alone.

The per-view tables (``cell_views.parquet``, ``instance_views.parquet``) keep every per-view
feature, so the candidate columns can be rebuilt without re-reading the recording: the
same :class:`fuse.accumulate.CandidateSums` as the streaming pass, fed from the table a
record batch at a time.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa

from care.errors import FuseError
from care.store import Store, iter_batches, read_table, write_table_atomic
from care.threads import Work, threads_for
from fuse.accumulate import CandidateSums
from fuse.build import update_config
from fuse.measures import candidate_metadata
from fuse.sidecar import sidecar_path
from fuse.vocabulary import vocabulary_text

__all__ = ["recompute_candidates", "recompute_grid", "sums_from_views"]


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


def recompute_grid(
    store_path: Path, vocabulary: Sequence[str] | None = None, logit_scale: float | None = None
) -> Path:
    """Rewrite the candidate columns of ``cells.parquet`` for another vocabulary or scale.

    The grid's own columns (position, colour, obstacle...) are kept; ``None`` keeps the
    current logit scale, and the store's cached names when ``vocabulary`` is None.
    """
    from fuse.grid import CELL_VIEWS_TABLE, CELLS_TABLE

    return recompute_candidates(
        store_path, CELLS_TABLE, CELL_VIEWS_TABLE, "cell_id", "grid",
        weight_column="weight", vocabulary=vocabulary, logit_scale=logit_scale,
    )  # fmt: skip


@threads_for(Work.FUSE)  # the same bytes as a build, whoever calls it (fuse.build.build_map)
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
    """Rewrite the common candidate columns of a map table from its per-view table.

    Shared by both maps so a grid and an instance map recompute the same way: the map's
    own columns (geometry, masks) are kept in place, the metadata and the map's config
    (``care.<kind>.config``) record the new vocabulary and scale.
    """
    store = Store(store_path)
    path = store.table_path(table_name)
    table = read_table(path)
    md = dict(table.schema.metadata or {})
    scale = float(md[b"care.logit_scale"]) if logit_scale is None else float(logit_scale)
    names, text = vocabulary_text(store, vocabulary)
    sums = sums_from_views(
        store.table_path(views_table),
        id_column,
        text,
        scale,
        num_candidates=table.num_rows,
        weight_column=weight_column,
    )
    common = sums.columns()
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
    return path
