"""Provenance end to end: every file knows what it was built from, and a file of another
store or build, or a table of another layout, is one line naming it.

Inputs are real: a dataset folder whose ``image/`` is a symbolic link (living-room frames),
and two stores of one sample-world recording ingested with different options, each with its
grid; the faults are what users do (a file copied from one store into another, a table
rewritten by hand with its checksum updated, a newer ``meta.json``).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from tests.support.faults import assert_fault

GRID_FILES = ("cells.parquet", "cell_views.parquet", "grid_rgb.png", "grid_obstacles.png",
              "map.pgm", "map.yaml")  # fmt: skip


@pytest.fixture(scope="module")
def stores(tmp_path_factory: pytest.TempPathFactory, recording: Path) -> Path:
    """Two stores of one recording, ``a`` every view and ``b`` every second one, each with
    its grid (read-only: tests copy them)."""
    from care_maps.fuse.grid import GridConfig, build_grid
    from care_maps.ingest.pipeline import IngestConfig, run_ingest
    from care_maps.ingest.select import FrameSelection
    from care_maps.runtime.execution import Execution

    root = tmp_path_factory.mktemp("provenance")
    run = Execution(workers=1, progress=False)
    for name, every in (("a", 1), ("b", 2)):
        config = IngestConfig(encoder="labels", select=FrameSelection(every=every))
        store = run_ingest(recording, root / name, config, run=run)
        build_grid(store, GridConfig(cell_size=0.1), run=run)
    return root


@pytest.fixture
def copy_store(stores: Path, tmp_path: Path) -> Callable[[str], Path]:
    def copy(name: str) -> Path:
        dst = tmp_path / name
        shutil.copytree(stores / name, dst)
        return dst

    return copy


def _errors(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("error: ")]


# -- a dataset folder shared by a link ------------------------------------------------------


def test_changed_image_behind_a_linked_folder_rebuilds_the_store(
    care, shared_data: Path, tmp_path: Path
) -> None:
    """``image/`` a link to shared storage: an image changed there makes the store stale."""
    source = shared_data / "rgbd" / "livingroom1_clean_micro"
    shared, folder = tmp_path / "shared_images", tmp_path / "living"
    shared.mkdir()
    (folder / "depth").mkdir(parents=True)
    for i in range(3):
        shutil.copy(source / "image" / f"{i:05d}.jpg", shared)
        shutil.copy(source / "depth" / f"{i:05d}.png", folder / "depth")
    lines = (source / "trajectory.log").read_text().splitlines()[:15]
    (folder / "trajectory.log").write_text("\n".join(lines) + "\n")
    shutil.copy(source / "camera_intrinsic.json", folder)
    (folder / "image").symlink_to(shared, target_is_directory=True)
    store = tmp_path / "store"
    assert care("ingest", folder, "--out", store)[0] == 0
    views = (store / "views.parquet").read_bytes()
    digest = json.loads((store / "meta.json").read_text())["source"]["blake2b"]
    shutil.copy(shared / "00002.jpg", shared / "00001.jpg")  # the shared image changes
    code, _, err = care("ingest", folder, "--out", store)
    assert code == 0, err
    assert json.loads((store / "meta.json").read_text())["source"]["blake2b"] != digest
    assert (store / "views.parquet").read_bytes() != views  # rebuilt with the new image


def test_fingerprint_follows_links_without_looping(tmp_path: Path) -> None:
    """A link back up the tree is entered once; a linked file is hashed by its content."""
    from care_maps.core.fingerprint import content_digest

    (tmp_path / "d" / "sub").mkdir(parents=True)
    (tmp_path / "d" / "sub" / "a.txt").write_text("a")
    (tmp_path / "d" / "sub" / "up").symlink_to(tmp_path / "d", target_is_directory=True)
    first = content_digest(tmp_path / "d")
    (tmp_path / "d" / "sub" / "a.txt").write_text("b")
    assert content_digest(tmp_path / "d") != first


# -- files of another store -----------------------------------------------------------------


def test_map_frame_of_another_store_is_refused(care, stores: Path, copy_store) -> None:
    store = copy_store("a")
    shutil.copy(stores / "b" / "map_frame.json", store / "map_frame.json")
    for args in (("check", store), ("query", store, "chair", "--map", "grid")):
        code, _, err = care(*args)
        line = assert_fault(code, err, r"map_frame\.json: a map frame found for another store")
        assert f"care fuse grid {store}" in line
    assert care("fuse", "grid", store, "--cell-size", "0.1")[0] == 0  # found again
    assert care("check", store)[0] == 0


@pytest.mark.parametrize("with_marker", [False, True], ids=["grid", "grid-and-marker"])
def test_whole_grid_of_another_store_is_refused(
    care, stores: Path, copy_store, with_marker: bool
) -> None:
    """The copied tables are named as another store's (not as damaged, and no intact file
    is named); ``care query`` refuses in one line even when the checksums were copied too."""
    store = copy_store("a")
    other = stores / "b"
    for name in GRID_FILES:
        shutil.copy(other / name, store / name)
    shutil.rmtree(store / "cells.query")
    shutil.copytree(other / "cells.query", store / "cells.query")
    if with_marker:
        shutil.copy(other / "care-output.json", store / "care-output.json")
    code, _, err = care("check", store)
    assert code == 1
    assert "Traceback" not in err
    named = {line.split(": ")[1] for line in _errors(err)}
    assert named == {f"{store}/cells.parquet", f"{store}/cell_views.parquet"}, err
    assert all("a map table of another store" in line for line in _errors(err)), err
    code, _, err = care("query", store, "chair", "--map", "grid")
    assert_fault(code, err, r"cells\.parquet: a map table of another store.*care fuse grid")
    assert care("fuse", "grid", store, "--cell-size", "0.1")[0] == 0
    assert care("check", store)[0] == 0


def test_query_cache_of_another_map_is_refused(care, copy_store) -> None:
    """A sidecar that does not describe its table is refused, not silently skipped, and
    ``care fuse grid`` writes it again."""
    store = copy_store("a")
    index = store / "cells.query" / "index.json"
    record = json.loads(index.read_text())
    index.write_text(json.dumps({**record, "fingerprint": "0" * 64}))
    for args in (("check", store), ("query", store, "chair", "--map", "grid")):
        code, _, err = care(*args)
        assert_fault(code, err, r"cells\.query: the query cache of another map")
    assert care("fuse", "grid", store, "--cell-size", "0.1")[0] == 0
    assert care("query", store, "chair", "--map", "grid")[0] == 0


# -- schema drift ---------------------------------------------------------------------------


def _rewrite_views(store: Path, change: Callable[[pa.Table], pa.Table]) -> None:
    """Rewrite ``views.parquet`` and record its new checksum, as a hand-made edit would."""
    from care_maps.core.outputs import file_digest

    path = store / "views.parquet"
    pq.write_table(change(pq.read_table(path)), path)
    meta = json.loads((store / "meta.json").read_text())
    meta["tables"]["views.parquet"] = file_digest(path)
    (store / "meta.json").write_text(json.dumps(meta, indent=2))


@pytest.mark.parametrize(
    ("change", "pattern"),
    [
        (lambda t: t.drop_columns(["depth_zstd"]), r"missing depth_zstd"),
        (lambda t: t.append_column("flow", pa.array([0] * t.num_rows)), r"unknown column flow"),
    ],
    ids=["missing-column", "unknown-column"],
)
def test_views_table_of_another_layout_is_one_line(
    care, copy_store, recording: Path, change, pattern: str
) -> None:
    store = copy_store("a")
    _rewrite_views(store, change)
    for args in (
        ("check", store),
        ("fuse", "grid", store, "--overwrite"),
        ("query", store, "chair", "--map", "grid"),
    ):
        code, _, err = care(*args)
        line = assert_fault(code, err, rf"views\.parquet: not a views table .*{pattern}")
        assert "care ingest" in line
        assert "--force" in line
    code, _, err = care("ingest", recording, "--out", store, "--encoder", "labels")
    assert code == 0, err
    assert care("check", store)[0] == 0  # rebuilt, not kept as up to date


def test_unknown_meta_version_is_one_line_naming_meta_json(
    care, copy_store, recording: Path
) -> None:
    store = copy_store("a")
    meta = json.loads((store / "meta.json").read_text())
    (store / "meta.json").write_text(json.dumps({**meta, "meta_version": 99}))
    for args in (("check", store), ("fuse", "grid", store), ("query", store, "chair")):
        code, _, err = care(*args)
        line = assert_fault(code, err, r"meta\.json: meta version 99, this program reads \d")
        assert "care ingest" in line
        assert "--force" in line
    assert care("ingest", recording, "--out", store, "--encoder", "labels")[0] == 0
    assert care("check", store)[0] == 0
