"""The VLMaps-style grid map: dense features fused into occupied top-down cells, streaming.

One pass over the store's views: each view becomes its (view, cell) samples
(:func:`care_maps.fuse.cells.view_samples`), which are listed in ``cell_views.parquet`` and merged
into per-cell streaming statistics (:class:`care_maps.fuse.accumulate.CandidateSums`, 5.7 KB a cell
at d = 512, n = 100). Memory grows with the occupied cells, never with the number of views,
and is capped by the run's ``Execution.memory_budget``: cells beyond what the budget holds
are fused in further passes over only the views that see them (:func:`build_grid`). At the
end the store gets:

- ``cells.parquet``: the common candidate columns (``care_maps.fuse.measures.candidate_columns``) plus
  ``ix, iy`` (int32, from the grid origin), ``x, y`` (cell centre, metres), ``z_max``
  (highest fused point), ``weight`` (W1), and the layers of the top-down maps: ``r, g, b``
  (colour of the highest point, as VLMaps' top-down colour map), ``obstacle`` (``z_max`` above
  ``obstacle_height``: something stands in the cell) and ``num_pixels``. Metadata:
  ``care.grid.cell_size``, ``care.grid.origin`` ([x, y] of the corner of cell (0, 0)),
  ``care.grid.shape`` ([nx, ny]), ``care.grid.config``.
- ``cells.query/``: the query sidecar (:mod:`care_maps.fuse.sidecar`), memory-mapped by
  :func:`care_maps.query.map.load_map`: per-class log-confidence, features and top classes.
- ``cell_views.parquet``: every (cell_id, view_id, weight, num_pixels) sample
  (:data:`care_maps.fuse.schemas.CELL_VIEWS_FIELDS`): which views saw a cell, with what weight and
  how many pixels. It holds no copy of the samples' features (a copy cost more to write
  than the fusion itself, and a megabyte or more a view): they are a function of the store
  and the config, so a recompute for another vocabulary or logit scale
  (:func:`care_maps.fuse.recompute.recompute_grid`) derives them again from the store's views through
  the same per-view code as the build (:func:`fused_columns`) and gives the same columns
  as a fresh build, bit for bit.
- ``grid_rgb.png`` and ``grid_obstacles.png``: the same two layers as images for people;
  row 0 is the largest y (north up), column = ix; and the obstacle layer as a ROS
  ``map_server`` occupancy map, ``map.pgm`` + ``map.yaml`` (:mod:`care_maps.fuse.rosmap`).

A finished grid whose config and store match is not rebuilt (the run's ``overwrite`` forces
it). How the build runs (read-ahead, memory budget, progress) is the run's
:class:`care_maps.runtime.execution.Execution`; the map is the same bytes whatever it says.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Iterator
from contextlib import closing, nullcontext
from dataclasses import dataclass
from itertools import zip_longest
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from PIL import Image
from tqdm import tqdm

from care_maps.core.errors import FuseError, StoreError
from care_maps.core.keys import SCHEMA_VERSION_KEY, VOCABULARY_KEY
from care_maps.core.maps import MapKind
from care_maps.core.outputs import damaged, write_atomic
from care_maps.core.store import (
    SCHEMA_VERSION,
    Store,
    append_rows,
    as_numpy,
    iter_batches,
    open_writer,
    read_schema,
    read_table,
    run_records,
)
from care_maps.fuse.accumulate import CandidateSums
from care_maps.fuse.build import MapBuild, MapSpec, build_map
from care_maps.fuse.cells import CellIndex, ViewSamples, pack_cells, unpack_cells, view_samples
from care_maps.fuse.config import GridConfig
from care_maps.fuse.frame import DECODERS, check_height_band
from care_maps.fuse.grid_state import (
    STATE_FILE,
    GridState,
    frame_of,
    load_state,
    save_state,
    store_runs,
)
from care_maps.fuse.keys import STORE_KEY, build_key, config_key
from care_maps.fuse.layout import CELLS_TABLE, GridLayout
from care_maps.fuse.measures import MAX_TOP_CLASSES
from care_maps.fuse.pixels import warm_up
from care_maps.fuse.rosmap import occupancy_image, write_ros_map
from care_maps.fuse.schemas import CELL_VIEWS_FIELDS
from care_maps.fuse.sidecar import SidecarWriter, sidecar_path
from care_maps.runtime.background import in_background
from care_maps.runtime.budget import check_raster
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution
from care_maps.runtime.malloc import resident_bytes
from care_maps.runtime.readahead import read_ahead

__all__ = [
    "CELLS_TABLE",
    "CELL_VIEWS_TABLE",
    "GRID_MAP",
    "GridConfig",
    "GridLayout",
    "build_grid",
    "cell_keys",
    "cell_views_schema",
    "cells_per_pass",
    "default_memory_budget",
    "fused_columns",
    "grid_image",
    "write_grid_images",
]

CELL_VIEWS_TABLE = "cell_views"

VIEWS_GROUP_ROWS = 1 << 20
"""Rows per row group of ``cell_views.parquet`` (16 bytes a row: 16 MiB held at most)."""


def cell_views_schema(metadata: dict[bytes, bytes] | None = None) -> pa.Schema:
    """``cell_views.parquet``: one row per (view, cell) sample, the columns declared in
    :data:`care_maps.fuse.schemas.CELL_VIEWS_FIELDS`, all plain numbers (polars, duckdb). Its
    metadata: the store's stamp and the build's id of the grid's ``metadata`` (what the
    samples belong to, :mod:`care_maps.fuse.provenance`), not the grid's vocabulary or config."""
    own = {k: v for k, v in (metadata or {}).items() if k in (STORE_KEY, build_key(MapKind.GRID))}
    return pa.schema(
        CELL_VIEWS_FIELDS, metadata={SCHEMA_VERSION_KEY: str(SCHEMA_VERSION).encode(), **own}
    )


