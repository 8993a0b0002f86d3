"""care_maps.runtime.threads sets torch's, BLAS's and Arrow's pools in a fresh worker process, as every
entry point does."""

from __future__ import annotations

import multiprocessing as mp

import pytest

from care_maps.core.errors import CareError
from care_maps.runtime.threads import PINNED, THREADS, Work, thread_count


def _pools_in_worker(kind: str, queue) -> None:  # runs in a spawned process
    import numpy as np
    import pyarrow as pa
    import torch
    from threadpoolctl import threadpool_info

    from care_maps.runtime.threads import Work, threads_for, use_threads

    np.ones((64, 64)) @ np.ones((64, 64))  # BLAS loaded and used before
    set_to = use_threads(Work(kind))
    blas = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
    inside = None
    arrow = pa.cpu_count()
    with threads_for(Work.ENCODE) as n:
        inside = (n, torch.get_num_threads(), pa.cpu_count())
    after = (torch.get_num_threads(), pa.cpu_count())
    queue.put((set_to, torch.get_num_threads(), blas, arrow, inside, after))


def _run(kind: Work, env: dict[str, str] | None = None) -> tuple:
    import os

    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    old = dict(os.environ)
    os.environ.update(env or {})
    try:
        proc = ctx.Process(target=_pools_in_worker, args=(kind.value, queue))
        proc.start()
        out = queue.get(timeout=120)
        proc.join()
    finally:
        os.environ.clear()
        os.environ.update(old)
    return out


@pytest.mark.slow
def test_worker_pools_follow_the_kind_of_work() -> None:
    set_to, torch_threads, blas, arrow, (encode_n, encode_torch, encode_arrow), after = _run(
        Work.FUSE
    )
    assert set_to == THREADS[Work.FUSE] == 1
    assert torch_threads == 1
    assert blas
    assert all(n == 1 for n in blas)
    assert arrow == 1  # Parquet decoding too
    assert encode_torch == encode_arrow == encode_n >= 1  # the encoder's block gets every core...
    assert after == (1, 1)  # ...and gives them back


@pytest.mark.slow
def test_environment_overrides_every_count_but_the_pinned(monkeypatch: pytest.MonkeyPatch) -> None:
    set_to, torch_threads, blas, arrow, _, _ = _run(Work.DEFAULT, {"CARE_THREADS": "2"})
    assert set_to == torch_threads == arrow == 2
    assert all(n == 2 for n in blas)
    monkeypatch.setenv("CARE_THREADS", "2")
    for work in PINNED:  # their results must not depend on the machine
        assert thread_count(work) == THREADS[work] == 1
    assert thread_count(Work.ENCODE) == 2
    monkeypatch.setenv("CARE_THREADS", "many")
    with pytest.raises(CareError, match="CARE_THREADS"):
        thread_count(Work.FUSE)


def test_stage_functions_run_on_their_own_pools(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    """A caller's pools (a notebook at every core) do not reach the fusion or the ingest:
    the maps' bytes depend on torch's and BLAS's thread counts (tests/evaluate's serial
    run in the test process against pool and Ray workers checks the bytes)."""
    import torch
    from threadpoolctl import threadpool_info, threadpool_limits

    import care_maps.fuse.api
    import care_maps.fuse.build
    import care_maps.ingest.api
    import care_maps.ingest.pipeline
    from care_maps.fuse.config import GridConfig, InstanceConfig
    from care_maps.ingest.pipeline import IngestConfig

    seen: dict[str, tuple[int, list[int]]] = {}

    def spy(name: str):
        def record(*_args: object) -> None:
            blas = [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]
            seen[name] = (torch.get_num_threads(), blas)

        return record

    calls = iter(("grid", "instances"))
    monkeypatch.setattr(care_maps.fuse.build, "_build_map", lambda *a: spy(next(calls))())
    monkeypatch.setattr(care_maps.ingest.pipeline, "_run_ingest", spy("ingest"))
    monkeypatch.setattr(care_maps.ingest.api, "Store", lambda path: path)  # nothing was written
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with threadpool_limits(2):
            care_maps.fuse.api.fuse_grid(tmp_path, GridConfig())
            care_maps.fuse.api.fuse_instances(tmp_path, InstanceConfig())
            care_maps.ingest.api.ingest(tmp_path / "rec", tmp_path, IngestConfig())
            assert torch.get_num_threads() == 2  # given back
    finally:
        torch.set_num_threads(before)
    for name in ("grid", "instances", "ingest"):
        threads, blas = seen[name]
        assert threads == 1, name
        assert blas, name
        assert all(n == 1 for n in blas), name
