"""Per-view features computed elsewhere (e.g. LSeg or OpenSeg on a GPU box), read by image stamp.

Why: the strongest dense open-vocabulary encoders need a GPU and their own environments.
Users run them where they can and hand us the maps; ingest then only looks them up.

File format (``--precomputed FEATURES.parquet``), one row per view:

==============  ============================  ==================================================
column          type                          meaning
==============  ============================  ==================================================
``stamp_ns``    int64                         stamp of the colour image the map was computed
                                              from (nanoseconds, as in the recording)
``fh``, ``fw``  any integer type              height and width of the feature map in cells
``feature``     list<float16> or list<float32> the (fh, fw, d) map flattened row-major; cell
                                              (i, j) covers image rows ``i*H/fh ..`` and columns
                                              ``j*W/fw ..`` of the whole (uncropped) image
==============  ============================  ==================================================

Optional schema metadata: ``care.encoder.name`` and ``care.encoder.version`` (e.g. ``lseg`` and
``demo_e200``) are recorded in the store as the features' provenance.

Text side: a sibling table ``FEATURES.text.parquet`` with columns ``name`` (string) and
``embedding`` (list<float>, length d) holds the class-name embeddings made by the same model;
:meth:`PrecomputedEncoder.encode_text` looks names up there (this encoder has no text model).

Write with modest row groups (``pq.write_table(table, path, row_group_size=64)``): only the
``stamp_ns`` column is read up front; features are read one row group at a time when a view
asks for them, so memory stays bounded by one row group whatever the file's length. Row groups
above :data:`MAX_ROW_GROUP_BYTES` are refused with a message saying how to rewrite the file.

A view matches the row whose stamp is nearest to its image stamp, within ``tolerance_ns``
(1 ms by default). Maps are re-normalised to unit length per cell on reading.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from care_maps.core.encoders.base import Encoder, EncoderOptions, l2_normalise
from care_maps.core.errors import EncoderError
from care_maps.core.frames import Frame
from care_maps.core.keys import ENCODER_NAME_KEY, ENCODER_VERSION_KEY

__all__ = [
    "MAX_ROW_GROUP_BYTES",
    "STAMP_TOLERANCE_NS",
    "PrecomputedEncoder",
    "lookup_text",
    "text_path_for",
]

STAMP_TOLERANCE_NS = 1_000_000
"""Largest |image stamp - feature stamp| accepted as the same view (1 ms)."""

MAX_ROW_GROUP_BYTES = 512 * 2**20
"""Largest uncompressed row group read at once; bigger ones would defeat streaming."""

_REQUIRED = ("stamp_ns", "fh", "fw", "feature")


def text_path_for(features_path: Path) -> Path:
    """Where the class-name embeddings of ``features_path`` live: ``<stem>.text.parquet``."""
    features_path = Path(features_path)
    return features_path.with_name(f"{features_path.stem}.text.parquet")


class PrecomputedEncoder(Encoder):
    """Looks up each view's feature map in ``options.precomputed`` by image stamp."""

    name = "precomputed"
    supports_crops = False

    def __init__(self, options: EncoderOptions, *, tolerance_ns: int = STAMP_TOLERANCE_NS) -> None:
        if options.precomputed is None:
            msg = "encoder 'precomputed' needs --precomputed FILE.parquet (per-view features by stamp)"
            raise EncoderError(msg)
        self.path = Path(options.precomputed)
        self.tolerance_ns = int(tolerance_ns)
        self._file = _open(self.path)
        self._check_schema(self._file.schema_arrow)
        self._index_stamps()
        self._check_row_groups()
        self._cache: tuple[int, pa.Table] | None = None
        self.dim = self._first_dim()
        md = self._file.schema_arrow.metadata or {}
        source = md.get(ENCODER_NAME_KEY, b"").decode()
        version = md.get(ENCODER_VERSION_KEY, b"").decode()
        # Provenance if the writer gave it; the file's name and size tell re-runs apart anyway.
        provenance = ":".join(p for p in (source, version) if p)
        self.version = (
            f"{provenance + '@' if provenance else ''}{self.path.name}:{self.path.stat().st_size}"
        )

    # -- set-up ----------------------------------------------------------------------------

    def _check_schema(self, schema: pa.Schema) -> None:
        missing = [c for c in _REQUIRED if c not in schema.names]
        if missing:
            msg = (
                f"{self.path}: no column {', '.join(missing)}; precomputed features need "
                f"{', '.join(_REQUIRED)} (columns present: {', '.join(schema.names)})."
            )
            raise EncoderError(msg)
        feature = schema.field("feature").type
        stamp = schema.field("stamp_ns").type
        if not (
            pa.types.is_list(feature) or pa.types.is_large_list(feature)
        ) or not pa.types.is_floating(feature.value_type):
            msg = f"{self.path}: column feature is {feature}, expected list<float16|float32>."
            raise EncoderError(msg)
        if not pa.types.is_integer(stamp):
            msg = f"{self.path}: column stamp_ns is {stamp}, expected int64 nanoseconds."
            raise EncoderError(msg)

    def _index_stamps(self) -> None:
        """Sorted stamps with (row group, row in group) of each: the only column read up front."""
        stamps, groups, rows = [], [], []
        for g in range(self._file.num_row_groups):
            col = self._file.read_row_group(g, columns=["stamp_ns"]).column(0)
            col = col.to_numpy().astype(np.int64)
            stamps.append(col)
            groups.append(np.full(len(col), g, np.int32))
            rows.append(np.arange(len(col), dtype=np.int64))
        stamp = np.concatenate(stamps) if stamps else np.zeros(0, np.int64)
        if stamp.size == 0:
            msg = f"{self.path}: no rows; it holds no precomputed features."
            raise EncoderError(msg)
        order = np.argsort(stamp, kind="stable")
        self._stamps = stamp[order]
        self._groups = np.concatenate(groups)[order]
        self._rows = np.concatenate(rows)[order]
        dup = np.flatnonzero(np.diff(self._stamps) == 0)
        if dup.size:
            msg = f"{self.path}: stamp {self._stamps[dup[0]]} ns appears twice; keep one row per view."
            raise EncoderError(msg)

    def _check_row_groups(self) -> None:
        meta = self._file.metadata
        for g in range(meta.num_row_groups):
            size = meta.row_group(g).total_byte_size
            if size > MAX_ROW_GROUP_BYTES:
                msg = (
                    f"{self.path}: row group {g} holds {size / 2**20:.0f} MiB, too much to read "
                    "per view; rewrite it with pq.write_table(table, path, row_group_size=64)."
                )
                raise EncoderError(msg)

    def _first_dim(self) -> int:
        table = self._row_group(int(self._groups[0]))
        row = int(self._rows[0])
        fh, fw = int(table.column("fh")[row].as_py()), int(table.column("fw")[row].as_py())
        length = len(table.column("feature")[row].values)
        if fh <= 0 or fw <= 0 or length % (fh * fw):
            msg = (
                f"{self.path}: stamp {int(self._stamps[0])}: feature of length {length} is not "
                f"fh * fw * d with fh={fh}, fw={fw}."
            )
            raise EncoderError(msg)
        return length // (fh * fw)

    # -- lookup ----------------------------------------------------------------------------

    def find(self, stamps_ns: np.ndarray) -> np.ndarray:
        """Position in the sorted index of the row nearest each stamp, or a clear error."""
        stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
        right = np.clip(np.searchsorted(self._stamps, stamps_ns), 0, len(self._stamps) - 1)
        left = np.clip(right - 1, 0, len(self._stamps) - 1)
        pick = np.where(
            np.abs(self._stamps[left] - stamps_ns) <= np.abs(self._stamps[right] - stamps_ns),
            left,
            right,
        )
        dt = np.abs(self._stamps[pick] - stamps_ns)
        bad = np.flatnonzero(dt > self.tolerance_ns)
        if bad.size:
            i = bad[0]
            msg = (
                f"{self.path}: no precomputed features for image stamp {int(stamps_ns[i])} ns "
                f"(nearest {int(self._stamps[pick[i]])} ns is {dt[i] / 1e6:.3f} ms away, "
                f"tolerance {self.tolerance_ns / 1e6:g} ms); compute features for every "
                "ingested view."
            )
            raise EncoderError(msg)
        return pick

    def _row_group(self, group: int) -> pa.Table:
        """One row group's maps, kept until the next group is needed (views come in order)."""
        if self._cache is None or self._cache[0] != group:
            table = self._file.read_row_group(group, columns=["fh", "fw", "feature"])
            self._cache = (group, table)
        return self._cache[1]

    def _map(self, pos: int) -> np.ndarray:
        table = self._row_group(int(self._groups[pos]))
        row = int(self._rows[pos])
        fh, fw = int(table.column("fh")[row].as_py()), int(table.column("fw")[row].as_py())
        flat = table.column("feature")[row].values.to_numpy(zero_copy_only=False)
        if flat.size != fh * fw * self.dim:
            msg = (
                f"{self.path}: stamp {int(self._stamps[pos])}: feature of length {flat.size}, "
                f"expected fh * fw * d = {fh} * {fw} * {self.dim}."
            )
            raise EncoderError(msg)
        return flat.reshape(fh, fw, self.dim)

    # -- Encoder ---------------------------------------------------------------------------

    def encode_views(self, frames: Sequence[Frame]) -> np.ndarray:
        """(B, fh, fw, d) float32 maps of the views' stamps, L2-normalised per cell."""
        if not frames:
            return np.zeros((0, 0, 0, self.dim), np.float32)
        pos = self.find(np.array([f.stamp_ns for f in frames], dtype=np.int64))
        maps = [self._map(int(p)) for p in pos]
        shapes = {m.shape for m in maps}
        if len(shapes) > 1:
            msg = f"{self.path}: feature maps of different shapes {sorted(shapes)} in one batch"
            raise EncoderError(msg)
        return l2_normalise(np.stack(maps).astype(np.float32))

    def encode_text(self, names: Sequence[str]) -> np.ndarray:
        """(n, d) embeddings of ``names`` from the sibling text table, L2-normalised."""
        path = text_path_for(self.path)
        if not path.is_file():
            msg = (
                f"{path}: no text embeddings beside {self.path.name}; write a table with columns "
                "name, embedding made by the same model (the precomputed encoder has no text side)."
            )
            raise EncoderError(msg)
        return lookup_text(path, names, self.dim)


