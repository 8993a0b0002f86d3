"""The same numbers with one thread and with two: a Matterport-like recording is encoded,
mapped and evaluated under ``CARE_THREADS=1`` and ``=2``; every table must be the same."""

from __future__ import annotations

from pathlib import Path

import pyarrow.parquet as pq
import pytest

from care_maps.core.encoders import EncoderOptions
from care_maps.evaluate.job import EvalConfig, run_eval
from care_maps.research.dataset_stats import MeasureConfig, map_dataset
from care_maps.runtime.execution import Execution
from care_maps.runtime.threads import ENV_VAR, Work, use_threads
from care_maps.world.presets import PRESETS, WorldPreset
from care_maps.world.record import DatasetConfig, make_dataset

pytestmark = pytest.mark.slow


def test_one_and_two_threads_give_identical_results(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    dataset = tmp_path / "ds"
    make_dataset(
        DatasetConfig(
            out=dataset, scenes=1, seed=2, width=80, height=60, frames=6, num_rooms=1,
            workers=1, progress=False, preset=WorldPreset.MATTERPORT_LIKE,
            world=PRESETS[WorldPreset.MATTERPORT_LIKE],
        )
    )  # fmt: skip
    evaluation = EvalConfig(
        strategies=("no_replan", "max_confidence", "min_stderr", "largest"),
        k_instances=(2,), k_grid=(4,), seeds=1, bootstrap=50,
    )  # fmt: skip
    hashed = MeasureConfig(encoder_options=EncoderOptions(weights="hashed"))  # no model load
    results = []
    try:
        for n in (1, 2):
            monkeypatch.setenv(ENV_VAR, str(n))
            use_threads(Work.DEFAULT)
            out = tmp_path / f"threads{n}"
            scenes = map_dataset(dataset, out, hashed)
            run_eval(scenes, evaluation, out / "eval", run=Execution(workers=1, progress=False))
            store = out / "stores" / "scene_000"
            tables = {
                "instances": store / "instances.parquet",
                "cells": store / "cells.parquet",
                "attempts": out / "eval" / "attempts.parquet",
                "headline": out / "eval" / "preregistered.parquet",
                "summary": out / "eval" / "summary.parquet",
            }
            # contents (NaN where NaN), not file bytes: the files' metadata name their paths
            results.append({k: pq.read_table(p).to_pandas() for k, p in tables.items()})
    finally:
        monkeypatch.delenv(ENV_VAR)
        use_threads(Work.DEFAULT)
    for name in results[0]:
        assert results[0][name].equals(results[1][name]), name
    assert len(results[0]["attempts"]) > 0
