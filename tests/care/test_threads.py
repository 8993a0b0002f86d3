"""care.threads sets torch's, BLAS's and Arrow's pools in a fresh worker process, as every
entry point does."""

from __future__ import annotations

import multiprocessing as mp

import pytest

from care.errors import CareError
from care.threads import THREADS, Work, thread_count


def _pools_in_worker(kind: str, queue) -> None:  # runs in a spawned process
    import numpy as np
    import pyarrow as pa
    import torch
    from threadpoolctl import threadpool_info

    from care.threads import Work, threads_for, use_threads

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


def test_environment_overrides_every_count(monkeypatch: pytest.MonkeyPatch) -> None:
    set_to, torch_threads, blas, arrow, _, _ = _run(Work.FUSE, {"CARE_THREADS": "2"})
    assert set_to == torch_threads == arrow == 2
    assert all(n == 2 for n in blas)
    monkeypatch.setenv("CARE_THREADS", "many")
    with pytest.raises(CareError, match="CARE_THREADS"):
        thread_count(Work.FUSE)
