"""Work on background threads, for the stages' maths modules to use without a pool of their
own (thread pools are this package's concern: ``docs/architecture.md``, Threads).

Both helpers suit work that releases the GIL (decoding in C, compiling kernels): it then
overlaps the caller's own work on a second core.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

__all__ = ["in_background", "thread_map"]

T = TypeVar("T")
R = TypeVar("R")


def in_background(fn: Callable[[], Any], name: str) -> None:
    """Start ``fn()`` on a thread of its own and return at once (not awaited: the thread
    ends with the call). For a warm-up whose result the caller meets later anyway, such as
    compiled kernels that a first call waits for under their own lock."""
    pool = ThreadPoolExecutor(1, thread_name_prefix=name)
    pool.submit(fn)
    pool.shutdown(wait=False)


def thread_map(fn: Callable[[T], R], items: Iterable[T], workers: int, name: str) -> list[R]:
    """``[fn(x) for x in items]``, in order, on ``workers`` threads (in the caller's thread
    when ``workers <= 1``)."""
    if workers <= 1:
        return [fn(item) for item in items]
    with ThreadPoolExecutor(workers, thread_name_prefix=name) as pool:
        return list(pool.map(fn, items))
