"""The VLMaps-style grid map: dense features fused into occupied top-down cells, streaming.

One pass over the store's views: each view becomes its (view, cell) samples
(:func:`fuse.cells.view_samples`), which are appended to ``cell_views.parquet`` and added to
per-cell sums (:class:`fuse.accumulate.CandidateSums`). Memory grows with the occupied
cells, never with the number of views. At the end the store gets:

- ``cells.parquet``: the common candidate columns (``fuse.measures.candidate_columns``) plus
  ``ix, iy`` (int32, from the grid origin), ``x, y`` (cell centre, metres), ``z_max``
  (highest fused point), ``weight`` (W1), and the layers of the top-down maps: ``r, g, b``
  (colour of the highest point, as VLMaps' top-down colour map), ``obstacle`` (``z_max`` above
  ``obstacle_height``: something stands in the cell) and ``num_pixels``. Metadata:
  ``care.grid.cell_size``, ``care.grid.origin`` ([x, y] of the corner of cell (0, 0)),
  ``care.grid.shape`` ([nx, ny]), ``care.grid.config``.
- ``cell_views.parquet``: every (cell_id, view_id, weight, num_pixels, feature) sample, so
  the columns can be recomputed for another vocabulary or logit scale
  (:func:`fuse.recompute.recompute_grid`) without the views. Features are float16 there;
  the streaming pass uses them at full precision, so a recompute matches a fresh build up
  to that rounding (about 1e-3 relative), not bit for bit.
- ``grid_rgb.png`` and ``grid_obstacles.png``: the same two layers as images for people;
  row 0 is the largest y (north up), column = ix.

A finished grid whose config and store match is not rebuilt (``overwrite`` forces it).
"""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass
from itertools import zip_longest
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from PIL import Image
from tqdm import tqdm

from care.checks import check_numbers
from care.errors import FuseError
from care.outputs import damaged, record_table
from care.store import (
    SCHEMA_VERSION,
    Store,
    append_rows,
    open_writer,
    read_table,
    write_table_atomic,
)
from fuse.accumulate import CandidateSums
from fuse.budget import check_cells, check_raster
from fuse.cells import CellIndex, ViewSamples, unpack_cells, view_samples
from fuse.measures import DEFAULT_LOGIT_SCALE, candidate_metadata, list_column, to_float16
from fuse.vocabulary import vocabulary_text

__all__ = [
    "CELLS_TABLE",
    "CELL_VIEWS_SCHEMA",
    "CELL_VIEWS_TABLE",
    "GridConfig",
    "GridLayout",
    "build_grid",
    "grid_image",
    "write_grid_images",
]

CELLS_TABLE = "cells"
CELL_VIEWS_TABLE = "cell_views"

CELL_VIEWS_SCHEMA = pa.schema(
    [
        pa.field("cell_id", pa.int32(), nullable=False),
        pa.field("view_id", pa.int32(), nullable=False),
        pa.field("weight", pa.float32(), nullable=False),
        pa.field("num_pixels", pa.int32(), nullable=False),
        pa.field("feature", pa.list_(pa.float16()), nullable=False),
    ],
    metadata={b"care.schema_version": str(SCHEMA_VERSION).encode()},
)