def grid_image(
    ix: np.ndarray, iy: np.ndarray, values: np.ndarray, shape: tuple[int, int], fill: float = np.nan
) -> np.ndarray:
    """Raster (ny, nx[, c]) of per-cell values; row 0 = largest y, so north is up."""
    values = np.asarray(values)
    nx, ny = shape
    check_raster((ny, nx, *values.shape[1:]), np.result_type(values, type(fill)).itemsize)
    image = np.full((ny, nx, *values.shape[1:]), fill, dtype=np.result_type(values, type(fill)))
    image[ny - 1 - np.asarray(iy), np.asarray(ix)] = values
    return image


class _CellLayers:
    """Per-cell non-feature state: highest point and its colour, pixel count."""

    def __init__(self) -> None:
        self.z_max = np.empty(0, np.float32)
        self.rgb = np.empty((0, 3), np.uint8)
        self.num_pixels = np.empty(0, np.int64)

    @classmethod
    def restored(cls, z_max: np.ndarray, rgb: np.ndarray, num_pixels: np.ndarray) -> _CellLayers:
        """The layers a grid saved (:mod:`care_maps.fuse.grid_state`), to add views to."""
        layers = cls()
        layers.z_max = np.array(z_max, np.float32)
        layers.rgb = np.array(rgb, np.uint8).reshape(-1, 3)
        layers.num_pixels = np.array(num_pixels, np.int64)
        return layers

    def add(self, ids: np.ndarray, samples: ViewSamples) -> None:
        size = int(ids.max()) + 1 if ids.size else 0
        if size > self.z_max.size:
            grow = max(size, 2 * self.z_max.size) - self.z_max.size
            self.z_max = np.concatenate([self.z_max, np.full(grow, -np.inf, np.float32)])
            self.rgb = np.concatenate([self.rgb, np.zeros((grow, 3), np.uint8)])
            self.num_pixels = np.concatenate([self.num_pixels, np.zeros(grow, np.int64)])
        higher = samples.top_z > self.z_max[ids]  # ids are distinct within a view
        self.z_max[ids[higher]] = samples.top_z[higher]
        self.rgb[ids[higher]] = samples.top_rgb[higher]
        self.num_pixels[ids] += samples.num_pixels


