"""Per-view features computed elsewhere (e.g. LSeg or a big CLIP on a GPU box), read back by stamp.

File format (one Parquet file, written by any tool)::

    stamp_ns  int64              stamp of the colour image the features belong to
    fh, fw    int16/int32        feature-map height and width
    feature   list<float16|32>   the (fh, fw, d) map flattened row-major

plus, for the text side, a sibling ``<stem>.text.parquet`` with ``name`` (string) and
``embedding`` (list<float>) rows: the same model's class-name embeddings. Features need not
be normalised; they are L2-normalised per cell on the way in, as every encoder's are.

Why an index instead of a table load: a precomputed file for a long recording is as large
as the store itself. Only the ``stamp_ns`` column is read up front; feature rows are read a
row group at a time when a view asks for them, and the last row group is kept because
views arrive in stamp order.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from care.encoders.base import Encoder, EncoderOptions, l2_normalise
from care.errors import EncoderError
from care.frames import Frame

__all__ = ["STAMP_TOLERANCE_NS", "PrecomputedEncoder", "text_path_for"]

STAMP_TOLERANCE_NS = 1_000_000
"""A view matches a feature row whose stamp is within 1 ms of its own."""


def text_path_for(path: Path) -> Path:
    """Where the text embeddings of a precomputed feature file live."""
    return path.with_name(f"{path.stem}.text.parquet")


class PrecomputedEncoder(Encoder):
    """Reads ``options.precomputed``; see the module docstring for the format."""

    name = "precomputed"

    def __init__(self, options: EncoderOptions) -> None:
        if options.precomputed is None:
            msg = "encoder 'precomputed' needs the feature file: pass --precomputed FILE.parquet"
            raise EncoderError(msg)
        self.path = Path(options.precomputed)
        try:
            self._file = pq.ParquetFile(self.path)
        except (OSError, ValueError) as err:
            msg = f"{self.path}: cannot read precomputed features ({err}); pass a Parquet file"
            raise EncoderError(msg) from err
        missing = {"stamp_ns", "fh", "fw", "feature"} - set(self._file.schema_arrow.names)
        if missing:
            msg = f"{self.path}: missing column(s) {sorted(missing)}; see care/encoders/precomputed.py"
            raise EncoderError(msg)
        self._stamps, self._group, self._row = self._index()
        first = self._read_row(0)
        self.dim = int(first.shape[2])
        self.version = f"{self.path.name}:{self.path.stat().st_size}"
        self._cached: tuple[int, object] | None = None

    def _index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stamps sorted, with the row group and row within it of each."""
        stamps, groups, rows = [], [], []
        for g in range(self._file.num_row_groups):
            s = self._file.read_row_group(g, columns=["stamp_ns"]).column(0).to_numpy()
            stamps.append(s)
            groups.append(np.full(len(s), g))
            rows.append(np.arange(len(s)))
        if not stamps or sum(len(s) for s in stamps) == 0:
            msg = f"{self.path}: no feature rows"
            raise EncoderError(msg)
        stamp = np.concatenate(stamps).astype(np.int64)
        order = np.argsort(stamp, kind="stable")
        return stamp[order], np.concatenate(groups)[order], np.concatenate(rows)[order]

    def _read_row(self, i: int) -> np.ndarray:
        g, r = int(self._group[i]), int(self._row[i])
        if getattr(self, "_cached", None) is None or self._cached[0] != g:
            self._cached = (g, self._file.read_row_group(g, columns=["fh", "fw", "feature"]))
        table = self._cached[1]
        fh = int(table.column("fh")[r].as_py())
        fw = int(table.column("fw")[r].as_py())
        flat = table.column("feature")[r].values.to_numpy(zero_copy_only=False)
        if flat.size % (fh * fw):
            msg = f"{self.path}: row of stamp {self._stamps[i]} has {flat.size} values, not a multiple of fh*fw={fh * fw}"
            raise EncoderError(msg)
        return flat.astype(np.float32).reshape(fh, fw, -1)

    def _lookup(self, stamp_ns: int) -> int:
        j = int(np.searchsorted(self._stamps, stamp_ns))
        near = [k for k in (j - 1, j) if 0 <= k < len(self._stamps)]
        best = min(near, key=lambda k: abs(int(self._stamps[k]) - stamp_ns))
        if abs(int(self._stamps[best]) - stamp_ns) > STAMP_TOLERANCE_NS:
            msg = (
                f"{self.path}: no features for the view stamped {stamp_ns} ns (nearest "
                f"{int(self._stamps[best])} ns); compute features for every colour frame"
            )
            raise EncoderError(msg)
        return best

    def encode_views(self, frames: Sequence[Frame]) -> np.ndarray:
        """The stored maps of the given views, L2-normalised per cell."""
        maps = [self._read_row(self._lookup(int(f.stamp_ns))) for f in frames]
        if len({m.shape for m in maps}) > 1:
            msg = f"{self.path}: feature maps of different shapes {sorted({m.shape for m in maps})}"
            raise EncoderError(msg)
        if not maps:
            return np.zeros((0, 0, 0, self.dim), np.float32)
        return l2_normalise(np.stack(maps)).astype(np.float32)

    def encode_text(self, names: Sequence[str]) -> np.ndarray:
        """Embeddings of ``names`` looked up in the sibling ``.text.parquet``."""
        text_path = text_path_for(self.path)
        if not text_path.is_file():
            msg = f"{text_path}: missing; the precomputed encoder's text side needs the class-name embeddings (name, embedding)"
            raise EncoderError(msg)
        table = pq.read_table(text_path, columns=["name", "embedding"])
        index = {n: i for i, n in enumerate(table.column("name").to_pylist())}
        absent = [n for n in names if n not in index]
        if absent:
            msg = f"{text_path}: no embedding for {absent[:5]}{' ...' if len(absent) > 5 else ''}; add them or use its vocabulary"
            raise EncoderError(msg)
        emb = table.column("embedding").combine_chunks().values.to_numpy(zero_copy_only=False)
        emb = emb.reshape(len(index), -1).astype(np.float32)
        return l2_normalise(emb[[index[n] for n in names]])
