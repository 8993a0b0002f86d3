"""The Arrow feature store: one directory per recording, Parquet tables readable as they are.

Layout of a store directory::

    meta.json          written last; its presence marks a complete store
    views.parquet      one row per view: pose, intrinsics, encoded images (VIEWS_SCHEMA)
    features.parquet   one row per view: the dense feature map, float16 (FEATURES_SCHEMA)
    text.parquet       class-name embeddings of the encoder's text side (TEXT_SCHEMA)
    <map tables>       written later by fuse (cells.parquet, instances.parquet, ...)

How images and features are encoded is :mod:`care_maps.core.codecs`'s (:class:`StoreEncoding`): stores
are written in :attr:`~StoreEncoding.RAW_ZSTD`; the 0.1 encoding is still read and written
(``encoding=``) to measure against. Every table carries ``care.schema_version`` in its
schema metadata. Whole stores are written
into a sibling temporary directory and renamed at the end, so an interrupted job never
leaves a store that looks complete; single tables added later go through
:func:`write_table_atomic`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from collections.abc import Callable, Collection, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from care_maps.core.codecs import StoreEncoding, decode_jpeg, encode_jpeg, jpeg_size
from care_maps.core.errors import StoreError
from care_maps.core.fingerprint import fingerprint
from care_maps.core.frames import Frame
from care_maps.core.keys import (
    ENCODER_DIM_KEY,
    ENCODER_NAME_KEY,
    ENCODER_VERSION_KEY,
    SCHEMA_VERSION_KEY,
    VOCABULARY_KEY,
)
from care_maps.core.mapframe import MapFrame
from care_maps.core.outputs import MARKER as OUTPUT_MARKER
from care_maps.core.outputs import (
    OutputKind,
    damaged,
    disk_full,
    file_digest,
    is_disk_full,
    rebuild_hint,
    record_table,
    remove_path,
    staged,
    swap_in,
    temporary,
    write_marker,
)

__all__ = [
    "BATCH_SIZE",
    "EXTRA_IMAGES",
    "FEATURES_SCHEMA",
    "FEATURES_SCHEMA_LISTS",
    "MAP_FRAME_FILE",
    "MAP_FRAME_STORE_FIELD",
    "META_FILE",
    "META_VERSION",
    "SCHEMA_VERSION",
    "STORE_OWN",
    "TEXT_SCHEMA",
    "VIEWS_SCHEMA",
    "VIEWS_SCHEMA_PNG",
    "WRITER_FIELDS",
    "EncodedDepth",
    "EncoderInfo",
    "RunRecord",
    "SourceFile",
    "SourceRecord",
    "Store",
    "StoreMeta",
    "StoreWriter",
    "append_rows",
    "carried_meta",
    "damaged_table",
    "features_encoding",
    "group_rows",
    "iter_batches",
    "map_frame_json",
    "map_frame_owner",
    "map_frame_record",
    "open_writer",
    "read_map_frame",
    "read_schema",
    "read_table",
    "run_records",
    "source_record",
    "source_recording",
    "store_identity",
    "views_encoding",
    "write_table_atomic",
]

SCHEMA_VERSION = 1
"""Bumped whenever a table's columns change meaning; readers refuse other versions."""

DEPTH_SCALE = 0.001
"""Metres per unit of the stored 16-bit depth (millimetres, so 65.535 m at most)."""

EXTRA_IMAGES = ("instance", "class")
"""Per-pixel label images a recording may carry (sample-world recordings do)."""


def _views_schema(encoding: StoreEncoding) -> pa.Schema:
    suffix = encoding.image_suffix
    return pa.schema(
        [
            pa.field("view_id", pa.int32(), nullable=False),
            pa.field("stamp_ns", pa.int64(), nullable=False),
            pa.field("width", pa.int32(), nullable=False),
            pa.field("height", pa.int32(), nullable=False),
            pa.field("K", pa.list_(pa.float64(), 9), nullable=False),
            pa.field("cam_to_world", pa.list_(pa.float64(), 16), nullable=False),
            pa.field("depth_scale", pa.float32(), nullable=False),
            pa.field("rgb_jpeg", pa.binary(), nullable=False),
            pa.field(f"depth_{suffix}", pa.binary(), nullable=False),
            *(pa.field(f"{name}_{suffix}", pa.binary(), nullable=True) for name in EXTRA_IMAGES),
        ],
        metadata={SCHEMA_VERSION_KEY: str(SCHEMA_VERSION).encode()},
    )


VIEWS_SCHEMA = _views_schema(StoreEncoding.RAW_ZSTD)
"""``depth_zstd`` (and ``instance_zstd``, ``class_zstd``) hold a (height, width) ``uint16``
image in :func:`care_maps.core.codecs.encode_u16`'s zstd frame; ``rgb_jpeg`` a JPEG."""
VIEWS_SCHEMA_PNG = _views_schema(StoreEncoding.PNG_LISTS)
"""The 0.1 views table: the same images as 16-bit PNGs (``depth_png``, ...)."""


def _features_schema(feature: pa.DataType) -> pa.Schema:
    return pa.schema(
        [
            pa.field("view_id", pa.int32(), nullable=False),
            pa.field("fh", pa.int16(), nullable=False),
            pa.field("fw", pa.int16(), nullable=False),
            pa.field("feature", feature, nullable=False),
        ],
        metadata={SCHEMA_VERSION_KEY: str(SCHEMA_VERSION).encode()},
    )


FEATURES_SCHEMA = _features_schema(pa.binary())
"""``feature`` is the (fh, fw, d) map's little-endian ``float16`` bytes, row-major; pixel
(u, v) of a W x H image falls in feature cell (v * fh // H, u * fw // W)."""
FEATURES_SCHEMA_LISTS = _features_schema(pa.list_(pa.float16()))
"""The 0.1 features table: the same map flattened into a Parquet ``float16`` list."""


def views_encoding(schema: pa.Schema) -> StoreEncoding:
    """The encoding of a views table, told by its depth column."""
    if "depth_png" in schema.names:
        return StoreEncoding.PNG_LISTS
    return StoreEncoding.RAW_ZSTD


def features_encoding(schema: pa.Schema) -> StoreEncoding:
    """The encoding of a features table, told by its ``feature`` column's type."""
    if pa.types.is_list(schema.field("feature").type):
        return StoreEncoding.PNG_LISTS
    return StoreEncoding.RAW_ZSTD


TEXT_SCHEMA = pa.schema(
    [
        pa.field("name", pa.string(), nullable=False),
        pa.field("embedding", pa.list_(pa.float32()), nullable=False),
    ],
    metadata={SCHEMA_VERSION_KEY: str(SCHEMA_VERSION).encode()},
)


