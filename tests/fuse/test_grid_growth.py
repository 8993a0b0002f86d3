"""A grid grows with the runs appended to its store: its saved state takes the new views alone,
and the map is the one a build from every view makes, byte for byte (the reference: a second
store of the same two runs, fused from scratch in the same map frame). Anything the state
cannot vouch for (another config, a rebuild asked for, a state too large for one pass, a
damaged state file) builds from every view instead, to the same bytes.

The runs are the third-party living-room frames written by the real writers: the first as a
ROS 1 bag, the second, which sees the first's last places again, as an MCAP file."""

from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest

import care_maps.fuse.grid as grid
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.fuse.grid_state import STATE_FILE
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.runs import RunOptions
from care_maps.runtime.execution import Execution
from tests.support.encoders import TinyEncoder
from tests.support.frames import load_livingroom
from tests.support.recordings import Container, robot_messages, write_bag

pytestmark = pytest.mark.slow

CONFIG = IngestConfig(vocabulary="tv,sofa,table,lamp,floor")
GRID = GridConfig(cell_size=0.05, stride=2)
MAP_FILES = (
    "cells.parquet",
    "cell_views.parquet",
    "grid_rgb.png",
    "grid_obstacles.png",
    "map.pgm",
    "map.yaml",
)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory, livingroom_root: Path) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("growth")
    frames = load_livingroom(livingroom_root, 12)
    return (
        write_bag(folder / "day1.bag", robot_messages(frames[0:8]), Container.ROS1),
        write_bag(folder / "day2.mcap", robot_messages(frames[4:12]), Container.MCAP),
    )


def _ingest(recording: Path, store: Path, *, append: bool = False) -> Path:
    return run_ingest(
        recording, store, CONFIG, encoder=TinyEncoder(), placement=RunOptions(append=append)
    )


