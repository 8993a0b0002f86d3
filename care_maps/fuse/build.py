"""The one skeleton of a map build, shared by the grid (:mod:`care_maps.fuse.grid`) and the instances
(:mod:`care_maps.fuse.instances`).

A map is a set of tables in the store directory, the main one (``cells`` / ``instances``)
committed last. Building one always goes the same way, and only here:

1. the store's map frame is fixed (:func:`care_maps.fuse.frame.ensure_map_frame`) and the vocabulary's
   text embeddings are read;
2. the map's metadata is assembled once (:meth:`MapSpec.metadata`, under the keys of
   :mod:`care_maps.fuse.keys`): the candidate metadata of :mod:`care_maps.fuse.measures`, the content stamp
   of the store, and the config it is built with, both as a fingerprint (the cache key)
   and as JSON (so a later command can reuse it);
3. an up-to-date map (every table present and whole, the same config, store and
   vocabulary) is returned as it is (:meth:`MapSpec.is_current`) unless the run's
   :attr:`care_maps.runtime.execution.Execution.overwrite` asks for a rebuild;
4. otherwise the builder writes each table to a staged temporary (:class:`StagedMap`), and
   the skeleton checks the main table against its declared columns
   (:data:`care_maps.fuse.schemas.MAP_SCHEMAS`, which :func:`care_maps.query.map.load_map` checks too), and a
   per-view table with a declared layout against it (:data:`care_maps.fuse.schemas.VIEW_TABLE_SCHEMAS`),
   and renames them into place in the declared order, the main table last, so an
   interrupted build leaves the previous map whole. A map whose tables are in another
   layout (an older program's) is not current: it is rebuilt.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from care_maps.core.errors import FuseError
from care_maps.core.fingerprint import canonical_json, config_json, fingerprint
from care_maps.core.keys import VOCABULARY_KEY
from care_maps.core.maps import MapKind
from care_maps.core.outputs import damaged, record_table, temporary
from care_maps.core.store import Store, read_schema
from care_maps.fuse.frame import ensure_map_frame, store_stamp
from care_maps.fuse.keys import STORE_KEY, build_key, config_json_key, config_key
from care_maps.fuse.measures import candidate_metadata
from care_maps.fuse.provenance import map_problems
from care_maps.fuse.schemas import (
    MAP_SCHEMAS,
    VIEW_TABLE_SCHEMAS,
    schema_problems,
    view_table_problems,
)
from care_maps.fuse.vocabulary import vocabulary_text
from care_maps.runtime.execution import Execution
from care_maps.runtime.threads import Work, threads_for

__all__ = [
    "STORE_KEY",
    "VOCABULARY_KEY",
    "MapBuild",
    "MapConfig",
    "MapSpec",
    "StagedMap",
    "build_map",
    "config_json_key",
    "config_key",
]


def update_config(metadata: dict[bytes, bytes], kind: str, **changes: Any) -> None:
    """Record in a map's ``metadata`` that its config now has ``changes`` (a recompute's new
    vocabulary or scale): the JSON and the fingerprint stay one another's."""
    fields = json.loads(metadata.get(config_json_key(kind), b"{}"))
    fields.update(changes)
    text = canonical_json(fields)
    metadata[config_json_key(kind)] = text.encode()
    metadata[config_key(kind)] = fingerprint(text, length=16).encode()


class MapConfig(Protocol):
    """What the skeleton needs of a map's config dataclass."""

    @property
    def vocabulary(self) -> tuple[str, ...] | None: ...
    @property
    def logit_scale(self) -> float: ...


@dataclass(frozen=True)
class MapSpec:
    """What a kind of map is made of: its tables, in commit order."""

    kind: MapKind
    """Which map: its name keys the ``care.<kind>.config`` metadata."""
    tables: tuple[str, ...]
    """Table names in commit order; the last one is the map's main table."""

    @property
    def table(self) -> str:
        return self.tables[-1]

    @property
    def schema(self) -> pa.Schema:
        """The declared columns of the main table (:data:`care_maps.fuse.schemas.MAP_SCHEMAS`)."""
        return MAP_SCHEMAS[self.kind]

    def config_json(self, config: Any) -> str:
        return config_json(config)

    def config_fingerprint(self, config: Any) -> str:
        """The cache key of ``config``: a hash of all its fields (each shapes the map)."""
        return fingerprint(self.config_json(config), length=16)

    def metadata(
        self, store: Store, config: MapConfig, vocabulary: tuple[str, ...]
    ) -> dict[bytes, bytes]:
        """Schema metadata of every table of the map built from ``store`` with ``config``:
        with the store's stamp and the build's id (:func:`care_maps.fuse.keys.build_key`), so each
        table says which store and which build it belongs to."""
        stamp = store_stamp(store)
        config_fp = self.config_fingerprint(config)
        return {
            **candidate_metadata(vocabulary, config.logit_scale, store.encoder.name),
            config_key(self.kind): config_fp.encode(),
            config_json_key(self.kind): self.config_json(config).encode(),
            STORE_KEY: stamp,
            build_key(self.kind): fingerprint(
                self.kind, config_fp, stamp.decode(), length=16
            ).encode(),
        }

    def is_current(self, store: Store, metadata: dict[bytes, bytes]) -> bool:
        """Whether the map in ``store`` has every table, whole, built from the same store,
        config and vocabulary as ``metadata`` describes."""
        paths = [store.table_path(n) for n in self.tables]
        if not all(p.is_file() for p in paths):
            return False
        if damaged(store.path, [p.name for p in paths]):  # a damaged map is rebuilt
            return False
        schema = read_schema(paths[-1])
        if schema_problems(schema, self.kind, paths[-1]) is not None:  # another layout: rebuilt
            return False
        for name, path in zip(self.tables, paths, strict=True):
            if name in VIEW_TABLE_SCHEMAS and view_table_problems(read_schema(path), name, path):
                return False
        found = schema.metadata or {}
        keys = (config_key(self.kind), STORE_KEY, VOCABULARY_KEY)
        if not all(found.get(k) == metadata[k] for k in keys):
            return False
        # every table of this one build, its query sidecar current: else rebuilt
        return not map_problems(store, self.kind)


