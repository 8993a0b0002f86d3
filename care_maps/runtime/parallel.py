"""Where independent tasks run: in this process, in a local process pool, or as Ray tasks.

The dataset pipeline (one task a recording: ingest and both maps) and the evaluation (one
task a scene) hand their tasks to :func:`run_tasks` and get the results back as they
finish, whichever :class:`Runner` was chosen. Every worker process starts with the same
process settings as the ``care`` program (:func:`setup_worker`: the allocator of
:mod:`care_maps.runtime.malloc`, the thread pools of :mod:`care_maps.runtime.threads`): as the process pool's
initializer, and as Ray's ``worker_process_setup_hook``. The tasks are pure functions of
their arguments, so the outputs are the same, bit for bit, whichever runner ran them.

An interrupted run (Ctrl-C, SIGTERM, SIGHUP: :mod:`care_maps.runtime.signals`) stops its workers
within a second: :func:`stop_workers` signals every live pool's workers at once, each
unwinds its task and leaves (:func:`care_maps.runtime.signals.in_task`), and the program waits for
them (killing any that outlast :data:`care_maps.runtime.signals.WORKER_GRACE_S`) before it exits;
a run's Ray tasks are cancelled.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import sys
import threading
import time
import weakref
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextvars import ContextVar
from dataclasses import dataclass, field, replace
from multiprocessing.context import SpawnContext, SpawnProcess
from pathlib import Path
from typing import Any, TypeVar

from care_maps.core.errors import CareError
from care_maps.runtime.execution import Backend, Execution
from care_maps.runtime.signals import (
    STOPS,
    WORKER_GRACE_S,
    answer_stops_in_worker,
    in_task,
    release_semaphores,
)

__all__ = [
    "RAY_HOOK",
    "Runner",
    "open_runner",
    "openmp_threads",
    "ray_runtime_env",
    "run_tasks",
    "setup_worker",
    "start_task",
    "stop_pool",
    "stop_workers",
]

T = TypeVar("T")
R = TypeVar("R")

RAY_HOOK = "care_maps.runtime.parallel.setup_worker"
"""Ray's ``worker_process_setup_hook``, by module path (imported in every worker)."""

_ROOT = Path(__file__).resolve().parents[2]
"""The directory holding the ``care_maps`` package (put on the workers' path: a cluster's
nodes started with ``ray start`` in another directory find them there)."""


def ignore_interrupt() -> None:
    """A worker's Ctrl-C handling: none. Ctrl-C reaches every process of the terminal's
    group; the program stops the pool (:func:`stop_pool`) and says so in one line, where a
    worker's own KeyboardInterrupt would only add tracebacks."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def setup_worker() -> None:
    """The process settings of every worker: freed memory kept mapped (:mod:`care_maps.runtime.malloc`)
    and the thread pools of :attr:`care_maps.runtime.threads.Work.DEFAULT` (:mod:`care_maps.runtime.threads`); no
    progress bars of their own."""
    from care_maps.runtime.malloc import keep_freed_memory
    from care_maps.runtime.threads import Work, use_threads

    keep_freed_memory()
    use_threads(Work.DEFAULT)
    ignore_interrupt()
    # read by open3d's OpenMP runtime when it loads, after this hook (a Ray worker has it
    # from the runtime environment already)
    os.environ["OMP_NUM_THREADS"] = openmp_threads()
    # a worker's stage bars would interleave on the driver's terminal; the driver shows one
    # bar for the dataset instead (tqdm reads TQDM_* variables as defaults)
    os.environ["TQDM_DISABLE"] = "1"


@dataclass(frozen=True)
class Runner:
    """Where :func:`run_tasks` runs tasks, and what each task declares to Ray; made from a
    run's :class:`care_maps.runtime.execution.Execution` by :meth:`of`."""

    workers: int = 1
    """Local processes (1: one after another in this process)."""
    backend: Backend = Backend.PROCESSES
    """A local process pool, or Ray."""
    address: str | None = None
    """A running Ray cluster's address (with the Ray backend; None: a local Ray)."""
    num_cpus: float = 1.0
    """CPUs a Ray task declares."""
    memory: int | None = None
    """Bytes of memory a Ray task declares (None: none, Ray's default)."""
    executor: Executor | None = field(default=None, compare=False, repr=False)
    """A process pool kept up across :func:`run_tasks` calls (:func:`open_runner`)."""

    @classmethod
    def of(cls, run: Execution) -> Runner:
        """The runner of ``run``'s tasks: ``run.workers`` processes (default: one per CPU)
        or Ray, each task declaring ``run.task_cpus`` and ``run.task_memory``."""
        return cls(
            workers=run.workers or os.cpu_count() or 1,
            backend=run.backend,
            address=run.ray_address or None,
            num_cpus=run.task_cpus,
            memory=run.task_memory,
        )

    @property
    def uses_ray(self) -> bool:
        return self.backend is Backend.RAY

    def describe(self) -> str:
        if self.uses_ray:
            return f"Ray at {self.address}" if self.address else "local Ray"
        return "serial" if self.workers <= 1 else f"{self.workers} processes"


