"""A map's candidates as typed arrays, read once from ``cells.parquet`` / ``instances.parquet``.

Queries and replan strategies are array operations over these columns; nothing here touches
the recording again. The record maps one-to-one onto the map-table contract of the fuse stage
(``candidate_id`` row order, ``feature``, ``log_norm``, ``top_classes``, ``entropy``,
``stderr``, ``pwkl``, ``num_views`` plus the grid's ``x, y, z_max`` or the instances'
``center`` and ``point_indices``).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import pyarrow as pa

from care_maps.core.errors import QueryError
from care_maps.core.keys import ENCODER_NAME_KEY, GRID_CELL_SIZE_KEY
from care_maps.core.maps import MapKind
from care_maps.core.store import META_FILE, Store, as_numpy, read_schema, read_table
from care_maps.fuse.provenance import MAIN_TABLES, check_map_files
from care_maps.fuse.schemas import QUERY_COLUMNS, schema_problems
from care_maps.fuse.sidecar import read_sidecar
from care_maps.query.store_text import StoreText

__all__ = [
    "LOG_CONFIDENCE_CACHE",
    "MAP_TABLES",
    "MEASURES",
    "NOT_IN_TOP",
    "REPLAN_COLUMNS",
    "CandidateMap",
    "list_column",
    "load_map",
    "map_from_table",
]


MAP_TABLES: dict[MapKind, str] = MAIN_TABLES
"""Map kind -> table name in the store directory (:data:`care_maps.fuse.provenance.MAIN_TABLES`)."""

MEASURES = ("entropy", "stderr", "pwkl")
"""Per-candidate uncertainty columns the strategies choose by."""

REPLAN_COLUMNS = (*MEASURES, "num_views", "size")
"""Every column a strategy may choose by: the measures and the non-CARe baselines' view
count and mask size (scene points; 0 for grid cells, which all have one size)."""

LOG_CONFIDENCE_CACHE = 1 << 25
"""Most entries (classes x candidates, 128 MiB of float32) of the cached log-confidence table."""

NOT_IN_TOP = np.iinfo(np.int16).max
"""Rank given to a class that is not among a candidate's stored ``top_classes``."""


def list_column(table: pa.Table, name: str, dtype: type = np.float32) -> np.ndarray:
    """A fixed-length ``list<...>`` column as an (N, k) array (k = 0 for an empty table)."""
    col = table.column(name).combine_chunks()
    if len(col) == 0:
        return np.zeros((0, 0), dtype=dtype)
    flat: np.ndarray = as_numpy(_values(col)).astype(dtype, copy=False)
    if flat.size % len(col):
        msg = f"column {name!r}: rows have different lengths; the map table is malformed, rebuild it with `care fuse`"
        raise QueryError(msg)
    return flat.reshape(len(col), -1)


def _values(col: pa.Array) -> pa.Array:
    """The values of a list column's rows, in order: its child array sliced to them.
    ``flatten()`` gives the same, through pyarrow's compute module (0.03 s to import at a
    query's start); it is kept for a column with null rows, which it skips."""
    if col.null_count:
        return col.flatten()
    if pa.types.is_fixed_size_list(col.type):
        size = col.type.list_size
        return col.values.slice(col.offset * size, len(col) * size)
    offsets = as_numpy(col.offsets)
    return col.values.slice(int(offsets[0]), int(offsets[-1] - offsets[0]))


def _ragged(table: pa.Table, name: str) -> tuple[np.ndarray, np.ndarray]:
    """A variable-length ``list<int32>`` column as (offsets (N+1,), values)."""
    col = table.column(name).combine_chunks()
    offsets = as_numpy(col.offsets).astype(np.int64)
    values = as_numpy(col.values).astype(np.int64)
    return offsets - offsets[0], values[offsets[0] : offsets[-1]]