@dataclass(frozen=True)
class EncoderInfo:
    """What the store records about the encoder that made its features."""

    name: str
    version: str
    dim: int
    vocabulary: tuple[str, ...] = ()

    def metadata(self) -> dict[bytes, bytes]:
        return {
            SCHEMA_VERSION_KEY: str(SCHEMA_VERSION).encode(),
            ENCODER_NAME_KEY: self.name.encode(),
            ENCODER_VERSION_KEY: self.version.encode(),
            ENCODER_DIM_KEY: str(self.dim).encode(),
            VOCABULARY_KEY: json.dumps(list(self.vocabulary)).encode(),
        }

    @classmethod
    def from_metadata(cls, md: dict[bytes, bytes]) -> EncoderInfo:
        return cls(
            name=md[ENCODER_NAME_KEY].decode(),
            version=md[ENCODER_VERSION_KEY].decode(),
            dim=int(md[ENCODER_DIM_KEY]),
            vocabulary=tuple(json.loads(md.get(VOCABULARY_KEY, b"[]"))),
        )


def damaged_table(path: Path, err: BaseException | None = None) -> StoreError:
    """The one-line error of a table that cannot be read: what is wrong and what rebuilds it."""
    path = Path(path)
    why = f" ({str(err).splitlines()[0][:160]})" if err is not None and str(err) else ""
    msg = (
        f"{path}: damaged or truncated table{why}; rebuild it with "
        f"{rebuild_hint(path.parent, path.name)}"
    )
    return StoreError(msg)


@contextlib.contextmanager
def reading(path: Path) -> Iterator[None]:
    """Turn Arrow/Parquet read failures of ``path`` into :func:`damaged_table`'s one line."""
    try:
        yield
    except (pa.ArrowException, OSError) as err:
        if isinstance(err, PermissionError):
            raise
        if isinstance(err, FileNotFoundError) and not Path(path).parent.exists():
            raise
        raise damaged_table(path, err) from err


def _check_version(schema: pa.Schema, path: Path) -> None:
    """Refuse a table of another schema version, and a store table whose columns are not
    those of a layout this program writes (:func:`layout_problem`), in one line naming it."""
    found = (schema.metadata or {}).get(SCHEMA_VERSION_KEY)
    if found is None or not found.isdigit() or int(found) != SCHEMA_VERSION:
        msg = (
            f"{path}: schema version {found.decode(errors='replace') if found else 'missing'}, "
            f"this program reads version {SCHEMA_VERSION}; rebuild it with the matching `care` "
            "command."
        )
        raise StoreError(msg)
    problem = layout_problem(schema, path)
    if problem is not None:
        raise StoreError(problem)


def _layouts() -> dict[str, tuple[pa.Schema, ...]]:
    return {
        "views.parquet": (VIEWS_SCHEMA, VIEWS_SCHEMA_PNG),
        "features.parquet": (FEATURES_SCHEMA, FEATURES_SCHEMA_LISTS),
        "text.parquet": (TEXT_SCHEMA,),
    }


def layout_problem(schema: pa.Schema, path: Path) -> str | None:
    """What keeps the store table ``path`` from being read as one of the layouts this
    program writes: a column missing or of another type, or one it does not know (None:
    a layout it reads; not a store table: None).

    A store table has one writer (:class:`StoreWriter`), so its columns are exact: a
    missing one was a ``KeyError`` deep in a reader, an unknown one means another program
    (or a hand) wrote it, and neither is what ``meta.json`` describes."""
    path = Path(path)
    layouts = _layouts().get(path.name)
    if layouts is None or not (path.parent / META_FILE).is_file():
        return None
    found = {f.name: f.type for f in schema}

    def mismatch(layout: pa.Schema) -> tuple[int, int]:
        names = len(set(layout.names) ^ set(found))
        types = sum(1 for f in layout if f.name in found and not found[f.name].equals(f.type))
        return names, types

    # two encodings share column names (features: binary or a float16 list): the closest
    # by names, then by types
    best = min(layouts, key=mismatch)
    missing = [n for n in best.names if n not in found]
    extra = [n for n in found if n not in best.names]
    wrong = [
        f"{f.name} is {found[f.name]}, not {f.type}"
        for f in best
        if f.name in found and not found[f.name].equals(f.type)
    ]
    what = [
        *(["missing " + ", ".join(missing)] if missing else []),
        *(["unknown column " + ", ".join(extra)] if extra else []),
        *wrong,
    ]
    if not what:
        return None
    table = path.name.removesuffix(".parquet")
    return (
        f"{path}: not a {table} table this program reads ({'; '.join(what)}); rebuild the "
        f"store with {rebuild_hint(path.parent, table)}"
    )


CHECKED = {"page_checksum_verification": True}
"""Reader options of every table here: each page's CRC (written by :func:`parquet_options`)
checked as it is read, so damage inside a value is a damaged table, not wrong data."""


def parquet_options(schema: pa.Schema, *, compress_binary: bool = False) -> dict[str, Any]:
    """Writer options of every table here: zstd, dictionary encoding for id-like columns only,
    and no Parquet compression of binary columns.

    Parquet tries a dictionary for every column by default and gives up only after filling
    it; on float features and PNG bytes that attempt took more than half of each write (the
    sample's grid tables: 1.1 s -> 0.4 s, and a little smaller). Binary columns hold
    encoded images and raw feature bytes (:mod:`care_maps.core.codecs`): compressing them again cost
    a decompression per read and saved nothing on images, 8% on features.
    """

    def leaf(ty: pa.DataType) -> pa.DataType:
        while pa.types.is_list(ty) or pa.types.is_large_list(ty) or pa.types.is_fixed_size_list(ty):
            ty = ty.value_type
        return ty

    repetitive = (pa.types.is_integer, pa.types.is_boolean, pa.types.is_string)
    names = [f.name for f in schema if any(test(leaf(f.type)) for test in repetitive)]
    # a CRC per page, checked on every read (:data:`CHECKED`): an image's zstd frame carries
    # no checksum of its own, so a flipped byte inside one decoded into wrong depth, silently
    checked = {"use_dictionary": names, "write_page_checksum": True}
    if compress_binary or not any(pa.types.is_binary(f.type) for f in schema):
        return {"compression": "zstd", **checked}
    # per leaf column (a list column's leaf is `name.list.element`); Parquet's default for
    # a column left out of the mapping is no compression, so every one is named
    codecs = {
        path: "none" if pa.types.is_binary(field.type) else "zstd"
        for field in schema
        for path in _leaf_paths(field)
    }
    # no min/max of image or feature bytes: meaningless, and a small one is stored twice more
    stats = [path for path, codec in codecs.items() if codec == "zstd"]
    return {"compression": codecs, "write_statistics": stats, **checked}


def _leaf_paths(field: pa.Field) -> list[str]:
    """Parquet's dotted paths of a field's leaf columns (``K.list.element`` for a list)."""
    ty = field.type
    if pa.types.is_list(ty) or pa.types.is_large_list(ty) or pa.types.is_fixed_size_list(ty):
        return [f"{field.name}.list.element"]
    return [field.name]


_GROUP_LIST_VALUES = 1 << 22
"""List values per Parquet row group at most (see :func:`group_rows`)."""