class StagedMap:
    """The staged temporaries of a map's tables, renamed into place by :meth:`commit` in
    the spec's order (main table last); whatever is left uncommitted goes on exit."""

    def __init__(self, store: Store, spec: MapSpec) -> None:
        self.store, self.spec = store, spec
        self._staged: dict[str, Path] = {}

    def path(self, table: str) -> Path:
        """The temporary to write ``table`` to (not yet visible under its name)."""
        if table not in self.spec.tables:
            msg = f"{table!r} is not a table of the {self.spec.kind} map"
            raise ValueError(msg)
        final = self.store.table_path(table)
        tmp = temporary(final)
        self._staged[table] = tmp
        return tmp

    def commit(self) -> None:
        """Rename every staged table that was written into place, in commit order, once
        the main table is checked against its declared columns."""
        main = self._staged.get(self.spec.table)
        if main is None or not main.is_file():
            msg = f"{self.store.path}: the {self.spec.kind} build wrote no {self.spec.table} table"
            raise FuseError(msg)
        problem = schema_problems(
            pq.read_schema(main), self.spec.kind, self.store.table_path(self.spec.table)
        )
        for table, tmp in self._staged.items():
            if problem is None and table in VIEW_TABLE_SCHEMAS and tmp.is_file():
                final = self.store.table_path(table)
                problem = view_table_problems(pq.read_schema(tmp), table, final)
        if problem is not None:  # a writer out of step with the declaration: a bug
            msg = f"{problem}; the {self.spec.kind} writer does not match care_maps.fuse.schemas"
            raise FuseError(msg)
        for table in self.spec.tables:
            staged = self._staged.pop(table, None)
            if staged is None or not staged.is_file():
                continue
            final = self.store.table_path(table)
            staged.replace(final)
            record_table(final)

    def __enter__(self) -> StagedMap:
        return self

    def __exit__(self, *exc: object) -> None:
        for tmp in self._staged.values():
            tmp.unlink(missing_ok=True)
        self._staged.clear()


@dataclass(frozen=True)
class MapBuild:
    """What a builder gets to write a map: the store, the vocabulary and its (n, d) text
    embeddings, the metadata every table carries, and where to stage each table."""

    store: Store
    vocabulary: tuple[str, ...]
    text: np.ndarray
    metadata: dict[bytes, bytes]
    staged: StagedMap


def build_map(
    store_path: Path,
    spec: MapSpec,
    config: MapConfig,
    write: Callable[[MapBuild], None],
    *,
    run: Execution,
    after: Callable[[Store], None] | None = None,
) -> Path:
    """Build the ``spec`` map of the store with ``config`` unless it is current (and not
    ``run.overwrite``); returns the path of its main table.

    ``write`` stages every table of the map (:meth:`StagedMap.path`); the skeleton commits
    them. ``after`` runs once the tables are in place (images derived from them). Runs on
    the thread pools of :attr:`care_maps.runtime.threads.Work.FUSE` whoever calls it: the per-view class
    products round their last bits by BLAS's thread count, and a caller's pools (a notebook
    at every core) would otherwise change the map's bytes.
    """
    with threads_for(Work.FUSE):
        return _build_map(store_path, spec, config, write, run.overwrite, after)


def _build_map(
    store_path: Path,
    spec: MapSpec,
    config: MapConfig,
    write: Callable[[MapBuild], None],
    overwrite: bool,
    after: Callable[[Store], None] | None,
) -> Path:
    ensure_map_frame(store_path)  # the gravity-aligned frame every pose is read in
    store = Store(store_path)
    vocabulary, text = vocabulary_text(store, config.vocabulary)
    metadata = spec.metadata(store, config, tuple(vocabulary))
    if overwrite or not spec.is_current(store, metadata):
        with StagedMap(store, spec) as staged:
            write(MapBuild(store, tuple(vocabulary), text, metadata, staged))
            staged.commit()
        if after is not None:
            after(store)
    return store.table_path(spec.table)