@dataclass(frozen=True, eq=False)
class CandidateMap:
    """N candidates (grid cells or instance masks) with their fused features and measures.

    Confidence of class y for candidate c is ``exp(s * features[c] . text[y] - log_norm[c])``
    (see :func:`care_maps.query.confidence.confidence`).
    """

    kind: MapKind
    vocabulary: tuple[str, ...]
    text: np.ndarray
    """(n, d) float32 L2-normalised text embeddings of the vocabulary, in vocabulary order."""
    logit_scale: float
    features: np.ndarray
    """(N, d) float32 fused features."""
    log_norm: np.ndarray
    """(N,) float32 ``logsumexp_y(s * f . t_y)``."""
    top_classes: np.ndarray
    """(N, K) int16 classes of P_c in descending order, K = min(n, 100)."""
    entropy: np.ndarray
    stderr: np.ndarray
    pwkl: np.ndarray
    num_views: np.ndarray
    positions: np.ndarray
    """(N, 3) float32: instance centre, or cell centre (x, y, z_max)."""
    point_offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    """(N+1,) offsets into :attr:`point_indices` (instances; all zero for the grid)."""
    point_indices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    """Concatenated scene-point indices of every instance mask."""
    encoder_name: str = ""
    cell_size: float | None = None
    text_encoder: Callable[[Sequence[str]], np.ndarray] | None = None
    """The store's own text side for free text (:class:`care_maps.query.store_text.StoreText`, set by
    :func:`load_map`); None for maps built in memory."""
    log_confidence_rows: np.ndarray | None = None
    """(n, N) float32 ``log P_c[y]`` per class, class-major (memory-mapped from the map's
    query sidecar, :mod:`care_maps.fuse.sidecar`); None: computed from the features when needed."""

    def __post_init__(self) -> None:
        n_cand = len(self.features)
        for name in ("log_norm", "entropy", "stderr", "pwkl", "num_views", "positions"):
            if len(getattr(self, name)) != n_cand:
                msg = f"map column {name!r} has {len(getattr(self, name))} rows, features {n_cand}"
                raise QueryError(msg)
        if self.text.shape != (len(self.vocabulary), self.features.shape[1]) and n_cand:
            msg = (
                f"text embeddings of shape {self.text.shape} do not match a vocabulary of "
                f"{len(self.vocabulary)} classes and features of dimension {self.features.shape[1]}"
            )
            raise QueryError(msg)

    @property
    def num_candidates(self) -> int:
        return len(self.features)

    def column(self, name: str) -> np.ndarray:
        """A per-candidate column by name (:data:`REPLAN_COLUMNS`)."""
        if name == "size":
            if len(self.point_offsets) != self.num_candidates + 1:  # grid: cells, no masks
                return np.zeros(self.num_candidates)
            return np.diff(self.point_offsets).astype(np.float64)
        if name not in (*MEASURES, "num_views"):
            msg = f"no measure column {name!r}; choose one of {', '.join(MEASURES)}"
            raise QueryError(msg)
        return getattr(self, name)

    def find_class(self, name: str) -> int | None:
        """Index of a class name in the vocabulary (case-insensitive, first match), or None."""
        return self._class_lookup.get(name.strip().lower())

    def class_id(self, name: str) -> int:
        """Index of a class name in the vocabulary (case-insensitive), or a QueryError."""
        found = self.find_class(name)
        if found is None:
            msg = (
                f"{name!r} is not a class of this map's vocabulary ({len(self.vocabulary)} classes)"
            )
            raise QueryError(msg)
        return found

    @cached_property
    def _class_lookup(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for i, name in enumerate(self.vocabulary):
            out.setdefault(name.strip().lower(), i)
        return out

    def mask(self, candidate: int) -> np.ndarray:
        """Scene-point indices of one instance mask."""
        return self.point_indices[self.point_offsets[candidate] : self.point_offsets[candidate + 1]]

    def subset(self, keep: np.ndarray) -> tuple[CandidateMap, np.ndarray]:
        """The map restricted to candidates ``keep`` (bool mask or ids), renumbered 0..M-1.

        Returns the new map and the original ids of its candidates (for room-by-room maps).
        """
        ids = np.flatnonzero(keep) if np.asarray(keep).dtype == bool else np.asarray(keep)
        starts, ends = self.point_offsets[ids], self.point_offsets[ids + 1]
        lengths = ends - starts
        offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
        pos = np.arange(offsets[-1]) - np.repeat(offsets[:-1], lengths) + np.repeat(starts, lengths)
        sub = CandidateMap(
            kind=self.kind,
            vocabulary=self.vocabulary,
            text=self.text,
            logit_scale=self.logit_scale,
            features=self.features[ids],
            log_norm=self.log_norm[ids],
            top_classes=self.top_classes[ids],
            entropy=self.entropy[ids],
            stderr=self.stderr[ids],
            pwkl=self.pwkl[ids],
            num_views=self.num_views[ids],
            positions=self.positions[ids],
            point_offsets=offsets
            if self.kind == MapKind.INSTANCES
            else np.zeros(len(ids) + 1, np.int64),
            point_indices=self.point_indices[pos.astype(np.int64)],
            encoder_name=self.encoder_name,
            cell_size=self.cell_size,
            log_confidence_rows=None
            if self.log_confidence_rows is None
            else self.log_confidence_rows[:, ids],
        )
        return sub, ids

    @cached_property
    def log_confidence_table(self) -> np.ndarray | None:
        """(n, N) float32 ``s * t_y . f_c - log_norm_c`` for every class, or None when that
        would exceed :data:`LOG_CONFIDENCE_CACHE` entries (then each query multiplies).

        Built at first use: a fixed vocabulary makes every query a row gather afterwards.
        """
        n_cls, n_cand = len(self.vocabulary), self.num_candidates
        if self.log_confidence_rows is not None:
            return self.log_confidence_rows
        if n_cls * n_cand > LOG_CONFIDENCE_CACHE or n_cand == 0:
            return None
        return self.log_confidence_of(np.arange(n_cls))

    def log_confidence_of(self, class_ids: np.ndarray) -> np.ndarray:
        """(U, N) float32 ``log P_c[y]`` for the given classes.

        From the sidecar when the map has one (a row read; exact near 1, see
        :func:`care_maps.fuse.measures.log_confidence`), else computed from the columns, capped at 0:
        float32 logits at CLIP's scale of 100 carry ~1e-5 of rounding, so a sure candidate
        would read 1.00002 (the cap never changes a ranking but the tie at 1).
        """
        class_ids = np.asarray(class_ids, dtype=np.int64)
        if self.log_confidence_rows is not None:
            return np.array(self.log_confidence_rows[class_ids], dtype=np.float32)
        weights = self.text[class_ids] * np.float32(self.logit_scale)
        out = np.empty((len(class_ids), self.num_candidates), np.float32)
        step = 1 << 16  # features may be float16 (memory-mapped): converted a block at a time
        for lo in range(0, self.num_candidates, step):
            block = np.asarray(self.features[lo : lo + step], dtype=np.float32)
            out[:, lo : lo + step] = weights @ block.T
        out -= self.log_norm[None, :]
        return np.minimum(out, 0.0, out=out)

    @cached_property
    def _cell_raster(self) -> tuple[np.ndarray, np.ndarray]:
        """Grid maps: (nx, ny) int32 candidate id of every cell (-1 empty) and the (ix, iy)
        of every candidate, from the cell centres: the spatial index of :meth:`near`."""
        cs = float(self.cell_size or 1.0)
        cells = np.rint(self.positions[:, :2].astype(np.float64) / cs - 0.5).astype(np.int64)
        cells -= cells.min(axis=0) if len(cells) else 0
        shape = tuple(int(v) + 1 for v in cells.max(axis=0)) if len(cells) else (0, 0)
        raster = np.full(shape, -1, np.int32)
        raster[cells[:, 0], cells[:, 1]] = np.arange(len(cells), dtype=np.int32)
        return raster, cells

    def near(self, candidate: int, radius: float) -> np.ndarray:
        """Ids of the candidates whose floor-plane centre lies within ``radius`` of
        ``candidate``'s (itself included).

        A grid map looks in the window of cells around it (its spatial index, built once),
        so excluding a failed attempt's surroundings costs the window, not a pass over every
        cell; other maps compare every centre.
        """
        xy = self.positions[:, :2]
        if self.kind != MapKind.GRID or not self.cell_size:
            d2 = ((xy - xy[candidate]) ** 2).sum(-1)
            return np.flatnonzero(d2 <= radius**2)
        raster, cells = self._cell_raster
        reach = int(np.ceil(radius / self.cell_size)) + 1
        cx, cy = cells[candidate]
        window = raster[
            max(cx - reach, 0) : cx + reach + 1, max(cy - reach, 0) : cy + reach + 1
        ].ravel()
        ids = window[window >= 0]
        d2 = ((xy[ids] - xy[candidate]) ** 2).sum(-1)
        return np.sort(ids[d2 <= radius**2])

    @cached_property
    def _rank_index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """Every (class, candidate) pair of ``top_classes`` sorted by class, then rank:
        ``(starts (n*K+1,), candidate, rank, K)``. One sort at first use; afterwards the
        candidates ranking class y below k are the slice ``starts[y*K] : starts[y*K + k]``."""
        n_top = self.top_classes.shape[1] if self.top_classes.ndim == 2 else 0
        n_cls = len(self.vocabulary)
        if n_top == 0:
            empty = np.zeros(0, np.int64)
            return np.zeros(n_cls + 1, np.int64), empty, empty, 0
        ranks = np.broadcast_to(np.arange(n_top), self.top_classes.shape)
        key = (self.top_classes.astype(np.int64) * n_top + ranks).reshape(-1)
        order = np.argsort(key, kind="stable")
        starts = np.searchsorted(key[order], np.arange(n_cls * n_top + 1))
        return starts, order // n_top, order % n_top, n_top

    def class_rank(self, class_ids: np.ndarray, limit: int | None = None) -> np.ndarray:
        """(Q, N) int16 position of class ``class_ids[q]`` in each candidate's top classes
        (0 = the candidate's top class), :data:`NOT_IN_TOP` where it is not stored or, with
        ``limit``, not below ``limit`` (cheaper: only ranks < limit are written).

        ``rank < k`` is the top-k category criterion (exact for every k <= limit).
        """
        class_ids = np.atleast_1d(np.asarray(class_ids, dtype=np.int64))
        starts, cand, rank, n_top = self._rank_index
        out = np.full((len(class_ids), self.num_candidates), NOT_IN_TOP, dtype=np.int16)
        if n_top == 0:
            return out
        depth = n_top if limit is None else max(0, min(int(limit), n_top))
        lo = starts[class_ids * n_top]
        lengths = starts[class_ids * n_top + depth] - lo
        rows = np.repeat(np.arange(len(class_ids)), lengths)
        pos = np.arange(lengths.sum()) + np.repeat(lo - (np.cumsum(lengths) - lengths), lengths)
        out[rows, cand[pos]] = rank[pos]
        return out


def _meta(table: pa.Table, key: str, path: Path) -> str:
    md = table.schema.metadata or {}
    value = md.get(key.encode())
    if value is None:
        msg = f"{path}: table metadata lacks {key}; rebuild the map with `care fuse`"
        raise QueryError(msg)
    return value.decode()


def map_from_table(
    table: pa.Table,
    text: np.ndarray,
    kind: MapKind,
    *,
    path: Path | None = None,
    sidecar: dict[str, np.ndarray] | None = None,
) -> CandidateMap:
    """Build a :class:`CandidateMap` from a map table (with its schema metadata) and the
    (n, d) text embeddings of its vocabulary.

    With a ``sidecar`` (:func:`care_maps.fuse.sidecar.read_sidecar`) the features, top classes and
    per-class log-confidence are its memory-mapped arrays and the table needs only the
    other columns."""
    where = path or Path(f"<{kind} table>")
    vocabulary = tuple(json.loads(_meta(table, "care.vocabulary", where)))
    scale = float(_meta(table, "care.logit_scale", where))
    md = table.schema.metadata or {}
    n_cand = table.num_rows
    if sidecar is None:
        features = list_column(table, "feature", np.float32)
        top = list_column(table, "top_classes", np.int16).reshape(n_cand, -1)
    else:
        features, top = sidecar["feature"], sidecar["top_classes"]
    if kind == MapKind.GRID:
        positions = np.stack(
            [as_numpy(table.column(c)).astype(np.float32) for c in ("x", "y", "z_max")], axis=1
        ).reshape(n_cand, 3)
        offsets, indices = np.zeros(n_cand + 1, np.int64), np.zeros(0, np.int64)
        cell = md.get(GRID_CELL_SIZE_KEY)
        cell_size = float(cell) if cell is not None else None
    else:
        positions = list_column(table, "center", np.float32).reshape(n_cand, 3)
        offsets, indices = _ragged(table, "point_indices")
        cell_size = None
    ids = as_numpy(table.column("candidate_id"))
    if not np.array_equal(ids, np.arange(n_cand)):
        msg = f"{where}: candidate_id is not 0..N-1 in row order; rebuild the map with `care fuse`"
        raise QueryError(msg)
    return CandidateMap(
        kind=kind,
        vocabulary=vocabulary,
        text=np.asarray(text, dtype=np.float32).reshape(len(vocabulary), -1),
        logit_scale=scale,
        features=features.reshape(n_cand, -1),
        log_norm=as_numpy(table.column("log_norm")).astype(np.float32),
        top_classes=top,
        entropy=as_numpy(table.column("entropy")).astype(np.float32),
        stderr=as_numpy(table.column("stderr")).astype(np.float32),
        pwkl=as_numpy(table.column("pwkl")).astype(np.float32),
        num_views=as_numpy(table.column("num_views")).astype(np.int32),
        positions=positions,
        point_offsets=offsets,
        point_indices=indices,
        encoder_name=(md.get(ENCODER_NAME_KEY) or b"").decode(),
        cell_size=cell_size,
        log_confidence_rows=None if sidecar is None else sidecar["log_confidence"],
    )


def _vocabulary_text(
    store: Path, vocabulary: tuple[str, ...], weights: Path | None = None
) -> np.ndarray:
    """The text embeddings of the map's vocabulary, in its order: the store's cache, and for
    names a ``care fuse --recompute --vocabulary`` added, the store's own model, exactly as
    the fusion embedded them (:func:`care_maps.fuse.vocabulary.vocabulary_text`)."""
    table = read_table(store / "text.parquet")
    names = table.column("name").to_pylist()
    index = {name: i for i, name in enumerate(names)}
    missing = [name for name in vocabulary if name not in index]
    if not missing:  # the usual case: no store model to load
        emb = list_column(table, "embedding", np.float32)
        return emb[[index[name] for name in vocabulary]]
    from care_maps.core.errors import CareError
    from care_maps.core.store import Store
    from care_maps.fuse.vocabulary import vocabulary_text

    try:
        return vocabulary_text(Store(store), vocabulary, weights=weights)[1]
    except CareError as err:
        msg = (
            f"{store / 'text.parquet'}: no text embedding for {len(missing)} classes of the map "
            f"(e.g. {missing[0]!r}) and the store's model cannot embed them ({err}); re-run "
            "`care fuse` with the store's vocabulary"
        )
        raise QueryError(msg) from err


def load_map(
    store: Path, kind: MapKind | str = MapKind.INSTANCES, *, weights: Path | None = None
) -> CandidateMap:
    """Read a store's ``instances.parquet`` or ``cells.parquet`` (and ``text.parquet``).

    A map with a current query sidecar (:mod:`care_maps.fuse.sidecar`) opens in milliseconds at a
    million cells: only the narrow columns are decoded, the rest is memory-mapped. Free text
    is embedded by the store's own model (``weights`` if its weights directory moved), loaded
    at the first free-text query. A map table of another store or map frame, or a sidecar of
    another map, is refused in one line naming it (:mod:`care_maps.fuse.provenance`), never read.
    """
    store = Path(store)
    if kind not in MAP_TABLES:
        msg = f"unknown map kind {kind!r}; choose one of {', '.join(MAP_TABLES)}"
        raise QueryError(msg)
    kind = MapKind(kind)  # a known name as its member (CandidateMap.kind is one)
    path = store / f"{MAP_TABLES[kind]}.parquet"
    if (store / META_FILE).is_file():  # a store's map: built from this store, as it is
        check_map_files(Store(store), [MAP_TABLES[kind]])
    schema = read_schema(path)
    problem = schema_problems(schema, kind, path, columns=QUERY_COLUMNS[kind])
    if problem is not None:
        msg = f"{problem}; rebuild it with `care fuse {kind} {store} --overwrite`"
        raise QueryError(msg)
    sidecar = read_sidecar(path, schema.metadata or {})
    # with a sidecar the wide columns stay on disk, memory-mapped (care_maps.fuse.sidecar)
    wide = ("feature", "top_classes", "top_probs")
    columns = None if sidecar is None else [n for n in schema.names if n not in wide]
    table = read_table(path, columns)
    vocabulary = tuple(json.loads(_meta(table, "care.vocabulary", path)))
    text = _vocabulary_text(store, vocabulary, weights)
    cmap = map_from_table(table, text, kind, path=path, sidecar=sidecar)
    return dataclasses.replace(cmap, text_encoder=StoreText(store, weights))