def group_rows(table: pa.Table) -> int:
    """Rows per Parquet row group so that no list column holds more than about 4M values.

    Parquet's writer expands a float16 list column to 16 bytes a value while it encodes a
    row group: 16 views of 640x480 features at once held 469 MiB (measured), and a grid of
    a million cells would hold gigabytes, so groups are cut by values, not rows. Small
    groups also keep reading them back bounded.
    """
    per_row = 1
    for column, field in zip(table.columns, table.schema, strict=True):
        if pa.types.is_fixed_size_list(field.type):
            per_row = max(per_row, field.type.list_size)
        elif pa.types.is_list(field.type) and table.num_rows:
            import pyarrow.compute as pc  # ~0.1 s to import: only a writer of lists needs it

            lengths = pc.list_value_length(column).to_numpy(zero_copy_only=False)
            per_row = max(per_row, int(lengths.mean()))
    return max(1, _GROUP_LIST_VALUES // per_row)


def open_writer(
    path: Path, schema: pa.Schema, *, compress_binary: bool = False
) -> pq.ParquetWriter:
    """A streaming Parquet writer with this project's options (:func:`parquet_options`)."""
    return pq.ParquetWriter(
        path, schema, **parquet_options(schema, compress_binary=compress_binary)
    )


def append_rows(writer: pq.ParquetWriter, table: pa.Table) -> None:
    """Write ``table`` through ``writer`` in row groups bounded by :func:`group_rows`."""
    writer.write_table(table, row_group_size=group_rows(table))


def write_table_atomic(
    table: pa.Table, path: Path, metadata: dict[bytes, bytes] | None = None
) -> None:
    """Write one Parquet table through a temporary file renamed over ``path``.

    The schema version is always added to the table's metadata.
    """
    md = dict(table.schema.metadata or {})
    md.update(metadata or {})
    md[SCHEMA_VERSION_KEY] = str(SCHEMA_VERSION).encode()
    table = table.replace_schema_metadata(md)
    path = Path(path)
    with staged(path) as tmp:
        pq.write_table(
            table, tmp, row_group_size=group_rows(table), **parquet_options(table.schema)
        )
        tmp.replace(path)
    record_table(path)


def read_schema(path: Path) -> pa.Schema:
    """The schema (with metadata) of a Parquet table of this project, checked like
    :func:`read_table`, without reading any column."""
    path = _readable(path)
    with reading(path):
        schema = pq.read_schema(path)
    _check_version(schema, path)
    return schema


def _readable(path: Path) -> Path:
    """``path``, refused in one line when it is missing or its directory's marker says it
    was damaged since it was written."""
    path = Path(path)
    if not path.is_file():
        msg = f"{path}: no such table; build it first (see `care --help`)."
        raise StoreError(msg)
    if damaged(path.parent, [path.name], checksum=False):
        raise damaged_table(path)
    return path


def as_numpy(column: pa.Array | pa.ChunkedArray) -> np.ndarray:
    """A numeric or boolean Arrow column as a NumPy array, read from its buffers.

    ``to_numpy`` converts through pyarrow's pandas path, which imports pandas on its first
    call (0.2 s): a query would pay that at every start. Numbers and booleans without nulls
    (every column a query reads) are viewed from their data buffer instead, read-only like
    ``to_numpy``'s zero-copy view; anything else goes through ``to_numpy``.
    """
    if isinstance(column, pa.ChunkedArray):
        column = column.combine_chunks()
    kind = column.type
    if column.null_count or not (
        pa.types.is_integer(kind) or pa.types.is_floating(kind) or pa.types.is_boolean(kind)
    ):
        return column.to_numpy(zero_copy_only=False)
    if pa.types.is_boolean(kind):  # bit-packed, least significant bit first
        if len(column) == 0:
            return np.zeros(0, dtype=bool)
        bits = np.unpackbits(np.frombuffer(column.buffers()[1], np.uint8), bitorder="little")
        return bits[column.offset : column.offset + len(column)].astype(bool)
    dtype = np.dtype(kind.to_pandas_dtype())
    if len(column) == 0:
        return np.zeros(0, dtype=dtype)
    return np.frombuffer(
        column.buffers()[1], dtype=dtype, count=len(column), offset=column.offset * dtype.itemsize
    )


def read_table(path: Path, columns: Sequence[str] | None = None) -> pa.Table:
    """Read a Parquet table of this project, refusing missing files and other schema versions.

    ``columns=None`` reads every column; ``[]`` none (the rows' count and the schema's
    metadata only: a grid's layout without decoding its million features, which a goal
    query needs on every call).
    """
    path = _readable(path)
    with reading(path), pq.ParquetFile(path, **CHECKED) as table:
        # one file: ParquetFile, not pq.read_table and its dataset layer (slower to open)
        _check_version(table.schema_arrow, path)
        return table.read(columns=None if columns is None else list(columns))


def iter_batches(
    path: Path,
    batch_size: int,
    columns: Sequence[str] | None = None,
    view_ids: Collection[int] | None = None,
) -> Iterator[pa.RecordBatch]:
    """A Parquet file's rows in batches, one row group in memory at a time.

    ``ParquetFile.iter_batches`` keeps the buffers of every row group it has read until the
    iterator ends (pyarrow 2x, measured: +1.4 MB a view over a 1,485-view store, 2 GB by
    the end), so streaming a large store through it grew without bound. Reading row group
    by row group frees each before the next.

    ``view_ids``: only row groups whose ``view_id`` range (the footer's statistics) holds one
    of them are read, so the views appended to a large store are read without the rest
    (the rows of a group read are all yielded: the caller filters them).
    """
    pf = pq.ParquetFile(path, **CHECKED)
    wanted = None if view_ids is None else np.unique(np.fromiter(view_ids, np.int64))
    for group in range(pf.num_row_groups):
        if wanted is not None and not _holds_any(pf, group, wanted):
            continue
        table = pf.read_row_group(group, columns=None if columns is None else list(columns))
        yield from table.to_batches(max_chunksize=batch_size)


def _holds_any(pf: pq.ParquetFile, group: int, wanted: np.ndarray) -> bool:
    """Whether row group ``group`` may hold a ``view_id`` of ``wanted`` (sorted): True where
    the file has no statistics for it."""
    names = pf.schema_arrow.names
    if "view_id" not in names:
        return True
    stats = pf.metadata.row_group(group).column(names.index("view_id")).statistics
    if stats is None or not stats.has_min_max:
        return True
    lo = int(np.searchsorted(wanted, int(stats.min)))
    return lo < wanted.size and int(wanted[lo]) <= int(stats.max)


_MAX_BUFFERED_VALUES = 1 << 26
"""Feature values buffered before a row group is written whatever ``rows_per_group`` says:
bounds the memory (128 MiB of float16) and keeps the list column's int32 offsets valid."""


META_FILE = "meta.json"
"""The store's metadata (:class:`StoreMeta`), written last: its presence marks a complete
store."""

STORE_OWN = frozenset(
    {"views.parquet", "features.parquet", "text.parquet", META_FILE, OUTPUT_MARKER}
)
"""What ingest writes into a store; anything else in it was made from the store (maps)."""

BATCH_SIZE = 8
"""Views handled at once where a stage batches them (read, projected, cropped, encoded)."""

META_VERSION = 2
"""Layout of ``meta.json`` (the source by content and relative path); a store of another
layout is refused, to be ingested again."""


@dataclass(frozen=True)
class SourceFile:
    """One file of a recording written in several: where it lies relative to the store,
    its name and size."""

    path: str | None = None
    name: str | None = None
    size: int | None = None


@dataclass(frozen=True)
class SourceRecord:
    """The recording a store was made from: where it lies *relative to the store* (no
    absolute machine path inside a store) and what it is (size and checksum)."""

    path: str | None = None
    """Relative to the store directory (version 1 stores: absolute); of a recording in
    several files, the first in time."""
    name: str | None = None
    size: int | None = None
    blake2b: str | None = None
    """Of a recording in several files, a checksum of every file's checksum."""
    files: tuple[SourceFile, ...] = ()
    """A recording in several files: each, in the order read (empty for one, and then
    not written)."""

    def resolve(self, store: Path) -> Path | None:
        """The recording's path as seen from ``store`` (None when none is recorded)."""
        if not self.path:
            return None
        return Path(os.path.normpath(Path(store).absolute() / self.path))


def source_record(source: Any) -> SourceRecord:
    """``meta.json``'s ``source``, typed (raises KeyError, TypeError or ValueError)."""
    if not isinstance(source, dict):
        return SourceRecord()
    listed = source.get("files") or []
    if not isinstance(listed, list) or not all(isinstance(f, dict) for f in listed):
        msg = f"source files {listed!r} are not a list of objects"
        raise TypeError(msg)
    files = tuple(SourceFile(**{k: f.get(k) for k in ("path", "name", "size")}) for f in listed)
    return SourceRecord(
        **{k: source.get(k) for k in ("path", "name", "size", "blake2b")}, files=files
    )


@dataclass(frozen=True)
class RunRecord:
    """One exploration run of a store that holds several (``care ingest --append``): its
    views, where it came from, the frame it was recorded in and how it was placed in the
    store's, and what the checks found."""

    first_view: int
    """Its views are ``first_view .. first_view + num_views - 1``."""
    num_views: int
    source: SourceRecord = dataclasses.field(default_factory=SourceRecord)
    fingerprint: str | None = None
    """Hash of the run's recording and the options it was read with (its store's, alone)."""
    request_fingerprint: str | None = None
    world_frame: str | None = None
    """The frame its recording's poses were in."""
    camera_frame: str | None = None
    world_transform: list[float] | None = None
    """``x, y, z, qx, qy, qz, qw`` of its world frame in the store's, as given (None: the
    same frame)."""
    counts: dict[str, Any] = dataclasses.field(default_factory=dict)
    geometry: dict[str, Any] | None = None
    """The run's own consistency check (its views among themselves)."""
    alignment: dict[str, Any] | None = None
    """Its views against the earlier runs' where they overlap (None for the first run)."""

    @property
    def view_ids(self) -> range:
        return range(self.first_view, self.first_view + self.num_views)

    @classmethod
    def from_json(cls, data: Any) -> RunRecord:
        """A ``runs`` entry of ``meta.json`` (raises KeyError, TypeError or ValueError)."""
        if not isinstance(data, dict):
            msg = f"run {data!r} is not an object"
            raise TypeError(msg)
        known = {f.name for f in dataclasses.fields(cls)}
        values = {k: v for k, v in data.items() if k in known}
        values.update(
            first_view=int(data["first_view"]),
            num_views=int(data["num_views"]),
            source=source_record(data.get("source")),
            counts=data.get("counts") or {},
        )
        return cls(**values)


@dataclass(frozen=True)
class StoreMeta:
    """``meta.json``: the one typed record of a store's metadata, read and written here only
    (:meth:`read`, :meth:`to_json`); versioned by :data:`META_VERSION`."""

    num_views: int
    encoder: EncoderInfo | None = None
    """Name, version and dimension of the features' encoder; None: views only."""
    encoder_record: dict[str, Any] | None = None
    """Every option that shapes the encoder (:class:`care_maps.core.encoders.record.EncoderRecord`)."""
    fingerprint: str | None = None
    """Hash of the recording's content and the ingest options the store depends on."""
    request_fingerprint: str | None = None
    """The same, known before the encoder is built (a re-run matching it loads no model)."""
    source: SourceRecord = dataclasses.field(default_factory=SourceRecord)
    topics: dict[str, Any] = dataclasses.field(default_factory=dict)
    world_frame: str | None = None
    camera_frame: str | None = None
    camera_convention: dict[str, Any] | None = None
    """The camera frame's axes as ingest found or was told them (``{"convention",
    "reason"}``; poses are stored in the optical convention whatever they were)."""
    distortion: list[dict[str, Any]] | None = None
    """The lens distortions removed from the images at ingest, ``{"model", "D"}`` as the
    camera info gave them, in order of first appearance; empty: zero D, the images are as
    recorded; None: a store made before ingest read D."""
    label_names: tuple[str, ...] = ()
    vocabulary: tuple[str, ...] = ()
    counts: dict[str, Any] = dataclasses.field(default_factory=dict)
    """Frames read, written and dropped (by reason)."""
    geometry: dict[str, Any] | None = None
    """What the geometric consistency check of ingest found (:mod:`care_maps.ingest.consistency`):
    its status, the agreement of reprojected depth between views, the likelier reading
    where one was found; None: a store made before the check."""
    config: dict[str, Any] = dataclasses.field(default_factory=dict)
    """The ingest options that shape the store (not where its inputs and outputs lie)."""
    tables: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    """Each table's size and BLAKE2b checksum at commit."""
    runs: tuple[RunRecord, ...] = ()
    """The exploration runs of a store that holds several, in view order (empty for one run,
    and then not written); the fields above are the first run's, but for the counts (all
    runs') and the fingerprint (of every run's)."""
    schema_version: int = SCHEMA_VERSION
    meta_version: int = META_VERSION

    def to_json(self) -> str:
        data = asdict(self)
        if not self.source.files:  # a recording in one file: no list of files
            del data["source"]["files"]
        if not self.runs:  # a store of one run: no list of runs
            del data["runs"]
        for run, written in zip(self.runs, data.get("runs", ()), strict=True):
            if not run.source.files:
                del written["source"]["files"]
        data["encoder"] = None if self.encoder is None else {
            "name": self.encoder.name, "version": self.encoder.version, "dim": self.encoder.dim
        }  # fmt: skip
        return json.dumps(data, indent=2, default=str)

    @classmethod
    def from_json(cls, data: Any, where: Path) -> StoreMeta:
        """Parse ``meta.json``'s content; one line naming ``where`` when it is not a store's."""
        if not isinstance(data, dict):
            msg = f"{where}: not a JSON object; rebuild the store with {rebuild_hint(where.parent, 'meta')}"
            raise StoreError(msg)
        if "schema_version" not in data:  # a store's meta always has it: this one is damaged
            msg = (
                f"{where}: damaged (no schema_version, {len(data)} of a store's fields); "
                f"rebuild the store with {rebuild_hint(where.parent, 'meta')}"
            )
            raise StoreError(msg)
        for field, ours in (("schema_version", SCHEMA_VERSION), ("meta_version", META_VERSION)):
            if data.get(field) != ours:
                msg = (
                    f"{where}: {field.replace('_', ' ')} {data.get(field)}, this program "
                    f"reads {ours}; "
                    f"rebuild the store with {rebuild_hint(where.parent, 'meta')}"
                )
                raise StoreError(msg)
        try:
            enc = data.get("encoder")
            source = data.get("source")
            known = {f.name for f in dataclasses.fields(cls)}
            values = {k: v for k, v in data.items() if k in known}
            values.update(
                num_views=int(data["num_views"]),
                encoder=None if not enc else EncoderInfo(enc["name"], enc["version"], int(enc["dim"])),
                source=source_record(source),
                label_names=tuple(data.get("label_names") or ()),
                vocabulary=tuple(data.get("vocabulary") or ()),
                topics=data.get("topics") or {},
                counts=data.get("counts") or {},
                config=data.get("config") or {},
                tables=data.get("tables") or {},
                runs=tuple(RunRecord.from_json(r) for r in data.get("runs") or ()),
                meta_version=META_VERSION,
            )  # fmt: skip
            return cls(**values)
        except (KeyError, TypeError, ValueError) as err:
            msg = f"{where}: malformed store metadata ({err}); rebuild the store with {rebuild_hint(where.parent, 'meta')}"
            raise StoreError(msg) from err

    @classmethod
    def read(cls, store: Path) -> StoreMeta:
        """The metadata of the store ``store``; one line when it is missing or unreadable."""
        path = Path(store) / META_FILE
        if not path.is_file():
            msg = f"{store}: not a complete feature store (no meta.json); run `care ingest` first."
            raise StoreError(msg)
        try:
            data = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError) as err:
            msg = f"{path}: not valid JSON ({err}); rebuild the store with {rebuild_hint(Path(store), 'meta')}"
            raise StoreError(msg) from err
        return cls.from_json(data, path)


