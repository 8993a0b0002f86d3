"""The query sidecar of a map table: ``<table>.query/``, raw arrays a query memory-maps.

``cells.parquet`` stays the map's one table (compressed, readable by any Parquet reader).
Next to it the fusion writes what a whole-building query needs without decoding it, as
``.npy`` files that :func:`numpy.load` memory-maps (opening costs a header; pages are read
when a query touches them):

- ``log_confidence.npy``: (n, N) float32, class-major: row y is ``log P_c[y]`` of every
  candidate by :func:`care_maps.fuse.measures.log_confidence` (near-certain candidates keep distinct
  values), so a vocabulary query reads one contiguous 4N-byte row instead of multiplying
  every (N, d) feature;
- ``feature.npy`` (N, d) float16 and ``top_classes.npy`` (N, K) int16: the table's values,
  for queries that need features and for the top-k category criterion.

``index.json``, written last, names the map table metadata it belongs to
(:func:`fingerprint`: the store's stamp, the config and the vocabulary), so a sidecar of
another map (left over, or copied from another store) is never used: the reader refuses it
in one line naming it (:func:`sidecar_problem`), and ``care fuse grid`` rebuilds it. An
unfinished one never has the sidecar's name.
"""

from __future__ import annotations

import contextlib
import json
import shutil
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pyarrow as pa

from care_maps.core.errors import StoreError
from care_maps.core.fingerprint import fingerprint as content_fingerprint
from care_maps.core.keys import LOGIT_SCALE_KEY, VOCABULARY_KEY
from care_maps.core.maps import MapKind
from care_maps.core.outputs import rebuild_hint, temporary
from care_maps.core.store import as_numpy
from care_maps.fuse.keys import STORE_KEY, config_key

__all__ = [
    "FINGERPRINT_KEYS",
    "SidecarWriter",
    "fingerprint",
    "read_sidecar",
    "sidecar_path",
    "sidecar_problem",
]

FINGERPRINT_KEYS = (
    VOCABULARY_KEY,
    LOGIT_SCALE_KEY,
    config_key(MapKind.GRID),
    config_key(MapKind.INSTANCES),
    STORE_KEY,
)
"""Metadata of the map table that a sidecar must share to describe the same map."""

_INDEX = "index.json"


def sidecar_path(table_path: Path) -> Path:
    """``cells.parquet`` -> ``cells.query/``."""
    table_path = Path(table_path)
    return table_path.with_name(f"{table_path.stem}.query")


def fingerprint(metadata: dict[bytes, bytes]) -> str:
    """The map table metadata a sidecar must match, as one hash (:mod:`care_maps.core.fingerprint`)."""
    return content_fingerprint({k.decode(): metadata.get(k, b"") for k in FINGERPRINT_KEYS})