def lookup_text(path: Path, names: Sequence[str], dim: int) -> np.ndarray:
    """(n, d) L2-normalised embeddings of ``names`` from a ``name, embedding`` table: the
    precomputed encoder's text side, also used on its own once a store exists."""
    table = _open(path).read()
    missing = [c for c in ("name", "embedding") if c not in table.column_names]
    if missing:
        msg = f"{path}: no column {', '.join(missing)}; it needs name and embedding."
        raise EncoderError(msg)
    known = {n: i for i, n in enumerate(table.column("name").to_pylist())}
    absent = [n for n in names if n not in known]
    if absent:
        shown = ", ".join(repr(n) for n in absent[:5])
        msg = f"{path}: no embedding for {shown}; add them, made by the model of the features."
        raise EncoderError(msg)
    emb = table.column("embedding").combine_chunks()
    lengths = np.diff(emb.offsets.to_numpy())
    if np.any(lengths != dim):
        msg = (
            f"{path}: embeddings of length {sorted(set(lengths.tolist()))}, features have d={dim}."
        )
        raise EncoderError(msg)
    matrix = emb.values.to_numpy(zero_copy_only=False).reshape(-1, dim)
    rows = np.array([known[n] for n in names], dtype=np.int64)
    return l2_normalise(matrix[rows].astype(np.float32)).reshape(len(names), dim)


def _open(path: Path) -> pq.ParquetFile:
    if not path.is_file():
        msg = f"{path}: no such file; pass --precomputed with a Parquet file of per-view features."
        raise EncoderError(msg)
    try:
        return pq.ParquetFile(path)
    except (pa.ArrowInvalid, OSError) as err:
        msg = f"{path}: not a readable Parquet file ({err}); see care_maps/core/encoders/precomputed.py for the format."
        raise EncoderError(msg) from err