WRITER_FIELDS = ("num_views", "encoder", "tables", "schema_version", "meta_version")
"""The fields of ``meta.json`` that :meth:`StoreWriter.commit` sets from what it wrote."""


def carried_meta(meta: StoreMeta) -> dict[str, Any]:
    """``meta`` as the JSON a new store written from this one's views (and more) commits:
    all but the :data:`WRITER_FIELDS`."""
    data = json.loads(meta.to_json())
    return {k: v for k, v in data.items() if k not in WRITER_FIELDS}


def run_records(meta: StoreMeta) -> list[RunRecord]:
    """The exploration runs of a store: those recorded, or its one run (the whole store)."""
    if meta.runs:
        return list(meta.runs)
    return [
        RunRecord(
            first_view=0,
            num_views=meta.num_views,
            source=meta.source,
            fingerprint=meta.fingerprint,
            request_fingerprint=meta.request_fingerprint,
            world_frame=meta.world_frame,
            camera_frame=meta.camera_frame,
            counts=meta.counts,
            geometry=meta.geometry,
        )
    ]


def source_recording(store: Path, meta: StoreMeta | None = None) -> Path | None:
    """The recording the store ``store`` was ingested from (None when it names none)."""
    return (meta or StoreMeta.read(store)).source.resolve(store)