_OPEN: ContextVar[tuple[Runner, ...]] = ContextVar("care_open_runners", default=())
"""The runners whose pools are open here (:func:`open_runner`), innermost last."""


@contextlib.contextmanager
def open_runner(runner: Runner) -> Iterator[Runner]:
    """``runner`` with its process pool started once for every :func:`run_tasks` inside the
    block (a dataset's recordings, then its evaluation): the workers' start-up, imports
    included, is paid once. Inside the block of a runner with the same settings, that
    runner's pool is the one used (a stage called with the same execution settings as its
    caller shares its caller's workers)."""
    for live in reversed(_OPEN.get()):
        if live == runner:
            yield live
            return
    if runner.uses_ray or runner.workers <= 1 or runner.executor is not None:
        yield runner
        return
    pool = _pool(runner.workers)
    live = replace(runner, executor=pool)
    token = _OPEN.set((*_OPEN.get(), live))
    try:
        yield live
    except KeyboardInterrupt:  # Ctrl-C: stop the workers, do not wait for their tasks
        stop_pool(pool)
        raise
    finally:  # an error: the workers finish what they hold, as the pool's own exit does
        _OPEN.reset(token)
        pool.shutdown()


_LIVE: weakref.WeakSet[ProcessPoolExecutor] = weakref.WeakSet()
"""Every process pool this process started and has not dropped (:func:`stop_workers`)."""
_STARTED: weakref.WeakSet[Any] = weakref.WeakSet()
"""Every pool worker this process started (:class:`_Worker`), known to :func:`stop_workers`
even where the pool had not yet recorded it."""
_HELD: list[tuple[Any, ...]] = []
"""The queues of the pools stopped (:func:`stop_pool`), kept from the garbage collector until
a new pool is made, by when their workers have long ended."""
_STARTING = threading.Lock()
"""Held while a worker starts: a program that stops waits for the hand-over of its start-up
data to end (cut short, the half-started worker prints a traceback of its own)."""
_STOPPING = threading.Event()
"""Set once the program stops its workers: a worker started after is killed at once (until
a new pool is made)."""
_RAY_PENDING: set[Any] = set()
"""Object references of this process's Ray tasks that have not finished."""
_RAY_LOCAL = False
"""Whether this process started a local Ray (no cluster address): its processes are this
run's, ended with it when it is stopped (:func:`stop_workers`)."""


def _workers(pool: ProcessPoolExecutor) -> list[Any]:
    """The pool's worker processes (read from a signal handler too: never raises)."""
    try:
        return list((getattr(pool, "_processes", None) or {}).values())
    except RuntimeError:  # changed size while read: the manager thread replaced one
        return []


def _signal_workers(processes: list[Any]) -> None:
    """Tell workers to stop (SIGTERM: each unwinds its task and leaves)."""
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            process.terminate()


def _await_workers(processes: list[Any], grace: float) -> None:
    """Wait up to ``grace`` seconds for the workers to end; kill those still running."""
    from multiprocessing.connection import wait

    deadline = time.monotonic() + grace
    sentinels = []
    for process in processes:
        with contextlib.suppress(ValueError, AttributeError):
            sentinels.append(process.sentinel)
    while sentinels and (left := deadline - time.monotonic()) > 0:
        for done in wait(sentinels, timeout=left):
            sentinels.remove(done)
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            if process.is_alive():
                process.kill()


