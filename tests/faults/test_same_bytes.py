"""The same input gives the same bytes in every output file: no time, date, host or pid
is written (timings go to the terminal). Each command that writes files runs twice into two
folders, and the folders are compared file by file.

Rerun's ``.rrd`` files are the one exception the SDK imposes: each row carries a row id
(a time-ordered unique id) and the wall-clock ``log_time`` timeline, the recording its
start time, and the SDK's batcher cuts rows into chunks by timing; no SDK option removes
them. A blueprint's store id is a fresh random one too (its views' and containers' ids are
derived from their place, ``care_maps.core.viz.send_blueprint``). Those files are compared by what they
hold: every row of every entity, its timelines (``stamp``, ``query``, ...) and components,
the recording's and the blueprint's, the same."""

from __future__ import annotations

from pathlib import Path

import pytest

TINY = ("--scenes", "1", "--seed", "11", "--rooms", "1", "--width", "32", "--height", "24",
        "--frames", "2", "--workers", "1")  # fmt: skip
RUN_OF_RERUN = ("rerun.controls.RowId", "log_time", "RecordingInfo:start_time")
"""Columns the Rerun SDK fills from the clock in every ``.rrd``."""


def _rrd_rows(path: Path) -> list[str]:
    """Every row of an ``.rrd`` (recording and blueprint), as text, without the SDK's
    run-dependent columns, in a fixed order (the chunking is the batcher's)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    rows = []
    for store in [*reader.recordings(), *reader.blueprints()]:
        for chunk in reader.stream(store=store):
            for row in chunk.to_record_batch().to_pylist():
                kept = sorted((k, v) for k, v in row.items()
                              if k not in RUN_OF_RERUN and v is not None)  # fmt: skip
                rows.append(repr((store.kind, str(chunk.entity_path), kept)))
    return sorted(rows)


def _files(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def _same(a: Path, b: Path) -> None:
    first, second = _files(a), _files(b)
    assert first.keys() == second.keys()
    differ = [k for k in first if first[k] != second[k]]
    assert [k for k in differ if not k.endswith(".rrd")] == []
    for name in differ:  # an .rrd: the same rows
        assert _rrd_rows(a / name) == _rrd_rows(b / name), name


def test_sample_make_twice_same_bytes(care, tmp_path: Path) -> None:
    for run in ("a", "b"):
        code, out, err = care("sample", "make", *TINY, "--out", tmp_path / run / "ds",
                              "--rrd", tmp_path / run / "ds.rrd")  # fmt: skip
        assert code == 0, err
        assert "CLIP likeness" in out  # the measurement ran (its time printed, not written)
    _same(tmp_path / "a", tmp_path / "b")


def test_ingest_twice_same_bytes(care, recording: Path, tmp_path: Path) -> None:
    for run in ("a", "b"):
        code, _, err = care("ingest", recording, "--out", tmp_path / run / "store",
                            "--rrd", tmp_path / run / "ingest.rrd")  # fmt: skip
        assert code == 0, err
    _same(tmp_path / "a", tmp_path / "b")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A dataset with ground truth large enough for both maps and an evaluation."""
    from care_maps.world.record import DatasetConfig, make_dataset

    root = tmp_path_factory.mktemp("same_bytes")
    make_dataset(
        DatasetConfig(
            out=root / "ds", scenes=1, seed=11, fmt="mcap", width=64, height=48, frames=12,
            num_rooms=1, workers=1,
        )
    )  # fmt: skip
    return root / "ds"


@pytest.mark.slow
def test_run_twice_same_bytes(care, dataset: Path, tmp_path: Path) -> None:
    """``care run``: stores, both maps, their query caches, the evaluation's tables, plots and
    ``results.md``, and the four Rerun files per scene. Then every command that writes a file
    from a store: ``care query --batch --out`` and the ``--rrd`` of query, replan and explore."""
    for run in ("a", "b"):
        out = tmp_path / run
        code, _, err = care("run", dataset, "--out", out / "run", "--seeds", "2",
                            "--workers", "1", "--encoder", "labels")  # fmt: skip
        assert code == 0, err
        store = out / "run" / "stores" / "scene_000"
        batch = out / "queries.txt"
        batch.write_text("chair\ntable\n")
        for args in (
            ("query", store, "--batch", batch, "--out", out / "answers.parquet"),
            ("query", store, "chair", "--map", "grid", "--rrd", out / "query.rrd"),
            ("replan", store, "chair", "--visited", "0", "--rrd", out / "replan.rrd"),
            ("explore", store, "--views", "2", "--rrd", out / "explore.rrd"),
        ):
            code, _, err = care(*args)
            assert code == 0, (args[0], err)
    _same(tmp_path / "a", tmp_path / "b")
