"""Recordings run side by side fuse in one thread each, with the same map settings."""

from __future__ import annotations

import dataclasses
from dataclasses import replace

from care_maps.evaluate.pipeline import one_thread_each
from care_maps.fuse.config import GridConfig, InstanceConfig
from care_maps.runtime.execution import Execution


def test_side_by_side_tasks_fuse_in_one_thread_each_with_the_same_map_settings() -> None:
    run = Execution(workers=2)
    assert run.read_ahead > 0  # the pipeline, run alone
    each = one_thread_each(run)
    assert each.read_ahead == 0
    # nothing else changes, and read_ahead is how a build runs, not part of a map's identity
    assert replace(each, read_ahead=run.read_ahead) == run
    for config in (GridConfig, InstanceConfig):
        assert "read_ahead" not in {f.name for f in dataclasses.fields(config)}