class _ViewsWriter:
    """``cell_views.parquet`` written a whole row group (:data:`VIEWS_GROUP_ROWS`) at a
    time, from column buffers allocated once: the groups are the same whatever the views'
    sizes, the pass writes without long stalls, and no per-view table is held from one view
    to the next (small blocks kept alive between the views' temporaries fragmented the
    heap: 180 MiB more peak memory on a 79k-cell floor)."""

    def __init__(self, path: Path, metadata: dict[bytes, bytes]) -> None:
        self._schema = cell_views_schema(metadata)
        self._columns = {
            f.name: np.empty(VIEWS_GROUP_ROWS, f.type.to_pandas_dtype()) for f in self._schema
        }
        self._rows = 0
        self._writer = open_writer(path, self._schema)

    def add(self, view_id: int, ids: np.ndarray, samples: ViewSamples) -> None:
        """One row per sample of the view (``ids``: the samples' cells)."""
        self._put(
            {
                "view_id": np.full(ids.size, view_id, np.int32),
                "cell_id": ids,
                "weight": samples.weight,
                "num_pixels": samples.num_pixels,
            }
        )

    def copy(self, path: Path) -> None:
        """Every row of the ``cell_views.parquet`` at ``path`` (a grid's earlier views, to
        which more are added): the rows, and so the row groups, a build from every view
        writes."""
        for batch in iter_batches(path, VIEWS_GROUP_ROWS):
            self._put({name: as_numpy(batch.column(name)) for name in self._columns})

    def _put(self, values: dict[str, np.ndarray]) -> None:
        size = len(values["cell_id"])
        done = 0
        while done < size:
            take = min(size - done, VIEWS_GROUP_ROWS - self._rows)
            rows = slice(self._rows, self._rows + take)
            for name, column in self._columns.items():
                column[rows] = values[name][done : done + take]
            self._rows += take
            done += take
            if self._rows == VIEWS_GROUP_ROWS:
                self._flush()

    def _flush(self) -> None:
        if self._rows:
            columns = {name: c[: self._rows] for name, c in self._columns.items()}
            table = pa.table(columns, schema=self._schema)
            self._writer.write_table(table, row_group_size=VIEWS_GROUP_ROWS)
            self._rows = 0

    def __enter__(self) -> _ViewsWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            if exc[0] is None:
                self._flush()
        finally:
            self._writer.close()


@dataclass
class _Growth:
    """Where a grid that grows starts from: its saved cells and layers, its samples' table,
    and the views to add."""

    index: CellIndex
    layers: _CellLayers
    cell_views: Path
    views: set[int]


@dataclass
class _FirstPass:
    """What the streaming pass leaves: every cell indexed, the layers, and the views that a
    later pass must read again (cells beyond the first pass's ``capacity``)."""

    index: CellIndex
    layers: _CellLayers | None
    """None when not gathered (a recompute keeps the map's own columns)."""
    later: dict[int, list[int]]
    """Pass number (>= 1) -> views with samples in that pass's cells, in view order."""
    sums: CandidateSums | None
    """The first pass's state; :func:`_cell_columns` takes it (and drops it after use)."""


def _samples(config: GridConfig, frame, feature_map: np.ndarray, text: np.ndarray) -> ViewSamples:
    return view_samples(
        frame,
        feature_map,
        cell_size=config.cell_size,
        stride=config.stride,
        z_min=config.z_min,
        z_max=config.z_max,
        sigma_z=config.sigma_z if config.distance_weighting else None,
        text=text,
    )


def _views(store: Store, config: GridConfig, wanted: set[int] | None = None):
    """``(view_id, frame, feature map)`` in view order (only ``wanted`` ones when given)."""
    # a store with fewer feature rows than views (or more) is out of step, not a smaller map
    pairs = zip_longest(
        store.iter_frames(extras=False, view_ids=wanted),
        store.iter_features(view_ids=wanted),
        fillvalue=(None, None),
    )
    for (view_id, frame), (feature_id, feature_map) in pairs:
        if view_id != feature_id:
            msg = f"{store.path}: views and features out of step ({view_id} vs {feature_id}); re-run `care ingest`"
            raise FuseError(msg)
        yield view_id, frame, feature_map