def stop_pool(pool: ProcessPoolExecutor, grace: float = WORKER_GRACE_S) -> None:
    """Cancel the pool's waiting tasks and end its workers now: each unwinds its task (its
    temporaries removed) and leaves; one still running after ``grace`` seconds is killed,
    and what it was staging stays as a temporary named for its dead process, swept by the
    next run there."""
    processes = _workers(pool)
    processes += [p for p in _started() if p not in processes]  # started, not yet recorded
    _HELD.append(_queues(pool))  # not freed under a worker still starting (see _queues)
    _signal_workers(processes)
    with contextlib.suppress(RuntimeError):
        pool.shutdown(wait=False, cancel_futures=True)
    _await_workers(processes, grace)


def _started() -> list[Any]:
    """The workers this process started (read from a signal handler too: never raises)."""
    try:
        return list(_STARTED)
    except RuntimeError:  # changed while read
        return []


def _queues(pool: ProcessPoolExecutor) -> tuple[Any, ...]:
    """The pool's call and result queues. A worker still starting has yet to open their
    semaphores (by name, from its start-up data), and a queue freed unlinks its semaphores:
    dropped by the pool's shutdown, they were freed under the worker, which printed a
    ``SemLock._rebuild`` traceback (one stop in four on a loaded machine). Held
    (:data:`_HELD`), they are freed with the program's other semaphores as it leaves
    (:func:`care_maps.runtime.signals.release_semaphores`), one thread at a time."""
    return tuple(getattr(pool, name, None) for name in ("_call_queue", "_result_queue"))


def stop_workers(*, grace: float | None = None) -> None:
    """Stop every worker this process started: the pools' (:func:`stop_pool`) and its Ray
    tasks (cancelled). ``grace=None``: only signal the pools' workers, without waiting or
    touching the pools' locks (safe in a signal handler, whatever the main thread was
    doing); else wait up to ``grace`` seconds for them and kill the rest."""
    try:
        processes = list(_STARTED)
    except RuntimeError:  # changed while read (a signal handler's read): the pools' own
        processes = [p for pool in list(_LIVE) for p in _workers(pool)]
    _signal_workers(processes)
    if grace is None:
        return
    _STOPPING.set()
    starting = _STARTING.acquire(timeout=grace)  # no worker half-started from here on
    try:
        processes = list(_STARTED)
        _signal_workers(processes)
        _cancel_ray(list(_RAY_PENDING))
        _await_workers(processes, grace)
    finally:
        if starting:
            _STARTING.release()
    for pool in list(_LIVE):
        with contextlib.suppress(Exception):
            pool.shutdown(wait=False, cancel_futures=True)
    _end_local_ray()
    release_semaphores()


def _end_local_ray() -> None:
    """Shut down the local Ray this process started (its agents would outlive a program
    that leaves at once, as a stopped one does); a cluster's Ray is left running."""
    global _RAY_LOCAL
    ray = sys.modules.get("ray")
    if not _RAY_LOCAL or ray is None:
        return
    _RAY_LOCAL = False
    with contextlib.suppress(Exception):
        ray.shutdown()


def _cancel_ray(refs: list[Any]) -> None:
    """Cancel Ray tasks now (their worker processes killed; a temporary one was staging is
    named for a dead process, swept by the next run there)."""
    if not refs:
        return
    import ray

    for ref in refs:
        with contextlib.suppress(Exception):
            ray.cancel(ref, force=True)
        _RAY_PENDING.discard(ref)


class _Worker(SpawnProcess):
    """A pool's worker, started with the interrupting signals held: one that came while it
    starts would cut the hand-over of its start-up data, and the half-started process, not
    yet known to the pool, would print a traceback; held, the signal is answered as soon as
    the worker is one the pool can stop."""

    def start(self) -> None:
        held = signal.pthread_sigmask(signal.SIG_BLOCK, STOPS)
        came: list[int] = []
        ours = _defer_stops(came)
        try:
            with _STARTING:
                super().start()
                _STARTED.add(self)  # known before a signal can stop the pool's book-keeping
                if _STOPPING.is_set():  # the program is stopping: this one never works
                    self.kill()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
            for signum, handler in ours.items():
                signal.signal(signum, handler)
            if came:  # answered now, by the program's own handler
                signal.raise_signal(came[0])


