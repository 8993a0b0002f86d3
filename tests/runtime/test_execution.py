"""How a run executes is one :class:`care_maps.runtime.execution.Execution`, and its runner is made in
one place (:meth:`care_maps.runtime.parallel.Runner.of`)."""

from __future__ import annotations

import os

import pytest

from care_maps.core.errors import CareError
from care_maps.runtime.execution import Backend, Execution
from care_maps.runtime.parallel import Runner, open_runner


def test_settings_are_checked() -> None:
    assert Execution(backend="ray").backend is Backend.RAY
    with pytest.raises(CareError, match="unknown backend"):
        Execution(backend="slurm")
    with pytest.raises(CareError, match="read_ahead=-1"):
        Execution(read_ahead=-1)
    with pytest.raises(CareError, match="workers=0"):
        Execution(workers=0)
    with pytest.raises(CareError, match="cells_per_pass=0"):
        Execution(cells_per_pass=0)


def test_the_runner_of_an_execution() -> None:
    local = Runner.of(Execution())
    assert (local.workers, local.uses_ray) == (os.cpu_count() or 1, False)
    assert Runner.of(Execution(workers=1)).describe() == "serial"
    ray = Runner.of(Execution(backend=Backend.RAY, ray_address="ray://head:10001", task_cpus=2))
    assert (ray.uses_ray, ray.address, ray.num_cpus) == (True, "ray://head:10001", 2)
    assert Runner.of(Execution(backend=Backend.RAY)).describe() == "local Ray"
    assert Runner.of(Execution(task_memory=None)).memory is None


def test_a_stage_with_the_same_settings_shares_the_open_pool() -> None:
    run = Execution(workers=2)
    with open_runner(Runner.of(run)) as outer:
        assert outer.executor is not None
        with open_runner(Runner.of(run)) as inner:
            assert inner.executor is outer.executor
        with open_runner(Runner.of(Execution(workers=3))) as other:
            assert other.executor is not outer.executor
