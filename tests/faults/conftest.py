"""The fault-injection suite's inputs.

Inputs are made with the real writers: a sample-world recording (MCAP through ``mcap``, with
ground truth) rendered once per session at 64x48 and 4 frames, bags through ``rosbags``
(:func:`tests.support.recordings.grey_bag`); faults are real: truncated and altered files,
``RLIMIT_FSIZE`` (the kernel refuses writes past the limit: a full disk as a process sees
it), ``SIGKILL`` mid-run, ``chmod`` (run without the DAC-override capability when the tests
run as root, so permissions bind).

Each fault asserts the five properties of :func:`tests.support.faults.assert_fault`: the exit
code, a single line on stderr, no traceback, nothing half-written (no temporary left) and
earlier good output intact; and then that a re-run succeeds.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.support.cli import InProcessCli
from tests.support.faults import eval_config


@pytest.fixture
def care(run_cli: InProcessCli, monkeypatch: pytest.MonkeyPatch) -> InProcessCli:
    """Run ``care ARGS`` in this process (fast): ``(exit code, stdout, stderr)``, without
    progress bars (tests/conftest.py's ``run_cli``)."""
    monkeypatch.setenv("TQDM_DISABLE", "1")
    return run_cli


@pytest.fixture(scope="session")
def world(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A sample-world dataset (1 scene, 4 frames, 64x48) with ground truth, rendered once."""
    from care_maps.world.record import DatasetConfig, make_dataset

    root = tmp_path_factory.mktemp("faults_world")
    make_dataset(
        DatasetConfig(
            out=root / "ds", scenes=1, seed=3, fmt="mcap", width=64, height=48, frames=4,
            num_rooms=1, workers=1,
        )
    )  # fmt: skip
    return root / "ds"


@pytest.fixture(scope="session")
def recording(world: Path) -> Path:
    return world / "scene_000.mcap"


@pytest.fixture(scope="session")
def good(tmp_path_factory: pytest.TempPathFactory, recording: Path) -> Path:
    """A store with both maps and an evaluation beside it, built once (read-only)."""
    from care_maps.evaluate.job import run_eval
    from care_maps.fuse.grid import GridConfig, build_grid
    from care_maps.fuse.instances import InstanceConfig, build_instances
    from care_maps.ingest.pipeline import IngestConfig, run_ingest
    from care_maps.runtime.execution import Execution

    root = tmp_path_factory.mktemp("faults_good")
    run = Execution(workers=1, progress=False)
    store = run_ingest(recording, root / "store", IngestConfig(encoder="labels"), run=run)
    build_grid(store, GridConfig(cell_size=0.1), run=run)
    build_instances(store, InstanceConfig(proposals="labels"), run=run)
    run_eval(store, eval_config(), root / "eval", run=run)
    return root


@pytest.fixture
def copy_good(good: Path, tmp_path: Path) -> Callable[[str], Path]:
    """A private copy of part of the good outputs (``store`` or ``eval``)."""

    def copy(name: str) -> Path:
        dst = tmp_path / name
        shutil.copytree(good / name, dst)
        return dst

    return copy