def depth_millimetres(depth_m: np.ndarray) -> np.ndarray:
    """``uint16`` depth in units of :data:`DEPTH_SCALE` (rounded half to even, clipped to
    0..65535): NaN and -inf become 0 (no depth), +inf 65535. In place on one float array: the
    step of every ingested view that touches each pixel the most often."""
    scaled = np.divide(depth_m, DEPTH_SCALE)
    np.rint(scaled, out=scaled)
    np.clip(scaled, 0, 65535, out=scaled)
    scaled[np.isnan(scaled)] = 0
    return scaled.astype(np.uint16)


class StoreWriter:
    """Streams views and features into a new store, committing it atomically on success.

    Use as a context manager: on an exception the temporary directory is removed and any
    previous store at ``path`` is left as it was.
    """

    def __init__(
        self,
        path: Path,
        encoder: EncoderInfo | None,
        *,
        rows_per_group: int = 16,
        encoding: StoreEncoding = StoreEncoding.RAW_ZSTD,
    ) -> None:
        self.path = Path(path)
        self.encoder = encoder
        self.rows_per_group = rows_per_group
        self.encoding = StoreEncoding(encoding)
        self.kept_jpeg = 0
        """Views whose colour is the recording's own JPEG bytes (not encoded again)."""
        self.tmp = temporary(self.path)  # within the name limit however long the name
        self.num_views = 0
        self._views: list[dict[str, Any]] = []
        self._features: list[dict[str, Any]] = []
        self._views_writer: pq.ParquetWriter | None = None
        self._features_writer: pq.ParquetWriter | None = None
        self._text: pa.Table | None = None
        self._pool: ThreadPoolExecutor | None = None
        self._pending: list[Future[dict[str, Any]]] = []

    def __enter__(self) -> StoreWriter:
        remove_path(self.tmp)
        self.tmp.mkdir(parents=True)
        legacy = self.encoding is StoreEncoding.PNG_LISTS
        views = VIEWS_SCHEMA_PNG if legacy else VIEWS_SCHEMA
        features = FEATURES_SCHEMA_LISTS if legacy else FEATURES_SCHEMA
        try:
            self._views_writer = open_writer(
                self.tmp / "views.parquet", views, compress_binary=legacy
            )
            if self.encoder is not None:
                schema = features.with_metadata(self.encoder.metadata())
                self._features_writer = open_writer(
                    self.tmp / "features.parquet", schema, compress_binary=legacy
                )
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def add(self, frame: Frame, features: np.ndarray | None = None) -> int:
        """Append one view (and its (fh, fw, d) feature map); returns its view id.

        The view's images are encoded in one background thread while the caller reads and
        decodes the next frame (JPEG, zstd and the depth conversion release the GIL: on two
        cores this is most of an encoder-less ingest's own time); rows are written in order,
        each when its images are done (:meth:`_flush`). ``frame``'s arrays must not change
        after this call."""
        view_id = self.num_views
        row: dict[str, Any] = {
            "view_id": view_id,
            "stamp_ns": int(frame.stamp_ns),
            "width": frame.width,
            "height": frame.height,
            "K": np.asarray(frame.K, dtype=np.float64).ravel().tolist(),
            "cam_to_world": np.asarray(frame.cam_to_world, dtype=np.float64).ravel().tolist(),
            "depth_scale": DEPTH_SCALE,
        }
        own = self._own_jpeg(frame)
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="store-encode")
        self._pending.append(self._pool.submit(self._images, frame, own))
        self._views.append(row)
        if features is not None:
            if self._features_writer is None or self.encoder is None:
                msg = "features given to a store opened without an encoder"
                raise StoreError(msg)
            if features.ndim != 3 or features.shape[2] != self.encoder.dim:
                msg = (
                    f"feature map of shape {features.shape}, expected (fh, fw, {self.encoder.dim})"
                )
                raise StoreError(msg)
            self._features.append(
                {
                    "view_id": view_id,
                    "fh": features.shape[0],
                    "fw": features.shape[1],
                    "feature": np.ascontiguousarray(features, dtype=np.float16).ravel(),
                }
            )
        self.num_views += 1
        buffered = sum(r["feature"].size for r in self._features)
        if len(self._views) >= self.rows_per_group or buffered >= _MAX_BUFFERED_VALUES:
            self._flush()
        return view_id

    def _own_jpeg(self, frame: Frame) -> bytes | None:
        """The recording's own JPEG when the frame carries it and its header agrees with
        the image (the store keeps those bytes), else None (the image is encoded once,
        :func:`care_maps.core.codecs.encode_jpeg`)."""
        own = frame.rgb_jpeg
        if (
            own is not None
            and self.encoding is StoreEncoding.RAW_ZSTD
            and jpeg_size(own) == (frame.width, frame.height)
        ):
            self.kept_jpeg += 1
            return bytes(own)
        return None

    def _images(self, frame: Frame, own: bytes | None) -> dict[str, Any]:
        """A view's encoded images (colour, depth in mm, label images), by column."""
        suffix = self.encoding.image_suffix
        out: dict[str, Any] = {
            "rgb_jpeg": own if own is not None else encode_jpeg(frame.rgb),
            f"depth_{suffix}": self.encoding.encode_image(depth_millimetres(frame.depth_m)),
        }
        for name in EXTRA_IMAGES:
            extra = frame.extras.get(name)
            out[f"{name}_{suffix}"] = (
                None if extra is None else self.encoding.encode_image(extra.astype(np.uint16))
            )
        return out

    def copy_views(self, store: Store) -> None:
        """Append every view and feature map of ``store`` as they are stored (their encoded
        bytes copied a row group at a time, nothing decoded): the earlier runs of a store
        that a run is appended to keep their view ids, and the new run's continue from them.
        The stores must be in one encoding and of one encoder (checked by the caller)."""
        self._flush()
        for name, writer in (("views", self._views_writer), ("features", self._features_writer)):
            path = store.table_path(name)
            if writer is None or not path.is_file():
                continue
            with reading(path):
                source = pq.ParquetFile(path)
                if source.schema_arrow.remove_metadata() != writer.schema.remove_metadata():
                    msg = f"{path}: another layout than the store being written; rebuild the store"
                    raise StoreError(msg)
                for group in range(source.num_row_groups):
                    table = source.read_row_group(group).replace_schema_metadata(
                        writer.schema.metadata
                    )
                    append_rows(writer, table)
        self.num_views += store.num_views

    def set_text(self, names: Sequence[str], embeddings: np.ndarray) -> None:
        """Cache the encoder's class-name embeddings (n, d) in the store."""
        self._text = pa.table(
            {
                "name": pa.array(list(names), pa.string()),
                "embedding": pa.array(
                    list(np.asarray(embeddings, np.float32)), pa.list_(pa.float32())
                ),
            },
            schema=TEXT_SCHEMA,
        )

    def _flush(self) -> None:
        for row, images in zip(self._views, self._pending, strict=True):
            row.update(images.result())  # in order; an encoding error is raised here
        self._pending.clear()
        if self._views and self._views_writer is not None:
            table = pa.Table.from_pylist(self._views, schema=self._views_writer.schema)
            append_rows(self._views_writer, table)
            self._views.clear()
        if self._features and self._features_writer is not None:
            rows = self._features
            # one flat buffer and its offsets: a list of per-view arrays would go through
            # Python objects value by value (half the ingest time, measured)
            sizes = np.array([r["feature"].size for r in rows], np.int64)
            flat = np.concatenate([r["feature"] for r in rows]).astype("<f2", copy=False)
            if self.encoding is StoreEncoding.PNG_LISTS:
                offsets = pa.array(np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32))
                column = pa.ListArray.from_arrays(offsets, pa.array(flat, pa.float16()))
            else:  # each view's bytes, laid end to end: one copy, no Python object per value
                ends = np.concatenate([[0], np.cumsum(2 * sizes)]).astype(np.int32)
                column = pa.BinaryArray.from_buffers(
                    pa.binary(), len(rows), [None, pa.py_buffer(ends), pa.py_buffer(flat)]
                )
            table = pa.table(
                {
                    "view_id": pa.array([r["view_id"] for r in rows], pa.int32()),
                    "fh": pa.array([r["fh"] for r in rows], pa.int16()),
                    "fw": pa.array([r["fw"] for r in rows], pa.int16()),
                    "feature": column,
                },
                schema=self._features_writer.schema,
            )
            append_rows(self._features_writer, table)
            self._features.clear()

    def commit(
        self, meta: dict[str, Any], *, replacing: Callable[[], object] | None = None
    ) -> None:
        """Finish the tables, write ``meta.json`` last, and rename into place; ``replacing``
        is called once everything is written, just before the old store is replaced (a
        commit that fails earlier leaves the old store, and says nothing of replacing it)."""
        self._flush()
        for writer in (self._views_writer, self._features_writer):
            if writer is not None:
                writer.close()
        self._views_writer = self._features_writer = None
        if self._text is not None:
            write_table_atomic(self._text, self.tmp / "text.parquet")
        full: dict[str, Any] = {"num_views": self.num_views, "encoder": self.encoder, **meta}
        # the store's fingerprint on disk: every table's size and checksum, so a deleted,
        # truncated or altered table is found (``care check``, the next ingest)
        full["tables"] = {p.name: file_digest(p) for p in sorted(self.tmp.glob("*.parquet"))}
        full["schema_version"] = SCHEMA_VERSION
        full["meta_version"] = META_VERSION
        if isinstance(full["encoder"], EncoderInfo):
            info = full["encoder"]
            full["encoder"] = {"name": info.name, "version": info.version, "dim": info.dim}
        record = StoreMeta.from_json(full, self.tmp / META_FILE)
        (self.tmp / META_FILE).write_text(record.to_json())
        write_marker(self.tmp, OutputKind.STORE, source=record.source.path)
        if replacing is not None:
            replacing()
        # in one step: a kill leaves the previous store or this one (swap_in)
        swap_in(self.tmp, self.path)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        # on every path, a full disk included: closing a writer may fail then, and the
        # temporary must go all the same (else it keeps the disk full for the next run)
        written = 0
        try:
            if self._pool is not None:  # images still encoding are dropped with the store
                self._pool.shutdown(wait=True, cancel_futures=True)
                self._pool = None
            self._pending.clear()
            for writer in (self._views_writer, self._features_writer):
                if writer is not None:
                    with contextlib.suppress(Exception):
                        writer.close()
            self._views_writer = self._features_writer = None
        finally:
            if self.tmp.exists():
                written = sum(p.stat().st_size for p in self.tmp.iterdir() if p.is_file())
            remove_path(self.tmp)
        if exc is not None and is_disk_full(exc):
            raise disk_full(self.path, written, exc) from exc


