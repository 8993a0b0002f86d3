"""Which store and which build each map file belongs to, checked one way for ``care check``,
every reader of a map and the fusion's up-to-date test.

Every map table carries the stamp of the store it was built from (:data:`care_maps.fuse.keys.STORE_KEY`:
the store's identity and its map frame) and, but the shared scene cloud, the id of its
build (:func:`care_maps.fuse.keys.build_key`); the grid's query sidecar names its table's metadata
(:mod:`care_maps.fuse.sidecar`). Checksums in the store's marker tell a changed file from the one
written; these tell a whole, readable file of another store or another build (copied in, or
left over) from the map's own, and name *that* file and what rebuilds it. Only pyarrow and
the store are imported: readers of finished maps load this without the fusion.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from care_maps.core.errors import CareError, StoreError
from care_maps.core.maps import MapKind
from care_maps.core.outputs import rebuild_hint
from care_maps.core.store import Store
from care_maps.fuse.keys import STORE_KEY, build_key
from care_maps.fuse.layout import CELLS_TABLE
from care_maps.fuse.sidecar import sidecar_path, sidecar_problem

__all__ = ["MAIN_TABLES", "check_map_files", "map_problems", "table_problem"]

MAIN_TABLES: dict[MapKind, str] = {MapKind.INSTANCES: "instances", MapKind.GRID: CELLS_TABLE}
"""Map kind -> its main table's name (the one a query reads; the build id's reference)."""


def _metadata(path: Path) -> dict[bytes, bytes] | None:
    """A table's schema metadata; None when its footer cannot be read (damage: the
    checksum checks name it)."""
    try:
        return pq.read_schema(path).metadata or {}
    except (pa.ArrowException, OSError):
        return None


def _frame_is_own(store: Store) -> bool:
    """Whether the store's map frame can be read as its own (else its own line names it,
    and the maps are compared by the store's identity only)."""
    try:
        store.map_frame  # noqa: B018 - reads and checks map_frame.json
    except CareError:
        return False
    return True


def table_problem(store: Store, path: Path, metadata: dict[bytes, bytes]) -> str | None:
    """One line when the map table ``path`` (with ``metadata``) was built from another
    store, or in another map frame than the store's (None: from this store, as it is)."""
    hint = rebuild_hint(store.path, path.name)
    found = metadata.get(STORE_KEY)
    if found is None:
        # written by hand (``candidate_metadata``: a user's own candidates, a test's map):
        # it names no store, so none can be told apart from this one; the build ids and the
        # marker's checksums still guard it
        return None
    identity, _, _ = found.decode(errors="replace").partition("|")
    if identity != store.identity:
        return (
            f"{path}: a map table of another store (built from store {identity}; this store "
            f"is {store.identity}); rebuild it with {hint}"
        )
    if _frame_is_own(store) and found != store.stamp:
        return (
            f"{path}: built in another map frame than the store's map_frame.json; rebuild it "
            f"with {hint}"
        )
    return None


def _map_tables(store: Store) -> dict[str, dict[bytes, bytes]]:
    """Every readable map table of ``store`` (not the store's own tables) -> its metadata."""
    own = set(store.meta.tables)
    found = {}
    for path in sorted(store.path.glob("*.parquet")):
        if path.name not in own and (md := _metadata(path)) is not None:
            found[path.name] = md
    return found


def _problems(store: Store, kind: MapKind | None) -> list[tuple[Path, str]]:
    """``(file, line)`` for every map file of ``store`` (of ``kind``'s map only) that is not
    the map's own (:func:`map_problems`)."""
    tables = _map_tables(store)
    kinds = list(MapKind) if kind is None else [kind]
    found: list[tuple[Path, str]] = []
    for name, md in tables.items():
        kinds_of = [k for k in MapKind if build_key(k) in md or name == f"{MAIN_TABLES[k]}.parquet"]
        if kind is not None and kind not in kinds_of:  # another map's (or the cloud)
            continue
        if problem := table_problem(store, store.path / name, md):
            found.append((store.path / name, problem))
    for k in kinds:
        main = f"{MAIN_TABLES[k]}.parquet"
        key = build_key(k)
        if main not in tables:  # no main table to compare with (missing or damaged: named so)
            continue
        build = tables[main].get(key)
        for name, md in tables.items():
            path = store.path / name
            if build is None or name == main or key not in md or md[key] == build:
                continue
            if path in dict(found):
                continue
            found.append(
                (
                    path,
                    f"{path}: from another build of the {k} map than {main} (copied, or left "
                    f"by an earlier one); rebuild it with {rebuild_hint(store.path, name)}",
                )
            )
        if line := sidecar_problem(store.path / main, tables[main]):
            found.append((sidecar_path(store.path / main), line))
    return found


def map_problems(store: Store, kind: MapKind | None = None) -> list[str]:
    """One line per map file of ``store`` (of ``kind``'s map only, when given) that belongs
    to another store, another map frame or another build, or a query sidecar of another map
    (empty: every one is the map's own)."""
    return [line for _, line in _problems(store, kind)]


def check_map_files(
    store: Store,
    names: Iterable[str],
    *,
    sidecar: bool = True,
    error: type[CareError] = StoreError,
) -> None:
    """Refuse, in one line naming it, the first of the map tables ``names`` (``cells``,
    ``cell_views``, ...) a reader is about to use that belongs to another store, frame or
    build, or (``sidecar``) the query sidecar of one of them that belongs to another map, as
    the caller's ``error``."""
    wanted = {store.table_path(name) for name in names}
    if sidecar:
        wanted |= {sidecar_path(path) for path in wanted}
    for path, line in _problems(store, None):
        if path in wanted:
            raise error(line)