def _view_samples(
    store: Store,
    config: GridConfig,
    run: Execution,
    text: np.ndarray,
    wanted: set[int] | None = None,
    desc: str = "fuse grid",
) -> Iterator[tuple[int, ViewSamples]]:
    """``(view_id, samples)`` of the store's views in view order (only ``wanted`` ones).

    A view's samples depend on that view alone, so they are made ahead of the merge, which
    must take views in order: with ``run.read_ahead`` > 0 one background thread decodes
    the store and another computes each view's samples, each up to ``read_ahead`` views
    ahead (:mod:`care_maps.runtime.readahead`), while the caller merges. The three overlap on a
    machine's cores (the per-view work releases the GIL in its array code); the views, and
    so the map, are the same bytes either way.
    """
    ahead = run.read_ahead
    decoded = read_ahead(_views(store, config, wanted), ahead)

    def sample() -> Iterator[tuple[int, ViewSamples]]:
        with closing(decoded):  # the decoding thread ends with this stage
            for view_id, frame, feature_map in decoded:
                yield view_id, _samples(config, frame, feature_map, text)

    total = store.num_views if wanted is None else len(wanted)
    with closing(read_ahead(sample(), ahead)) as samples:  # ended here, even on an error
        yield from tqdm(
            samples, total=total, desc=desc, unit="view", leave=False, disable=not run.progress
        )


def _known_cells(store: Store, index: CellIndex, keys: np.ndarray) -> np.ndarray:
    """Ids of a view's cells in a finished map's ``index``; one that is not there means the
    store or the config is not the map's (a recompute checks both first)."""
    ids = index.find(keys)
    if (ids < 0).any():
        msg = (
            f"{store.path}: a view has samples in cells the grid does not have; it was built "
            f"from other views or settings: rebuild it with `care fuse grid {store.path} --overwrite`"
        )
        raise FuseError(msg)
    return ids