@pytest.fixture
def grew(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The number of views each grid build added to a saved state (0: built from nothing)."""
    added: list[int] = []
    growth = grid._growth

    def spy(*args, **kwargs):
        found = growth(*args, **kwargs)
        added.append(0 if found is None else len(found[0].views))
        return found

    monkeypatch.setattr(grid, "_growth", spy)
    return added


def _reference(runs: tuple[Path, Path], grown: Path, out: Path, config: GridConfig) -> Path:
    """The same two runs in a store of their own, fused from every view in ``grown``'s map
    frame (the frame is the first run's: the grid grew in it)."""
    store = _ingest(runs[0], out)
    _ingest(runs[1], store, append=True)
    shutil.copy(grown / "map_frame.json", store / "map_frame.json")  # same store bytes: same id
    build_grid(store, config)
    return store


def _same_map(a: Path, b: Path, *, by_value: bool = False) -> None:
    """The grid files of ``a`` and ``b`` are the same bytes (``by_value``: the Parquet
    tables hold the same values and metadata, their row groups cut elsewhere, as a build in
    several passes cuts them)."""
    for name in MAP_FILES:
        if by_value and name.endswith(".parquet"):
            left, right = pq.read_table(a / name), pq.read_table(b / name)
            assert left.equals(right, check_metadata=True), name
            continue
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    query = sorted(p.name for p in (a / "cells.query").iterdir())
    assert query == sorted(p.name for p in (b / "cells.query").iterdir())
    for name in query:
        assert (a / "cells.query" / name).read_bytes() == (b / "cells.query" / name).read_bytes()


def test_a_grown_grid_is_the_grid_of_every_view(
    runs: tuple[Path, Path], tmp_path: Path, grew: list[int]
) -> None:
    store = _ingest(runs[0], tmp_path / "grown")
    build_grid(store, GRID)
    assert (store / STATE_FILE).is_file()
    _ingest(runs[1], store, append=True)
    build_grid(store, GRID)
    assert grew == [0, 8]  # the second build took the second run's 8 views alone
    reference = _reference(runs, store, tmp_path / "reference", GRID)
    _same_map(store, reference)
    build_grid(store, GRID)  # current: nothing built
    assert grew == [0, 8, 0]


@pytest.mark.parametrize(
    ("config", "run"),
    [
        (GridConfig(cell_size=0.1, stride=2), Execution()),  # another config: another map
        (GRID, Execution(overwrite=True)),  # a rebuild asked for
        (GRID, Execution(cells_per_pass=128)),  # no state kept: more cells than one pass
        (GRID, Execution(growth_state=False)),  # no state kept: asked for
    ],
    ids=["config", "overwrite", "passes", "no-state"],
)
def test_what_the_state_cannot_vouch_for_is_built_from_every_view(
    runs: tuple[Path, Path], tmp_path: Path, grew: list[int], config: GridConfig, run: Execution
) -> None:
    store = _ingest(runs[0], tmp_path / "grown")
    first = Execution(cells_per_pass=run.cells_per_pass, growth_state=run.growth_state)
    build_grid(store, GRID, run=first)
    assert (store / STATE_FILE).is_file() == (run.cells_per_pass is None and run.growth_state)
    _ingest(runs[1], store, append=True)
    build_grid(store, config, run=run)
    assert grew[-1] == 0
    reference = _reference(runs, store, tmp_path / "reference", config)
    _same_map(store, reference, by_value=run.cells_per_pass is not None)


def test_other_text_embeddings_of_the_same_names_are_built_from_every_view(
    runs: tuple[Path, Path], tmp_path: Path, grew: list[int], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The vocabulary's names alone do not pin a state: embedded otherwise (other weights
    for a name the store does not cache), the grid is built from every view."""
    import care_maps.fuse.build as build

    store = _ingest(runs[0], tmp_path / "grown")
    build_grid(store, GRID)
    _ingest(runs[1], store, append=True)
    embed = build.vocabulary_text

    def other(*args, **kwargs):
        names, text = embed(*args, **kwargs)
        return names, text[::-1].copy()  # the same names, their embeddings swapped round

    monkeypatch.setattr(build, "vocabulary_text", other)
    build_grid(store, GRID)
    assert grew == [0, 0]


def test_a_damaged_state_is_not_used(
    runs: tuple[Path, Path], tmp_path: Path, grew: list[int]
) -> None:
    store = _ingest(runs[0], tmp_path / "grown")
    build_grid(store, GRID)
    state = store / STATE_FILE
    data = bytearray(state.read_bytes())
    data[len(data) // 2] ^= 0xFF
    state.write_bytes(bytes(data))
    _ingest(runs[1], store, append=True)
    build_grid(store, GRID)
    assert grew[-1] == 0
    _same_map(store, _reference(runs, store, tmp_path / "reference", GRID))


def test_a_store_rebuilt_from_one_run_drops_the_grid(
    runs: tuple[Path, Path], tmp_path: Path
) -> None:
    store = _ingest(runs[0], tmp_path / "grown")
    _ingest(runs[1], store, append=True)
    build_grid(store, GRID)
    run_ingest(runs[1], store, CONFIG, encoder=TinyEncoder())  # the store replaced by one run
    assert not (store / "cells.parquet").exists()
    assert not (store / STATE_FILE).exists()


@pytest.mark.parametrize(("offset", "value"), [(8, 0x01), (10, 99)], ids=["encrypted", "method"])
def test_a_state_damaged_in_its_zip_directory_reads_as_none(
    tmp_path: Path, offset: int, value: int
) -> None:
    """The first member's flags marked encrypted, or its compression method made unknown, in
    the zip's central directory (zipfile then raises RuntimeError or NotImplementedError,
    not BadZipFile): no state, and the grid is rebuilt."""
    import numpy as np

    from care_maps.fuse.grid_state import load_state

    path = tmp_path / STATE_FILE
    np.savez(path, build=np.frombuffer(b"id", np.uint8), keys=np.arange(3))
    data = bytearray(path.read_bytes())
    data[data.index(b"PK\x01\x02") + offset] = value  # the central directory's first entry
    path.write_bytes(bytes(data))
    assert load_state(path) is None