def _defer_stops(came: list[int]) -> dict[int, Any]:
    """While a worker starts in the main thread, note an interrupting signal instead of
    answering it: the mask holds a signal back from this thread only, and Python runs a
    handler in the main thread whichever thread received it, so the start-up's hand-over
    (Python code) could be cut. Returns the handlers to put back."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    ours: dict[int, Any] = {signum: signal.getsignal(signum) for signum in STOPS}
    ours = {signum: handler for signum, handler in ours.items() if callable(handler)}
    for signum in ours:
        signal.signal(signum, lambda signum, frame: came.append(signum))
    return ours


class _WorkerContext(SpawnContext):
    """Spawn (no copy of the parent's threads and locks), of :class:`_Worker` processes."""

    Process = _Worker


def _pool(workers: int) -> ProcessPoolExecutor:
    _STOPPING.clear()  # new work (a caller that went on after a stop: a test)
    _HELD.clear()
    pool = ProcessPoolExecutor(workers, mp_context=_WorkerContext(), initializer=_setup_pool_worker)
    _LIVE.add(pool)
    return pool


def _setup_pool_worker() -> None:
    """A pool worker's settings (:func:`setup_worker`), and its answer to SIGTERM and SIGHUP
    (:func:`care_maps.runtime.signals.answer_stops_in_worker`): Ray's workers keep Ray's own. The
    signals its start held (inherited) are let through once it answers them."""
    setup_worker()
    answer_stops_in_worker()
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOPS)


def openmp_threads() -> str:
    """The OpenMP thread count of a worker: its :attr:`care_maps.runtime.threads.Work.DEFAULT` count.

    open3d (normals, DBSCAN) runs on an OpenMP pool that threadpoolctl cannot reach; left at
    one thread per core, two workers on two cores would run four threads. Its results do not
    depend on the pool's size (the planes are fitted by :mod:`care_maps.geometry.planes`, seeded, not by
    open3d's threaded RANSAC), so the count is a matter of speed only.
    """
    from care_maps.runtime.threads import Work, thread_count

    return str(thread_count(Work.DEFAULT))


def ray_runtime_env() -> dict[str, Any]:
    """The runtime environment of our Ray tasks: the set-up hook, the packages' path, and
    a worker's OpenMP thread count (:func:`openmp_threads`)."""
    path = os.pathsep.join(p for p in (str(_ROOT), os.environ.get("PYTHONPATH", "")) if p)
    env = {"PYTHONPATH": path, "OMP_NUM_THREADS": openmp_threads()}
    return {"worker_process_setup_hook": RAY_HOOK, "env_vars": env}


def run_tasks(fn: Callable[[T], R], items: Sequence[T], runner: Runner) -> Iterator[tuple[T, R]]:
    """``(item, fn(item))`` for every item, in the order they finish.

    A task's project error (:class:`care_maps.core.errors.CareError`) is raised here as itself (its
    one line), not wrapped in the pool's or Ray's exception.
    """
    if runner.uses_ray:
        yield from _run_ray(fn, items, runner)
    elif runner.executor is not None:
        yield from _run_pool(fn, items, runner.executor)
    elif runner.workers <= 1 or len(items) <= 1:
        for item in items:
            yield item, fn(item)
    else:
        pool = _pool(runner.workers)
        try:
            yield from _run_pool(fn, items, pool)
        except KeyboardInterrupt:  # interrupted: stop the workers, do not wait for their tasks
            stop_pool(pool)
            raise
        finally:
            pool.shutdown()


def start_task(fn: Callable[..., R], *args: Any, runner: Runner) -> Future[R]:
    """``fn(*args)`` started on ``runner`` now, its result for later (``.result()``), so
    the caller does other work meanwhile: on the runner's open pool
    (:func:`open_runner`) or as a Ray task. Without either it runs here, before this
    returns (its error, if any, is raised by ``.result()`` as from a pool).

    A task's project error (:class:`care_maps.core.errors.CareError`) comes out of ``.result()`` as
    itself, whichever runner ran it.
    """
    if runner.uses_ray:
        _, task = _ray_task(runner)
        return _unwrapped(task.remote(fn, *args).future())
    if runner.executor is not None:
        return runner.executor.submit(in_task, fn, *args)
    done: Future[R] = Future()
    try:
        done.set_result(fn(*args))
    except Exception as err:
        done.set_exception(err)
    return done