@dataclass(frozen=True)
class GridConfig:
    """How a grid map is fused (shared by ``care fuse grid`` and :func:`build_grid`)."""

    cell_size: float = 0.05
    """Cell edge in metres."""
    stride: int = 1
    """Use every stride-th depth pixel in both image directions (1 = full resolution)."""
    z_min: float = -0.2
    """Lowest world height (m) of a fused point; the floor (z = 0) is kept."""
    z_max: float = 2.0
    """Highest world height (m) of a fused point; keeps the ceiling out of the top-down map."""
    sigma_z: float = 2.5
    """Depth scale (m) of the distance weight exp(-z^2 / (2 sigma_z^2))."""
    distance_weighting: bool = True
    """Weight pixels by depth (VLMaps); False gives every pixel weight 1."""
    logit_scale: float = DEFAULT_LOGIT_SCALE
    """Scale s of the class distributions softmax(s * f . t)."""
    vocabulary: tuple[str, ...] | None = None
    """Class names of the columns; default: the names cached in the store."""
    obstacle_height: float = 0.1
    """A cell whose highest point is above this height (m) is an obstacle."""
    overwrite: bool = False
    """Rebuild even if a finished grid with the same config exists."""

    def __post_init__(self) -> None:
        check_numbers(
            FuseError,
            "grid config",
            positive={"cell_size": self.cell_size, "sigma_z": self.sigma_z,
                      "logit_scale": self.logit_scale},
            finite={"z_min": self.z_min, "z_max": self.z_max,
                    "obstacle_height": self.obstacle_height},
            at_least_one={"stride": self.stride},
        )  # fmt: skip
        if self.cell_size <= 0 or self.stride < 1 or self.sigma_z <= 0 or self.z_min > self.z_max:
            msg = (
                f"invalid grid config: cell_size={self.cell_size}, stride={self.stride}, "
                f"sigma_z={self.sigma_z}, z_min={self.z_min}, z_max={self.z_max}; need positive "
                "sizes and z_min <= z_max"
            )
            raise FuseError(msg)

    def fingerprint(self) -> str:
        """JSON of everything that shapes the map (not ``overwrite``)."""
        fields = dataclasses.asdict(self)
        fields.pop("overwrite")
        return json.dumps(fields, sort_keys=True)


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
                float(md[b"care.grid.cell_size"]),
                tuple(json.loads(md[b"care.grid.origin"])),
                tuple(json.loads(md[b"care.grid.shape"])),
            )
        except KeyError as err:
            msg = f"cells table lacks grid metadata {err}; rebuild it with `care fuse grid`"
            raise FuseError(msg) from err

    def metadata(self) -> dict[bytes, bytes]:
        return {
            b"care.grid.cell_size": repr(self.cell_size).encode(),
            b"care.grid.origin": json.dumps(list(self.origin)).encode(),
            b"care.grid.shape": json.dumps(list(self.shape)).encode(),
        }


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


def _view_rows(view_id: int, ids: np.ndarray, samples: ViewSamples) -> pa.Table:
    return pa.table(
        {
            "cell_id": pa.array(ids.astype(np.int32)),
            "view_id": pa.array(np.full(ids.size, view_id, np.int32)),
            "weight": pa.array(samples.weight.astype(np.float32)),
            "num_pixels": pa.array(samples.num_pixels.astype(np.int32)),
            "feature": list_column(to_float16(samples.feature), pa.float16()),
        },
        schema=CELL_VIEWS_SCHEMA,
    )


def _bytes_per_cell(sums: CandidateSums) -> int:
    """Memory one cell takes in the running sums and layers (float64 tables, layers)."""
    return sum(t.shape[1] * t.itemsize for t in sums._tables) + 24


def _is_current(store: Store, config: GridConfig, vocabulary: tuple[str, ...]) -> bool:
    cells, views = store.table_path(CELLS_TABLE), store.table_path(CELL_VIEWS_TABLE)
    if config.overwrite or not (cells.is_file() and views.is_file()):
        return False
    if damaged(store.path, [cells.name, views.name]):  # a damaged map is rebuilt, not trusted
        return False
    md = pq.read_schema(cells).metadata or {}
    return (
        md.get(b"care.grid.config") == config.fingerprint().encode()
        and md.get(b"care.store.created") == str(store.meta.get("created_unix")).encode()
        and md.get(b"care.vocabulary") == json.dumps(list(vocabulary)).encode()
    )


def _fuse_views(
    store: Store, config: GridConfig, sums: CandidateSums, views_path: Path
) -> tuple[CellIndex, _CellLayers]:
    """The streaming pass: every view's samples into ``sums`` and ``views_path``."""
    text = sums.text
    index, layers = CellIndex(), _CellLayers()
    sigma = config.sigma_z if config.distance_weighting else None
    pending: list[pa.Table] = []
    # a store with fewer feature rows than views (or more) is out of step, not a smaller map
    pairs = zip_longest(
        store.iter_frames(extras=False), store.iter_features(), fillvalue=(None, None)
    )
    with open_writer(views_path, CELL_VIEWS_SCHEMA) as writer:
        for (view_id, frame), (feature_id, feature_map) in tqdm(
            pairs, total=store.num_views, desc="fuse grid", unit="view", leave=False
        ):
            if view_id != feature_id:
                msg = f"{store.path}: views and features out of step ({view_id} vs {feature_id}); re-run `care ingest`"
                raise FuseError(msg)
            samples = view_samples(
                frame,
                feature_map,
                cell_size=config.cell_size,
                stride=config.stride,
                z_min=config.z_min,
                z_max=config.z_max,
                sigma_z=sigma,
                text=text,
            )
            ids = index.lookup(samples.keys)
            check_cells(index.size, _bytes_per_cell(sums), config.cell_size)  # before growing
            sums.add(ids, samples.weight, samples.feature, samples.dots)
            layers.add(ids, samples)
            pending.append(_view_rows(view_id, ids, samples))
            if len(pending) >= 16:
                append_rows(writer, pa.concat_tables(pending))
                pending.clear()
        if pending:
            append_rows(writer, pa.concat_tables(pending))
    return index, layers