def _npy(path: Path, dtype: str, shape: tuple[int, ...]) -> BinaryIO:
    out = path.open("wb")
    header = {"descr": np.dtype(dtype).str, "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_2_0(out, header)
    return out


class SidecarWriter:
    """Writes a sidecar chunk by chunk (rows in candidate order) into a temporary folder,
    renamed into place by :meth:`commit`; :meth:`abort` removes an unfinished one."""

    def __init__(
        self,
        path: Path,
        num_candidates: int,
        dim: int,
        num_top: int,
        num_classes: int,
        metadata: dict[bytes, bytes],
    ) -> None:
        self.path = Path(path)
        self.tmp = temporary(self.path)
        shutil.rmtree(self.tmp, ignore_errors=True)
        self.tmp.mkdir(parents=True)
        self.n, self.dim, self.num_top, self.num_classes = num_candidates, dim, num_top, num_classes
        self.fingerprint = fingerprint(metadata)
        self._files: list[BinaryIO] = []
        try:
            self._feature = self._open("feature.npy", "<f2", (num_candidates, dim))
            self._top = self._open("top_classes.npy", "<i2", (num_candidates, num_top))
            self._logp = self._open("log_confidence.npy", "<f4", (num_classes, num_candidates))
        except BaseException:  # a full disk at the first header: nothing left behind
            self.abort()
            raise
        self._logp_start = self._logp.tell()
        self._rows = 0

    def _open(self, name: str, dtype: str, shape: tuple[int, ...]) -> BinaryIO:
        out = _npy(self.tmp / name, dtype, shape)
        self._files.append(out)
        return out

    def write(self, chunk: pa.Table) -> None:
        """Take ``feature``, ``top_classes`` and ``log_confidence`` from the next chunk of
        :func:`care_maps.fuse.measures.candidate_columns` (``with_log_confidence=True``)."""
        n = chunk.num_rows
        for name, out, dtype in (
            ("feature", self._feature, "<f2"),
            ("top_classes", self._top, "<i2"),
        ):
            values = as_numpy(chunk.column(name).combine_chunks().flatten())
            out.write(np.ascontiguousarray(values, dtype=dtype).tobytes())
        if self.num_classes == 0:
            self._rows += n
            return
        logp = as_numpy(chunk.column("log_confidence").combine_chunks().flatten())
        logp = logp.reshape(n, self.num_classes).astype("<f4")
        for y in range(self.num_classes):  # class-major: one seek per class and chunk
            self._logp.seek(self._logp_start + 4 * (y * self.n + self._rows))
            self._logp.write(np.ascontiguousarray(logp[:, y]).tobytes())
        self._rows += n

    def _close(self) -> None:
        """Close every file; the first error (a full disk flushing a buffer) is raised once
        all are closed."""
        first: OSError | None = None
        for f in self._files:
            try:
                f.close()
            except OSError as err:
                first = first or err
        if first is not None:
            raise first

    def commit(self) -> None:
        """Finish the files and rename the folder into place (replacing an older one)."""
        self._close()
        if self._rows != self.n:
            msg = f"sidecar got {self._rows} rows of {self.n}"
            raise RuntimeError(msg)
        index = {"fingerprint": self.fingerprint, "num_candidates": self.n}
        (self.tmp / _INDEX).write_text(json.dumps(index, sort_keys=True))
        shutil.rmtree(self.path, ignore_errors=True)
        self.tmp.replace(self.path)

    def abort(self) -> None:
        """Drop an unfinished sidecar (a no-op after :meth:`commit`). Never raises: it runs
        while another error (a full disk) leaves, and closing a file whose buffer cannot be
        flushed fails again; the folder goes all the same."""
        with contextlib.suppress(OSError):
            self._close()
        shutil.rmtree(self.tmp, ignore_errors=True)


def _open_sidecar(folder: Path, metadata: dict[bytes, bytes]) -> dict[str, np.ndarray] | str:
    """The sidecar's memory-mapped arrays, or why they do not describe the map table of
    ``metadata``."""
    try:
        index = json.loads((folder / _INDEX).read_text())
    except (OSError, ValueError) as err:
        return f"no readable {_INDEX} ({err.__class__.__name__})"
    if not isinstance(index, dict) or index.get("fingerprint") != fingerprint(metadata):
        return "the query cache of another map (another store, build or vocabulary)"
    try:
        out = {
            name: np.load(folder / f"{name}.npy", mmap_mode="r")
            for name in ("feature", "top_classes", "log_confidence")
        }
    except (OSError, ValueError) as err:
        return f"unreadable arrays ({str(err).splitlines()[0][:120]})"
    n = int(index.get("num_candidates", -1))
    if len(out["feature"]) != n or out["log_confidence"].shape[1:] != (n,):
        return f"arrays of other sizes than the {n} candidates its index names"
    return out


def sidecar_problem(table_path: Path, metadata: dict[bytes, bytes]) -> str | None:
    """One line on ``table_path``'s sidecar when there is one that does not describe the
    table of ``metadata`` (None: none, or a current one), naming it and what rebuilds it."""
    folder = sidecar_path(table_path)
    if not folder.is_dir():
        return None
    found = _open_sidecar(folder, metadata)
    return _line(folder, Path(table_path), found) if isinstance(found, str) else None


def _line(folder: Path, table: Path, why: str) -> str:
    return f"{folder}: {why}, not of {table.name}; rebuild it with {rebuild_hint(table.parent, table.name)}"


def read_sidecar(table_path: Path, metadata: dict[bytes, bytes]) -> dict[str, np.ndarray] | None:
    """The memory-mapped arrays of ``table_path``'s sidecar, or None when there is none (a
    map made without one, or a recompute cut short before writing it). One that belongs to
    another version of the map is refused (:func:`sidecar_problem`), not ignored: it is a
    file of the map that is not what the map says."""
    folder = sidecar_path(table_path)
    if not folder.is_dir():
        return None
    found = _open_sidecar(folder, metadata)
    if isinstance(found, str):
        raise StoreError(_line(folder, Path(table_path), found))
    return found