def _unwrapped(future: Future) -> Future:
    """``future`` with a Ray task's :class:`care_maps.core.errors.CareError` raised as itself."""
    out: Future = Future()

    def settle(done: Future) -> None:
        err = done.exception()
        if err is None:
            out.set_result(done.result())
        else:
            out.set_exception(_own_error(err))

    future.add_done_callback(settle)
    return out


def _run_pool(fn: Callable[[T], R], items: Sequence[T], pool: Executor) -> Iterator[tuple[T, R]]:
    futures = {pool.submit(in_task, fn, item): item for item in items}
    for future in as_completed(futures):
        yield futures[future], future.result()


def _ray(runner: Runner) -> Any:
    try:
        import ray
    except ImportError as err:
        msg = "--ray needs Ray: pip install 'care-maps[ray]'"
        raise CareError(msg) from err
    if not ray.is_initialized():
        if runner.address:
            _check_reachable(runner.address)
        global _RAY_LOCAL
        ours: dict[int, Any] = {signum: signal.getsignal(signum) for signum in STOPS}
        _RAY_LOCAL = not runner.address
        ray.init(
            address=runner.address,
            include_dashboard=False,
            log_to_driver=False,
            runtime_env=ray_runtime_env(),
        )
        _answer_stops_again(ours)
    return ray


def _answer_stops_again(ours: dict[int, Any]) -> None:
    """Take the interrupting signals back from Ray: ``ray.init`` installs its own SIGTERM
    handlers in this process (one exits 1 without a word, one prints a stack dump), which
    leave the program's unwinding undone; the program's own, put back, stop the run as any
    other (:mod:`care_maps.runtime.signals`)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum, handler in ours.items():
        if handler is not None:
            signal.signal(signum, handler)


def _ray_task(runner: Runner) -> tuple[Any, Any]:
    """Ray (started or joined) and our task on it: :func:`_in_worker` with the runtime
    environment and the resources ``runner`` declares."""
    ray = _ray(runner)
    options: dict[str, Any] = {"num_cpus": runner.num_cpus, "max_retries": 0}
    if runner.memory:
        options["memory"] = int(runner.memory)
    return ray, ray.remote(_in_worker).options(runtime_env=ray_runtime_env(), **options)


def _own_error(err: BaseException) -> BaseException:
    """A failed Ray task's own project error (its one line), else Ray's exception as is."""
    cause = getattr(err, "cause", None)
    return cause if isinstance(cause, CareError) else err


def _run_ray(fn: Callable[[T], R], items: Sequence[T], runner: Runner) -> Iterator[tuple[T, R]]:
    ray, task = _ray_task(runner)
    refs = {task.remote(fn, item): item for item in items}
    pending = list(refs)
    _RAY_PENDING.update(pending)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            _RAY_PENDING.discard(done[0])
            try:
                result = ray.get(done[0])
            except ray.exceptions.RayTaskError as err:
                own = _own_error(err)
                if own is err:
                    raise
                raise own from None
            yield refs[done[0]], result
    except KeyboardInterrupt:  # interrupted: end the tasks, do not wait for them
        _cancel_ray(pending)
        raise
    finally:
        _RAY_PENDING.difference_update(pending)


def _in_worker(fn: Callable[..., R], *args: Any) -> R:
    """A Ray task: the process settings (again, should the hook not have run), then ``fn``."""
    setup_worker()
    return fn(*args)


def _check_reachable(address: str) -> None:
    """Fail at once on a cluster address nothing listens on: ``ray.init`` would retry for
    minutes, printing warnings, before giving up."""
    host, _, port = address.split("://")[-1].rpartition(":")
    if not host or not port.isdigit():
        return  # "auto" and the like: Ray resolves them itself
    try:
        socket.create_connection((host, int(port)), timeout=5).close()
    except OSError as err:
        msg = (
            f"cannot reach a Ray cluster at {address} ({err.strerror or err}); start one with "
            "`ray start --head` or drop --ray-address to use a local Ray"
        )
        raise CareError(msg) from err