def _in_frame(to_map: np.ndarray | None, cam_to_world: list[float]) -> np.ndarray:
    pose = np.asarray(cam_to_world, dtype=np.float64).reshape(4, 4)
    return pose if to_map is None else to_map @ pose


MAP_FRAME_FILE = "map_frame.json"
"""The store's map frame (:class:`care_maps.core.mapframe.MapFrame`, the options it was found with and
the identity of the store it was found for, :attr:`Store.identity`)."""

MAP_FRAME_STORE_FIELD = "store"
"""The field of ``map_frame.json`` naming the store it belongs to (:attr:`Store.identity`)."""


def store_identity(meta: StoreMeta) -> str:
    """What a store *is*, as 16 hex digits: a hash of its tables' recorded sizes and
    checksums (``meta.json``). The same store copied elsewhere, or built again to the same
    bytes, keeps it; another recording, other options, another ingest do not."""
    return fingerprint(meta.tables, length=16)


def map_frame_json(frame: MapFrame, options: dict[str, Any], store: Store) -> str:
    """The text of ``map_frame.json`` for ``frame`` found in ``store`` with ``options``:
    the frame carries the store's identity, so a frame copied from another store is refused
    (:func:`read_map_frame`), not used."""
    record = {"options": options, "frame": frame.as_json(), MAP_FRAME_STORE_FIELD: store.identity}
    return json.dumps(record, indent=2)


