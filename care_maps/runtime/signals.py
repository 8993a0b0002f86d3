"""The signals that stop a run, and how a worker process answers them.

A job is stopped by Ctrl-C (SIGINT), by a scheduler or service manager (SLURM, Kubernetes,
Ray and systemd send SIGTERM) or by its terminal closing (SIGHUP). Each is the same
interruption: the ``care`` program unwinds, removing what it staged, stops its workers, says
so in one line and exits with ``128 + N`` (:func:`exit_code`), as a shell reports a process
ended by signal N (``care_maps.cli.main``).

A worker of a process pool (:mod:`care_maps.runtime.parallel`) answers SIGTERM and SIGHUP the same
way for the task it runs (:func:`stop_task`): the task unwinds (its temporaries removed),
then the worker leaves at once instead of taking the next task. Ctrl-C stays ignored in a
worker: the terminal sends it to every process of the group, and the program stops its
workers itself, so a worker's own interruption would only add tracebacks.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any, NoReturn, TypeVar

__all__ = [
    "STOPS",
    "WORKER_GRACE_S",
    "WORKER_LEAVE_S",
    "answer_stops_in_worker",
    "exit_code",
    "in_task",
    "release_semaphores",
    "stop_line",
]

R = TypeVar("R")

STOPS: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""Signals that interrupt a run (the others keep their default meaning)."""

WORKER_LEAVE_S = 0.5
"""How long a worker told to stop may take to unwind its task before it leaves anyway (a
call in compiled code sees the interruption only when it returns)."""

WORKER_GRACE_S = 0.65
"""How long the program waits for a worker told to stop before it kills it: longer than
:data:`WORKER_LEAVE_S`. Leaving, the worker frees its semaphores (each unlinked, then struck
off the resource tracker's list); a kill due at the same moment cut that in two under load,
and the tracker warned of a "leaked" semaphore it could not find. Within the program's own
grace (``care_maps.cli.main._GRACE_S``)."""


_RELEASING = threading.RLock()
"""Held while this process frees its semaphores (:func:`release_semaphores`)."""

RELEASE_WAIT_S = 0.2
"""How long a thread that frees the semaphores waits for another one at it."""


def release_semaphores() -> None:
    """Free this process's multiprocessing semaphores now (its finalizers), as the
    interpreter's exit would: a process that leaves at once (``os._exit``) would otherwise
    have the resource tracker warn of "leaked semaphore objects" on the program's stderr.

    One thread at a time, and a caller returns only once another thread's release has
    ended (up to :data:`RELEASE_WAIT_S`): a semaphore is freed in two steps (unlinked, then
    struck off the tracker's list), and a process that left in between (the program's
    watchdog leaving while the main thread released) had the tracker warn of a "leaked"
    semaphore it could not find."""
    util = sys.modules.get("multiprocessing.util")
    if util is None or not _RELEASING.acquire(timeout=RELEASE_WAIT_S):
        return
    try:
        with contextlib.suppress(Exception):
            util._run_finalizers()
    finally:
        _RELEASING.release()


def exit_code(signum: int) -> int:
    """The exit code of a run stopped by signal ``signum``: 128 + N, as shells report it
    (130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP)."""
    return 128 + int(signum)


def stop_line(signum: int) -> bytes:
    """The one line a stopped run prints. Ctrl-C's is the one users know; another signal is
    named, since whoever sent it (a scheduler's time limit, a closed terminal) is the
    reason the run did not finish."""
    how = "" if signum == signal.SIGINT else f" by {signal.Signals(signum).name}"
    return f"error: interrupted{how}; nothing half-written was left behind\n".encode()


_task_running = False
"""Whether this worker process runs a task now (:func:`in_task`)."""
_stopping: int | None = None
"""The signal that stops this worker, once one came."""


def stop_task(signum: int, frame: object) -> None:
    """A worker's SIGTERM and SIGHUP: unwind the running task with KeyboardInterrupt (its
    staged outputs removed on the way) and leave within :data:`WORKER_LEAVE_S`; between
    tasks, leave at once. Only the first signal interrupts: a second one (the program's
    after the group's) would cut the unwinding short."""
    global _stopping
    _quiet()
    if not _task_running:
        _leave(signum)
    if _stopping is not None:
        return
    _stopping = signum
    timer = threading.Timer(WORKER_LEAVE_S, _leave, args=(signum,))
    timer.daemon = True
    timer.start()
    raise KeyboardInterrupt


def _quiet() -> None:
    """Send this stopped worker's stderr to nowhere: the program says the run was
    interrupted, in its one line; what a library says while the worker unwinds (Rerun's
    notice of a recording dropped unsaved, say) would only add lines to it."""
    with contextlib.suppress(OSError):
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)


def _leave(signum: int) -> NoReturn:
    """End this worker now, its semaphores released first."""
    release_semaphores()
    os._exit(exit_code(signum))


def answer_stops_in_worker() -> None:
    """Install :func:`stop_task` for SIGTERM and SIGHUP in this worker (a signal the worker
    started ignoring stays ignored, as ``nohup`` asks)."""
    for signum in STOPS:
        if signum == signal.SIGINT:
            continue
        if signal.getsignal(signum) is not signal.SIG_IGN:
            signal.signal(signum, stop_task)


def in_task(fn: Callable[..., R], *args: Any) -> R:
    """``fn(*args)`` in a pool's worker, told apart from the time between tasks: stopped
    while it runs, the task unwinds and then the worker leaves (not taking the next task)."""
    global _task_running
    _task_running = True
    try:
        return fn(*args)
    except KeyboardInterrupt:
        if _stopping is None:
            raise
        _leave(_stopping)
    finally:
        _task_running = False
