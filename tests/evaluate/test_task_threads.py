"""Recordings run side by side fuse in one thread each, with the same map settings."""

from __future__ import annotations

from dataclasses import replace

from evaluate.pipeline import RunConfig, one_thread_each
from fuse.config import GridConfig, InstanceConfig


def test_side_by_side_tasks_fuse_in_one_thread_each_with_the_same_map_settings() -> None:
    config = RunConfig()
    assert config.grid.read_ahead > 0  # the pipeline, run alone
    each = one_thread_each(config)
    assert each.grid.read_ahead == each.instances.read_ahead == 0
    # nothing else changes, and read_ahead is a how-to setting, not part of a map's identity
    assert replace(each.grid, read_ahead=config.grid.read_ahead) == config.grid
    assert replace(each.instances, read_ahead=config.instances.read_ahead) == config.instances
    assert replace(each, grid=config.grid, instances=config.instances) == config
    assert "read_ahead" in GridConfig.HOW
    assert "read_ahead" in InstanceConfig.HOW