def _fuse_views(
    store: Store,
    config: GridConfig,
    run: Execution,
    sums: CandidateSums,
    capacity: int,
    *,
    views_path: Path | None = None,
    views_metadata: dict[bytes, bytes] | None = None,
    index: CellIndex | None = None,
    grow: _Growth | None = None,
) -> _FirstPass:
    """The streaming pass: every view's samples, those of cells ``0..capacity-1`` into
    ``sums``. Without an ``index`` (a build) cells are indexed in order of first appearance,
    the layers gathered and every sample listed in ``views_path``; with one (a recompute:
    the map's cells) every sample's cell must be in it. ``grow``: a build that continues a
    grid's saved state (its index and layers, ``sums`` restored) with the views after it,
    its samples listed after the earlier ones."""
    text = sums.text
    build = index is None
    index = CellIndex() if index is None else index
    layers = _CellLayers() if build else None
    wanted = None
    if grow is not None:
        index, layers, wanted = grow.index, grow.layers, grow.views
    later: dict[int, list[int]] = {}
    views = None if views_path is None else _ViewsWriter(views_path, views_metadata or {})
    with nullcontext() if views is None else views as writer:
        if writer is not None and grow is not None:
            writer.copy(grow.cell_views)
        for view_id, samples in _view_samples(store, config, run, text, wanted):
            ids = index.lookup(samples.keys) if build else _known_cells(store, index, samples.keys)
            if ids.size and ids.max() >= capacity:
                keep = np.flatnonzero(ids < capacity)
                for p in np.unique(ids[ids >= capacity] // capacity):
                    later.setdefault(int(p), []).append(view_id)
                first = samples.take(keep)
                sums.add(ids[keep], first.weight, first.feature, first.dots)
            else:
                sums.add(ids, samples.weight, samples.feature, samples.dots)
            if layers is not None:
                layers.add(ids, samples)
            if writer is not None:
                writer.add(view_id, ids, samples)
    return _FirstPass(index, layers, later, sums)


def _fuse_pass(
    store: Store,
    config: GridConfig,
    run: Execution,
    sums: CandidateSums,
    index: CellIndex,
    first_id: int,
    views: list[int],
) -> None:
    """A later pass of bounded-memory fusion: the samples of cells ``first_id..`` (as many
    as ``sums`` holds) from the views that see them, in view order as the first pass."""
    last = first_id + sums.size
    desc = f"fuse grid (cells {first_id}+)"
    for _, samples in _view_samples(store, config, run, sums.text, set(views), desc):
        ids = index.find(samples.keys)
        keep = np.flatnonzero((ids >= first_id) & (ids < last))
        part = samples.take(keep)
        sums.add(ids[keep] - first_id, part.weight, part.feature, part.dots)


def _cell_columns(
    store: Store,
    config: GridConfig,
    run: Execution,
    first: _FirstPass,
    capacity: int,
    *,
    with_log_confidence: bool = False,
) -> Iterator[tuple[pa.Table, np.ndarray]]:
    """The common candidate columns of every cell of ``first.index``, chunk by chunk in id
    order, with each chunk's summed weights: the first pass's cells from ``first.sums``
    (taken: the only reference, each pass's state is freed), then each later pass's, fused
    from the views that see them."""
    n_cells = first.index.size
    sums, first.sums = first.sums, None
    assert sums is not None
    text, scale = sums.text, sums.scale
    for p, first_id in enumerate(range(0, n_cells, capacity)):
        size = min(capacity, n_cells - first_id)
        if p > 0:
            del sums  # the previous pass's state goes before the next one's is allocated
            sums = CandidateSums(text.shape[1], text, scale, capacity=size, limit=size)
        sums.ensure(size)  # the pass's cells (one no sample reached still gets its row)
        if p > 0:
            _fuse_pass(store, config, run, sums, first.index, first_id, first.later.get(p, []))
        weight = sums.weight
        # the next chunk's columns are made on a background thread while the caller writes
        # this one (Parquet and the sidecar release the GIL); ended with the pass, so a stop
        # waits for one chunk at most and the pass's state goes before the next is allocated
        columns = sums.iter_columns(first_id=first_id, with_log_confidence=with_log_confidence)
        with closing(read_ahead(columns, min(run.read_ahead, 1))) as chunks:
            for chunk in chunks:
                lo = chunk.column("candidate_id")[0].as_py() - first_id
                yield chunk, weight[lo : lo + chunk.num_rows]


def _layout(index: CellIndex, cell_size: float) -> tuple[GridLayout, np.ndarray, np.ndarray]:
    """The layout of the occupied cells and every cell's (ix, iy) from the grid origin."""
    ix, iy = unpack_cells(index.keys_by_id())
    lo = (int(ix.min()), int(iy.min()))
    layout = GridLayout(
        cell_size,
        (round(lo[0] * cell_size, 9), round(lo[1] * cell_size, 9)),
        (int(ix.max()) - lo[0] + 1, int(iy.max()) - lo[1] + 1),
    )
    return layout, ix - lo[0], iy - lo[1]


def _cells_chunk(
    columns: pa.Table,
    rows: slice,
    grid_ix: np.ndarray,
    grid_iy: np.ndarray,
    layout: GridLayout,
    layers: _CellLayers,
    config: GridConfig,
    weight: np.ndarray,
) -> pa.Table:
    """The common columns of cells ``rows`` plus the grid's own."""
    cs = config.cell_size
    ix, iy = grid_ix[rows], grid_iy[rows]
    ox, oy = round(layout.origin[0] / cs), round(layout.origin[1] / cs)
    z_max = layers.z_max[rows]
    grid_columns = {
        "ix": pa.array(ix.astype(np.int32)),
        "iy": pa.array(iy.astype(np.int32)),
        "x": pa.array(((ix + ox + 0.5) * cs).astype(np.float32)),
        "y": pa.array(((iy + oy + 0.5) * cs).astype(np.float32)),
        "z_max": pa.array(z_max),
        "weight": pa.array(weight.astype(np.float32)),
        "r": pa.array(layers.rgb[rows, 0]),
        "g": pa.array(layers.rgb[rows, 1]),
        "b": pa.array(layers.rgb[rows, 2]),
        "obstacle": pa.array(z_max > config.obstacle_height),
        "num_pixels": pa.array(layers.num_pixels[rows].astype(np.int32)),
    }
    for name, col in grid_columns.items():
        columns = columns.append_column(name, col)
    return columns


def _write_png(image: np.ndarray, path: Path) -> None:
    write_atomic(path, lambda tmp: Image.fromarray(image).save(tmp, format="PNG"))


def write_grid_images(store: Store, cells: pa.Table) -> None:
    """``grid_rgb.png`` (colour of the highest point; black = empty), ``grid_obstacles.png``
    and the ROS occupancy map ``map.pgm`` + ``map.yaml`` (:mod:`care_maps.fuse.rosmap`)."""
    layout = GridLayout.from_table(cells)
    ix, iy = cells.column("ix").to_numpy(), cells.column("iy").to_numpy()
    rgb = np.stack([cells.column(c).to_numpy() for c in "rgb"], axis=1)
    _write_png(
        grid_image(ix, iy, rgb, layout.shape, fill=0).astype(np.uint8), store.path / "grid_rgb.png"
    )
    occ = np.where(cells.column("obstacle").to_numpy(zero_copy_only=False), 0, 255).astype(np.uint8)
    _write_png(
        grid_image(ix, iy, occ, layout.shape, fill=128).astype(np.uint8),
        store.path / "grid_obstacles.png",
    )
    obstacle = cells.column("obstacle").to_numpy(zero_copy_only=False)
    write_ros_map(
        occupancy_image(ix, iy, obstacle, layout.shape), layout.cell_size, layout.origin, store.path
    )


def default_memory_budget() -> int:
    """Bytes a grid fusion may use when not told: half of this machine's memory."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") // 2
    except (ValueError, OSError, AttributeError):
        return 8 << 30


FIXED_MEMORY = 1536 << 20
"""Bytes of a budget kept for everything but the per-cell state: the program, a view's
temporaries and the views in flight in the pipeline (``2 read_ahead + 2`` of them, 10 by
default, 30 MB each at most in the benchmark's 14 m room), the cell_views writer's buffers, one chunk of
map columns, the cell index."""


def cells_per_pass(run: Execution, dim: int, num_classes: int) -> int:
    """Cells whose streaming state fits the run's memory budget beside what is already
    resident.

    ``run.cells_per_pass`` wins when set; otherwise ``(budget - resident - FIXED_MEMORY)``
    over the state of a cell (:meth:`CandidateSums.bytes_per_candidate`, plus its index and
    layer entries). A floor whose cells all fit is fused in one pass, exactly as without a
    budget.
    """
    if run.cells_per_pass is not None:
        return run.cells_per_pass
    budget = run.memory_budget or default_memory_budget()
    free = budget - resident_bytes() - FIXED_MEMORY
    per_cell = CandidateSums.bytes_per_candidate(dim, num_classes) + 64
    if free < 1024 * per_cell:
        msg = (
            f"a memory budget of {budget / 2**30:.2f} GiB leaves room for fewer than 1024 cells "
            f"(this process already holds {resident_bytes() / 2**30:.2f} GiB); raise --memory-budget"
        )
        raise FuseError(msg)
    return int(free // per_cell)


def _write_cells(
    store: Store,
    config: GridConfig,
    run: Execution,
    text: np.ndarray,
    first: _FirstPass,
    capacity: int,
    path: Path,
    metadata: dict[bytes, bytes],
    final: Path,
) -> None:
    """Write ``cells.parquet`` (to ``path``, later renamed to ``final``) chunk by chunk in
    id order, and its query sidecar (:mod:`care_maps.fuse.sidecar`) beside ``final``, from
    :func:`_cell_columns`."""
    layout, grid_ix, grid_iy = _layout(first.index, config.cell_size)
    check_raster((layout.shape[1], layout.shape[0], 3), 1, config.cell_size)  # the images
    metadata = {**metadata, **layout.metadata()}
    n_cells = first.index.size
    layers = first.layers
    assert layers is not None  # a build's first pass gathers them
    _keep_state(store, metadata, text, first, keep=run.growth_state and n_cells <= capacity)
    writer: pq.ParquetWriter | None = None
    n_top = min(len(text), MAX_TOP_CLASSES)
    sidecar = SidecarWriter(sidecar_path(final), n_cells, text.shape[1], n_top, len(text), metadata)
    try:
        for chunk, weight in _cell_columns(
            store, config, run, first, capacity, with_log_confidence=True
        ):
            sidecar.write(chunk)
            if "log_confidence" in chunk.column_names:
                chunk = chunk.drop_columns(["log_confidence"])
            lo = chunk.column("candidate_id")[0].as_py()
            rows = slice(lo, lo + chunk.num_rows)
            table = _cells_chunk(chunk, rows, grid_ix, grid_iy, layout, layers, config, weight)
            if writer is None:
                md = {**(table.schema.metadata or {}), **metadata}
                md[SCHEMA_VERSION_KEY] = str(SCHEMA_VERSION).encode()
                writer = open_writer(path, table.schema.with_metadata(md))
            append_rows(writer, table.replace_schema_metadata(writer.schema.metadata))
        sidecar.commit()
    finally:
        sidecar.abort()
        if writer is not None:
            writer.close()


def _state_config(metadata: dict[bytes, bytes], text: np.ndarray) -> bytes:
    """What a grid's state depends on beside its views: the config, the vocabulary, and its
    text embeddings (the names alone do not pin them: a name the store does not cache is
    embedded at fuse time, by whichever weights and threads the build has)."""
    digest = hashlib.sha256(np.ascontiguousarray(text, np.float32).tobytes()).hexdigest()
    return b"|".join(
        (metadata[config_key(MapKind.GRID)], metadata.get(VOCABULARY_KEY, b""), digest.encode())
    )


def _keep_state(
    store: Store, metadata: dict[bytes, bytes], text: np.ndarray, first: _FirstPass, *, keep: bool
) -> None:
    """Save the cells' streaming state beside the grid being written, so later views grow
    it (:mod:`care_maps.fuse.grid_state`); ``keep``: asked for (``Execution.growth_state``)
    and it all fitted one pass. Else any earlier state goes: it belongs to another build."""
    path = store.path / STATE_FILE
    if not keep or first.sums is None or first.layers is None:
        path.unlink(missing_ok=True)
        return
    n = first.index.size
    first.sums.ensure(n)  # a cell no sample reached still has its row
    save_state(
        path,
        GridState(
            build=metadata[build_key(MapKind.GRID)],
            config=_state_config(metadata, text),
            runs=store_runs(store),
            num_views=store.num_views,
            frame=frame_of(metadata[STORE_KEY]),
            keys=first.index.keys_by_id(),
            sums=first.sums.state(),
            z_max=first.layers.z_max[:n],
            rgb=first.layers.rgb[:n],
            num_pixels=first.layers.num_pixels[:n],
        ),
    )


def _growth(build: MapBuild, run: Execution, capacity: int) -> tuple[_Growth, GridState] | None:
    """Where this build can start from a grid of the store's earlier views instead of from
    nothing: its state saved for this config, vocabulary and map frame, beside the map it
    belongs to, from runs the store's begin with (runs appended since); None otherwise (a
    rebuild from every view, always right)."""
    store = build.store
    state = None if run.overwrite else load_state(store.path / STATE_FILE)
    if state is None or state.keys.size > capacity:
        return None
    tables = [store.table_path(CELLS_TABLE), store.table_path(CELL_VIEWS_TABLE)]
    if not all(p.is_file() for p in tables) or damaged(store.path, [p.name for p in tables]):
        return None  # a damaged map is rebuilt from every view
    key = build_key(MapKind.GRID)
    try:
        if any((read_schema(p).metadata or {}).get(key) != state.build for p in tables):
            return None
    except StoreError:  # a table no reader takes: rebuilt
        return None
    if state.config != _state_config(build.metadata, build.text):
        return None
    if state.frame != frame_of(build.metadata[STORE_KEY]):
        return None
    runs, records = store_runs(store), run_records(store.meta)
    done = len(state.runs)
    if (
        len(runs) <= done
        or runs[:done] != state.runs
        or records[done].first_view != state.num_views
    ):
        return None
    growth = _Growth(
        CellIndex.from_keys(state.keys),
        _CellLayers.restored(state.z_max, state.rgb, state.num_pixels),
        tables[1],
        set(range(state.num_views, store.num_views)),
    )
    return growth, state


GRID_MAP = MapSpec(MapKind.GRID, (CELL_VIEWS_TABLE, CELLS_TABLE))
"""The grid's tables (the per-view samples first: a current ``cells.parquet`` implies them)."""


def build_grid(
    store_path: Path, config: GridConfig | None = None, *, run: Execution = DEFAULT_EXECUTION
) -> Path:
    """Fuse the store's views into ``cells.parquet`` (and siblings); returns its path.

    ``config`` is what the map is made from; ``run`` how the build runs (read-ahead,
    memory, rebuilding a current map, progress). Memory follows ``run.memory_budget``,
    not the floor area: the streaming pass keeps
    the state of the first :func:`cells_per_pass` cells (ids in order of first appearance)
    and notes which views see the others; each further block of cells is then fused in a
    pass over just those views. Every cell gets the same samples in the same view order
    either way, so the map is the same whatever the budget (``tests/fuse/test_grid.py``).
    The up-to-date check and the staged commit are the skeleton's (:mod:`care_maps.fuse.build`).
    Logging the map to Rerun is the caller's (:func:`care_maps.fuse.viz_grid.log_grid`).
    """
    config = config or GridConfig()
    return build_map(
        store_path,
        GRID_MAP,
        config,
        lambda build: _fuse_grid(build, config, run),
        run=run,
        after=lambda store: write_grid_images(
            store,
            read_table(store.table_path(CELLS_TABLE), ["ix", "iy", "r", "g", "b", "obstacle"]),
        ),
    )


def _fuse_grid(build: MapBuild, config: GridConfig, run: Execution) -> None:
    """Stage ``cell_views`` and ``cells`` (and commit the query sidecar) of a new grid."""
    store, text = build.store, build.text
    if run.read_ahead > 0:  # else everything in this thread (the kernels load on first use)
        # the kernels load on their own thread while the check decodes its sample (not
        # awaited: a kernel's first call waits for its loading, under numba's lock)
        in_background(warm_up, "care-kernels")
    decoders = DECODERS if run.read_ahead > 0 else 1
    check_height_band(store, config.z_min, config.z_max, decoders)  # before any work
    dim = store.encoder.dim
    capacity = cells_per_pass(run, dim, len(text))
    # runs appended since the grid was built: its saved state takes the new views alone
    grows = _growth(build, run, capacity)
    if grows is None:
        sums = CandidateSums(dim, text, config.logit_scale, limit=capacity)
    else:
        sums = CandidateSums.restored(text, config.logit_scale, grows[1].sums, limit=capacity)
    views = build.staged.path(CELL_VIEWS_TABLE)
    first = _fuse_views(
        store,
        config,
        run,
        sums,
        capacity,
        views_path=views,
        views_metadata=build.metadata,
        grow=None if grows is None else grows[0],
    )
    del sums  # first.sums holds it, until _cell_columns lets it go
    if first.index.size == 0:
        msg = (
            f"{store.path}: no depth pixel fell between z_min={config.z_min} and "
            f"z_max={config.z_max} m; check the poses or widen the band"
        )
        raise FuseError(msg)
    cells = build.staged.path(CELLS_TABLE)
    final = store.table_path(CELLS_TABLE)
    _write_cells(store, config, run, text, first, capacity, cells, build.metadata, final)


def cell_keys(cells: pa.Table) -> np.ndarray:
    """(N,) packed key (:func:`care_maps.fuse.cells.pack_cells`) of each row of a grid's cells table:
    its ``ix, iy`` from the grid origin in its metadata (:class:`GridLayout`)."""
    layout = GridLayout.from_table(cells)
    ox = round(layout.origin[0] / layout.cell_size)
    oy = round(layout.origin[1] / layout.cell_size)
    ix = cells.column("ix").to_numpy().astype(np.int64) + ox
    iy = cells.column("iy").to_numpy().astype(np.int64) + oy
    return pack_cells(ix, iy)


def fused_columns(
    store: Store,
    config: GridConfig,
    text: np.ndarray,
    keys: np.ndarray,
    *,
    run: Execution = DEFAULT_EXECUTION,
    with_log_confidence: bool = False,
) -> pa.Table:
    """The common candidate columns of the cells ``keys`` (packed, row i = candidate i) for
    the vocabulary embeddings ``text`` at ``config.logit_scale``: the store's views streamed
    through the build's own per-view code and passes (:func:`_fuse_views`,
    :func:`_cell_columns`, under ``run``'s memory budget), so a grid built with ``config`` has these
    columns bit for bit (and, ``with_log_confidence``, its query sidecar's log-confidence
    column). Every view's cells must be among ``keys`` (the map's own store and config)."""
    capacity = cells_per_pass(run, store.encoder.dim, len(text))
    sums = CandidateSums(store.encoder.dim, text, config.logit_scale, limit=capacity)
    first = _fuse_views(store, config, run, sums, capacity, index=CellIndex.from_keys(keys))
    del sums  # first.sums holds it, until _cell_columns lets it go
    chunks = [
        chunk
        for chunk, _ in _cell_columns(
            store, config, run, first, capacity, with_log_confidence=with_log_confidence
        )
    ]
    if not chunks:  # no cells: the empty columns
        return CandidateSums(store.encoder.dim, text, config.logit_scale).columns()
    return pa.concat_tables(chunks).combine_chunks()
