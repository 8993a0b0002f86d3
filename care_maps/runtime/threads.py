"""The one place that sizes thread pools: torch's, the BLAS libraries' (via threadpoolctl)
and Arrow's CPU pool (Parquet decoding).

Left alone, torch and OpenBLAS each start one thread per core, and on a busy 2-core machine
they fight each other and every other process: ``torch.index_add_`` of the grid's sums
averaged ~95 ms a call with two threads under load, 0.5-1.6 ms with one, and the sample's
grid took 34 s instead of 6 s. Most of our work is many small array operations per view or
per query, which gain nothing from a second thread; parallelism comes from running scenes or
views in separate processes. So every kind of work (:class:`Work`) has a thread count
(:data:`THREADS`), and every entry point sets it:

- the ``care`` program: :func:`use_threads` for each command's kind of work (``main``
  sets :attr:`Work.DEFAULT` before any command runs; a model runs under
  :attr:`Work.ENCODE`: ``care ingest``'s forward pass and its vocabulary's text, the crops
  of ``care fuse instances --features crops``);
- Ray and process-pool workers: :func:`threads_for` around the task (``care_maps.evaluate.job``);
- benchmarks: :func:`use_threads` in ``main``, so their "one core" is true for BLAS too.

``CARE_THREADS=<n>`` overrides the counts (for a machine of your own; 0 = all cores) except
those of :data:`PINNED` work: BLAS decides the last bits of a float32 product by its thread
count, so the fusion, the queries and the evaluation keep one thread and their results are
the same bytes on every machine, worker and setting (``tests/evaluate/test_thread_counts``).
Arrow decodes a Parquet row group's columns on its own pool (one thread per core): it is
sized with the others, so "one thread" holds for reading the store too.

Threads of our own are stages, not pools: the grid's fusion decodes the store and makes
each view's samples on two background threads ahead of its merge
(``GridConfig.read_ahead``, :mod:`care_maps.runtime.readahead`); before it, the compiled kernels load on
one thread while two decode the depth sample of the height-band check
(``care_maps.fuse.frame.DECODERS``). Each stage's array work runs on the one-thread pools above, so
its results do not depend on the stages' overlap; ``--read-ahead 0`` runs it all in the
caller's thread. The compiled kernels (:mod:`care_maps.runtime.jit`) are single-threaded loops.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from enum import Enum

__all__ = [
    "ENV_VAR",
    "PINNED",
    "THREADS",
    "Work",
    "stage_threads",
    "sync_torch",
    "thread_count",
    "threads_for",
    "use_threads",
]

ENV_VAR = "CARE_THREADS"
"""Environment variable that overrides every thread count (0 = all cores)."""


class Work(Enum):
    """Kinds of work, each with its own thread count in :data:`THREADS`."""

    DEFAULT = "default"
    """Anything not listed: small array operations."""
    FUSE = "fuse"
    """Streaming fusion of views into candidate sums: many small operations per view."""
    QUERY = "query"
    """Queries and replanning: a few passes over the map's columns per attempt."""
    EVAL = "eval"
    """One scene's evaluation in a worker; scenes run in parallel processes."""
    ENCODE = "encode"
    """A vision-language model's forward pass: large matrix products that scale with cores."""


THREADS: dict[Work, int | None] = {
    Work.DEFAULT: 1,
    Work.FUSE: 1,
    Work.QUERY: 1,
    Work.EVAL: 1,
    Work.ENCODE: None,
}
"""Threads per kind of work; ``None`` = every core this process may use."""

PINNED: frozenset[Work] = frozenset({Work.FUSE, Work.QUERY, Work.EVAL})
"""Kinds of work whose results must not depend on the machine, so ``CARE_THREADS`` leaves
them at :data:`THREADS`: a float32 matrix product rounds its last bits by BLAS's thread
count (the grid's per-view class dot products changed its pwKL column with two threads),
and such bits decide near-ties between candidates. Their parallelism is processes. A model's
own outputs are not theirs: ingest's features and vocabulary text and the crops of an
instance map run on :attr:`Work.ENCODE` (every core), and, as between a CPU and a GPU, their
last bits may differ between machines of different core counts (a tiny CLIP's text
embeddings by 1e-7 between one thread and two); what is computed from them is pinned."""