def _cells_table(
    columns: pa.Table, index: CellIndex, layers: _CellLayers, config: GridConfig, weight: np.ndarray
) -> tuple[pa.Table, GridLayout]:
    """The common columns plus the grid's own, and the layout of the occupied cells."""
    ix, iy = unpack_cells(index.keys_by_id())
    lo = (int(ix.min()), int(iy.min()))
    cs = config.cell_size
    layout = GridLayout(
        cs,
        (round(lo[0] * cs, 9), round(lo[1] * cs, 9)),
        (int(ix.max()) - lo[0] + 1, int(iy.max()) - lo[1] + 1),
    )
    n = index.size
    z_max = layers.z_max[:n]
    grid_columns = {
        "ix": pa.array((ix - lo[0]).astype(np.int32)),
        "iy": pa.array((iy - lo[1]).astype(np.int32)),
        "x": pa.array(((ix + 0.5) * cs).astype(np.float32)),
        "y": pa.array(((iy + 0.5) * cs).astype(np.float32)),
        "z_max": pa.array(z_max),
        "weight": pa.array(weight.astype(np.float32)),
        "r": pa.array(layers.rgb[:n, 0]),
        "g": pa.array(layers.rgb[:n, 1]),
        "b": pa.array(layers.rgb[:n, 2]),
        "obstacle": pa.array(z_max > config.obstacle_height),
        "num_pixels": pa.array(layers.num_pixels[:n].astype(np.int32)),
    }
    for name, col in grid_columns.items():
        columns = columns.append_column(name, col)
    return columns, layout


def _write_png(image: np.ndarray, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        Image.fromarray(image).save(tmp, format="PNG")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


def write_grid_images(store: Store, cells: pa.Table) -> None:
    """``grid_rgb.png`` (colour of the highest point; black = empty) and ``grid_obstacles.png``."""
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


def build_grid(store_path: Path, config: GridConfig | None = None, rrd: Path | None = None) -> Path:
    """Fuse the store's views into ``cells.parquet`` (and siblings); returns its path.

    ``rrd``: also log the grid layers to this Rerun file (:mod:`fuse.viz_grid`).
    """
    config = config or GridConfig()
    store = Store(store_path)
    vocabulary, text = vocabulary_text(store, config.vocabulary)
    cells_path = store.table_path(CELLS_TABLE)
    if not _is_current(store, config, vocabulary):
        views_path = store.table_path(CELL_VIEWS_TABLE)
        tmp = views_path.with_name(f".{views_path.name}.tmp-{os.getpid()}")
        try:
            sums = CandidateSums(store.encoder.dim, text, config.logit_scale)
            index, layers = _fuse_views(store, config, sums, tmp)
            if index.size == 0:
                msg = (
                    f"{store.path}: no depth pixel fell between z_min={config.z_min} and "
                    f"z_max={config.z_max} m; check the poses or widen the band"
                )
                raise FuseError(msg)
            cells, layout = _cells_table(sums.columns(), index, layers, config, sums.weight)
            check_raster((layout.shape[1], layout.shape[0], 3), 1, config.cell_size)  # the images
            metadata = {
                **candidate_metadata(vocabulary, config.logit_scale, store.encoder.name),
                **layout.metadata(),
                b"care.grid.config": config.fingerprint().encode(),
                b"care.store.created": str(store.meta.get("created_unix")).encode(),
            }
            tmp.replace(views_path)  # per-view table first: a current cells.parquet implies it
            record_table(views_path)
            write_table_atomic(cells, cells_path, metadata)
        finally:
            tmp.unlink(missing_ok=True)
        write_grid_images(store, read_table(cells_path))
    if rrd is not None:
        from fuse.viz_grid import log_grid

        log_grid(store.path, rrd)
    return cells_path