def map_frame_record(store: Path) -> dict[str, Any] | None:
    """``map_frame.json`` of the store directory ``store`` as JSON (None: absent or not a
    JSON object)."""
    path = Path(store) / MAP_FRAME_FILE
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def map_frame_owner(record: dict[str, Any], meta: StoreMeta) -> bool:
    """Whether the map frame ``record`` (:func:`map_frame_record`) was found for the store
    ``meta`` describes."""
    return record.get(MAP_FRAME_STORE_FIELD) == store_identity(meta)


def read_map_frame(store: Path, meta: StoreMeta | None = None) -> MapFrame:
    """The gravity-aligned map frame of the store directory ``store`` (``map_frame.json``,
    written by its first fusion; the world frame itself until then), checked: every reader
    of positions goes through here, so a damaged frame, or one found for another store
    (``meta``: the store's, read when not given), is one line, not a failed solver or
    positions in another store's frame."""
    path = Path(store) / MAP_FRAME_FILE
    if not path.is_file():
        return MapFrame.identity()
    try:
        record = json.loads(path.read_text())
        frame = MapFrame.from_json(record["frame"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        msg = f"{path}: unreadable map frame ({err}); delete it and re-run `care fuse`"
        raise StoreError(msg) from err
    if meta is None and (Path(store) / META_FILE).is_file():
        meta = StoreMeta.read(Path(store))
    if meta is not None and not map_frame_owner(record, meta):
        found = record.get(MAP_FRAME_STORE_FIELD)
        whose = (
            f"found for another store ({found}; this store is {store_identity(meta)})"
            if found
            else "of no store it names (an earlier care's, or copied from another store)"
        )
        msg = f"{path}: a map frame {whose}; re-run `care fuse grid {store}` to find this store's"
        raise StoreError(msg)
    if not (np.isfinite(frame.map_from_world).all() and np.isfinite(frame.floor)):
        msg = (
            f"{path}: the map frame holds non-finite numbers; delete it and re-run "
            "`care fuse grid STORE` (with --up-axis/--floor-z if the automatic frame is wrong)"
        )
        raise StoreError(msg)
    return frame


class Store:
    """A complete store on disk; opening checks completeness, schema version and the store
    tables' columns (:func:`layout_problem`)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.meta = StoreMeta.read(self.path)
        bad = damaged(self.path, self.meta.tables, checksum=False)
        if bad:
            raise damaged_table(self.path / bad[0])
        for name in sorted(set(self.meta.tables) & set(_layouts())):
            # each table's footer: a column missing or unknown is one line naming the
            # table here, whatever reads the store, not a KeyError in the reader that needs it
            read_schema(self.path / name)

    @property
    def num_views(self) -> int:
        return self.meta.num_views

    @property
    def identity(self) -> str:
        """What the store is (:func:`store_identity`): the id its map frame records."""
        return store_identity(self.meta)

    @property
    def stamp(self) -> bytes:
        """What a map records of the store it was built from: the store's identity and its
        map frame. An ingest that changes the views or features, or another frame, makes
        every map stale; the same store copied to another directory or machine, or rebuilt
        to the same bytes, does not."""
        frame = self.map_frame
        if frame.is_identity:
            return self.identity.encode()
        matrix = ",".join(repr(float(v)) for v in frame.map_from_world.reshape(-1))
        return f"{self.identity}|{matrix}".encode()

    def verify(self) -> list[str]:
        """Messages about every damaged table of the store and its maps (empty: all whole).

        Compares each recorded table's size and checksum and reads every Parquet footer.
        """
        problems = [
            f"{self.path / name}: missing, truncated or altered since it was written; rebuild "
            f"it with {rebuild_hint(self.path, name)}"
            for name in damaged(self.path)
        ]
        try:
            self.map_frame  # noqa: B018 - reads and checks map_frame.json
        except StoreError as err:
            problems.append(str(err))
        named = {p.split(":")[0] for p in problems}
        for path in sorted(self.path.glob("*.parquet")):
            if str(path) in named:
                continue
            try:
                with reading(path):
                    pq.ParquetFile(path).metadata  # noqa: B018 - reads the footer
            except StoreError as err:
                problems.append(str(err))
        return problems

    def table_path(self, name: str) -> Path:
        return self.path / f"{name}.parquet"

    def views(self, columns: Sequence[str] | None = None) -> pa.Table:
        """The views table (pass ``columns`` to skip the image bytes)."""
        return read_table(self.table_path("views"), columns)

    @property
    def map_frame(self) -> MapFrame:
        """The store's gravity-aligned map frame (``map_frame.json``, written by the first
        fusion; the world frame itself until then)."""
        return read_map_frame(self.path, self.meta)

    def poses(self, *, in_map: bool = True) -> np.ndarray:
        """(V, 4, 4) camera poses in view order: camera-to-map (``in_map``), or camera-to-world
        as recorded."""
        col = self.views(["cam_to_world"]).column("cam_to_world").combine_chunks()
        poses = as_numpy(col.values).reshape(-1, 4, 4)
        frame = self.map_frame if in_map else None
        return poses if frame is None or frame.is_identity else frame.map_from_world @ poses

    def first_position(self) -> tuple[float, float] | None:
        """Where the recording starts: its first view's camera position on the floor (map
        x, y), the default start of paths and walks; None for a store without views."""
        if not self.table_path("views").is_file():
            return None
        poses = self.poses()
        return (float(poses[0, 0, 3]), float(poses[0, 1, 3])) if len(poses) else None

    def intrinsics(self) -> np.ndarray:
        """(V, 3, 3) intrinsics in view order."""
        col = self.views(["K"]).column("K").combine_chunks()
        return as_numpy(col.values).reshape(-1, 3, 3)

    def iter_frames(
        self,
        *,
        batch_size: int = BATCH_SIZE,
        extras: bool = True,
        view_ids: set[int] | None = None,
        in_map: bool = True,
    ) -> Iterator[tuple[int, Frame]]:
        """Decoded ``(view_id, Frame)`` pairs, streamed a row group at a time (only those of
        ``view_ids`` when given: the others are not decoded); poses in the map frame
        (``in_map``) or the recording's world frame."""
        path = self.table_path("views")
        encoding = self.views_encoding
        suffix = encoding.image_suffix
        frame = self.map_frame if in_map else MapFrame.identity()
        to_map = None if frame.is_identity else frame.map_from_world
        for batch in _batches(path, batch_size, view_ids=view_ids):
            if view_ids is not None:
                batch = batch.filter(pa.array(np.isin(batch.column("view_id"), list(view_ids))))
            for row in batch.to_pylist():
                w, h = row["width"], row["height"]
                extra = {
                    name: encoding.decode_image(row[f"{name}_{suffix}"], w, h)
                    for name in EXTRA_IMAGES
                    if extras and row.get(f"{name}_{suffix}") is not None
                }
                depth = encoding.decode_image(row[f"depth_{suffix}"], w, h)
                yield (
                    row["view_id"],
                    Frame(
                        stamp_ns=row["stamp_ns"],
                        rgb=decode_jpeg(row["rgb_jpeg"]),
                        depth_m=depth.astype(np.float32) * np.float32(row["depth_scale"]),
                        K=np.asarray(row["K"], dtype=np.float64).reshape(3, 3),
                        cam_to_world=_in_frame(to_map, row["cam_to_world"]),
                        extras=extra,
                    ),
                )

    @property
    def views_encoding(self) -> StoreEncoding:
        """How the views table's images are encoded (checked against the schema version)."""
        path = self.table_path("views")
        with reading(path):
            schema = pq.read_schema(path)
        _check_version(schema, path)
        return views_encoding(schema)

    def iter_depths(self, view_ids: set[int]) -> Iterator[EncodedDepth]:
        """The encoded depth images of ``view_ids`` with what decodes them, in view order:
        for a caller that decodes them on its own threads (:meth:`EncodedDepth.decode`)."""
        encoding = self.views_encoding
        column = f"depth_{encoding.image_suffix}"
        names = ["view_id", "width", "height", "depth_scale", "K", column]
        path = self.table_path("views")
        for batch in _batches(path, BATCH_SIZE, columns=names, view_ids=view_ids):
            for row in batch.to_pylist():
                if row["view_id"] in view_ids:
                    yield EncodedDepth(
                        row["view_id"], row[column], row["width"], row["height"],
                        row["depth_scale"], np.asarray(row["K"], np.float64).reshape(3, 3),
                        encoding,
                    )  # fmt: skip

    @property
    def encoder(self) -> EncoderInfo:
        path = self.table_path("features")
        if not path.is_file():
            msg = f"{self.path}: the store has no features; re-run `care ingest` with --encoder."
            raise StoreError(msg)
        with reading(path):
            return EncoderInfo.from_metadata(pq.read_schema(path).metadata or {})

    def iter_features(
        self, *, batch_size: int = BATCH_SIZE, view_ids: set[int] | None = None
    ) -> Iterator[tuple[int, np.ndarray]]:
        """``(view_id, feature map (fh, fw, d) float16)`` pairs, streamed (only those of
        ``view_ids`` when given)."""
        path = self.table_path("features")
        info = self.encoder
        with reading(path):
            schema = pq.read_schema(path)
        _check_version(schema, path)
        lists = features_encoding(schema) is StoreEncoding.PNG_LISTS
        for batch in _batches(path, batch_size, view_ids=view_ids):
            if view_ids is not None:
                batch = batch.filter(pa.array(np.isin(batch.column("view_id"), list(view_ids))))
            ids = batch.column("view_id").to_numpy()
            fh = batch.column("fh").to_numpy()
            fw = batch.column("fw").to_numpy()
            # one zero-copy view of the batch's values, sliced per row: a per-row
            # `feats[i].values.to_numpy()` cost more than reading the row (30 ms a view)
            feats = batch.column("feature")
            if lists:
                offsets = feats.offsets.to_numpy()
                values = feats.values.to_numpy(zero_copy_only=False)
            else:  # the bytes themselves, read in place: offsets in bytes, 2 a value
                _, ends, data = feats.buffers()
                offsets = np.frombuffer(ends, np.int32)[
                    feats.offset : feats.offset + len(feats) + 1
                ]
                offsets = offsets // 2
                values = np.frombuffer(data, "<f2") if data is not None else np.zeros(0, "<f2")
            for i in range(batch.num_rows):
                flat = values[offsets[i] : offsets[i + 1]]
                if flat.size != int(fh[i]) * int(fw[i]) * info.dim:
                    msg = (
                        f"{path}: view {int(ids[i])} holds {flat.size} feature values, not "
                        f"{int(fh[i])}x{int(fw[i])}x{info.dim} (the encoder's dimension); rebuild it "
                        f"with {rebuild_hint(self.path, 'features')}"
                    )
                    raise StoreError(msg)
                yield int(ids[i]), flat.reshape(int(fh[i]), int(fw[i]), info.dim)

    def text_embeddings(self) -> tuple[list[str], np.ndarray]:
        """Cached class names and their (n, d) float32 text embeddings."""
        path = self.table_path("text")
        table = read_table(path)
        names = table.column("name").to_pylist()
        emb = as_numpy(table.column("embedding").combine_chunks().values)
        emb = emb.reshape(len(names), -1).astype(np.float32)
        dim = None if self.meta.encoder is None else self.meta.encoder.dim
        if dim is not None and names and emb.shape[1] != dim:
            msg = (
                f"{path}: text embeddings of dimension {emb.shape[1]}, but the store's features "
                f"have {dim}; rebuild the store with {rebuild_hint(self.path, 'text')}"
            )
            raise StoreError(msg)
        return names, emb


@dataclass(frozen=True)
class EncodedDepth:
    """One view's depth as stored, with what decoding it needs (:meth:`Store.iter_depths`)."""

    view_id: int
    data: bytes
    width: int
    height: int
    scale: float
    K: np.ndarray
    encoding: StoreEncoding

    def decode(self) -> np.ndarray:
        """(H, W) float32 metres, 0 where invalid."""
        units = self.encoding.decode_image(self.data, self.width, self.height)
        return units.astype(np.float32) * np.float32(self.scale)


def _batches(
    path: Path,
    batch_size: int,
    columns: Sequence[str] | None = None,
    view_ids: Collection[int] | None = None,
) -> Iterator[pa.RecordBatch]:
    """:func:`iter_batches` of ``path``, a damaged row group becoming one line (not a
    traceback)."""
    with reading(path):
        it = iter_batches(path, batch_size, columns, view_ids)
    while True:
        with reading(path):
            batch = next(it, None)
        if batch is None:
            return
        yield batch