def _cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def thread_count(work: Work) -> int:
    """Threads for ``work``: :data:`THREADS`, or ``CARE_THREADS`` when set (except for the
    :data:`PINNED` kinds)."""
    override = os.environ.get(ENV_VAR, "").strip()
    if override:
        try:
            n = int(override)
        except ValueError:
            n = -1
        if n < 0:
            from care_maps.core.errors import CareError

            msg = f"{ENV_VAR}={override!r}: give a number of threads (0 = all cores)"
            raise CareError(msg)
        if work not in PINNED:
            return n or _cores()
    count = THREADS[work]
    return _cores() if count is None else count


_PROCESS_THREADS: int | None = None
"""The count :func:`use_threads` chose for this process (applied to torch when it arrives)."""


def sync_torch() -> None:
    """Give torch, if imported, the process's thread count; called where work starts
    (:func:`threads_for`, :func:`use_threads`), not where torch is imported (torch is not
    imported just to size its pool: a second or more of start-up that most commands do not
    need; the OMP_NUM_THREADS variable would do it, but with it set an interrupted run is
    killed by its SIGINT instead of exiting with 130)."""
    if _PROCESS_THREADS is not None and "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(_PROCESS_THREADS)


def _set(n: int) -> None:
    from threadpoolctl import threadpool_limits

    global _PROCESS_THREADS
    _PROCESS_THREADS = n
    sync_torch()
    import numpy  # noqa: F401  (its BLAS is loaded with it)

    _set_blas_env(n)
    threadpool_limits(limits=n)  # not used as a context: stays in effect for the process
    _set_arrow(n)


BLAS_ENV = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS")
"""The variables a BLAS library reads once, when it is loaded. threadpoolctl sizes the
libraries already loaded; scipy brings its own OpenBLAS with its first import, which most
commands never make or make late (importing scipy just to size it cost ~0.2 s of every
command's start-up), so the count is also left here for a library that arrives later.
(``OMP_NUM_THREADS`` is not set: see :func:`sync_torch`.)"""


def _set_blas_env(n: int) -> dict[str, str | None]:
    """Set :data:`BLAS_ENV` to ``n``; returns the values before."""
    before = {name: os.environ.get(name) for name in BLAS_ENV}
    for name in BLAS_ENV:
        os.environ[name] = str(n)
    return before


def _restore_env(before: dict[str, str | None]) -> None:
    for name, value in before.items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


def _set_arrow(n: int) -> int:
    """Size Arrow's CPU pool; returns the previous size."""
    import pyarrow

    before = pyarrow.cpu_count()
    pyarrow.set_cpu_count(n)
    return before


def use_threads(work: Work) -> int:
    """Set this process's torch and BLAS pools for ``work``; returns the thread count."""
    n = thread_count(work)
    _set(n)
    return n


def stage_threads(work: Work) -> int:
    """Size torch's pool for the calling thread alone, a stage's own thread, to ``work``'s
    count; returns it. torch keeps a thread's count from its first parallel operation (set
    then by the process's latest :func:`use_threads` or :func:`threads_for`), so a stage that
    starts while another thread runs a model under :attr:`Work.ENCODE` would run its own
    array work on every core too: on 2 cores ingest's resizing of the next batch then made
    a second team of torch threads fighting the forward pass's for the same cores. A thread
    calls this before its first torch operation; other threads keep their counts."""
    n = thread_count(work)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(n)
    return n


@contextmanager
def threads_for(work: Work) -> Iterator[int]:
    """Run a block with the pools of ``work``, restoring the previous ones afterwards.

    torch is not imported for it: a torch already imported is sized at the block's start
    (:func:`sync_torch`) and restored at its end. Modules that import torch do not size it
    themselves, so work whose bytes depend on the thread count (a map build, a scene's
    evaluation) runs in such a block, its modules imported before it starts."""
    from threadpoolctl import threadpool_limits

    global _PROCESS_THREADS
    n = thread_count(work)
    torch = sys.modules.get("torch")
    before = torch.get_num_threads() if torch is not None else None
    process_before = _PROCESS_THREADS
    _PROCESS_THREADS = n
    sync_torch()
    arrow_before = _set_arrow(n)
    env_before = _set_blas_env(n)
    try:
        with threadpool_limits(limits=n):
            yield n
    finally:
        _restore_env(env_before)
        _PROCESS_THREADS = process_before
        torch = sys.modules.get("torch")
        if torch is not None:
            restore = before if before is not None else process_before
            torch.set_num_threads(restore if restore is not None else _cores())
        _set_arrow(arrow_before)
