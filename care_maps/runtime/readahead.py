"""Read a stream ahead on a background thread, so decoding the store overlaps fusion.

Fusing a view needs its decoded frame (a PNG depth image, a JPEG) and its feature map (a
Parquet row group): about 20 ms a view at 640x480, a third of the grid's work per view,
all of it in C code that releases the GIL (zlib, libjpeg, Arrow's reader). A thread that
decodes the next views while the fusing thread works on this one hides that time on a
second core. The items and their order are those of the stream itself, so the map is the
same bytes with or without it (``tests/care/test_readahead.py``).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Generator, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

__all__ = ["READ_AHEAD", "read_ahead"]

READ_AHEAD = 4
"""Items produced ahead by default: enough to ride out a few slow items (a row group read
at once, a busy core; the grid's pipeline over 200 views: 6.4-7.1 s with 2, 6.0-6.5 with 4,
6.1-6.2 with 8), few enough that the views in flight stay about a hundred MB at 640x480."""

T = TypeVar("T")

_END = object()
"""Returned by ``next`` once the stream is exhausted (and ever after)."""


def read_ahead(items: Iterable[T], depth: int) -> Generator[T, None, None]:
    """The items of ``items`` in order, up to ``depth`` of them produced ahead of the
    consumer on one background thread (``depth`` <= 0: produced in the caller's thread).

    An error raised while producing an item is raised here, where that item would have
    been consumed (the same exception object: a store's one-line error stays one line).
    Closing this iterator early (a ``break``, an error in the consumer, Ctrl-C) waits for
    the item being produced, drops the others and closes ``items``: no thread outlives it.
    """
    it = iter(items)
    if depth <= 0:
        yield from it
        return
    # one worker: the stream's ``next`` calls run one at a time, in order, on one thread
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="care-read-ahead")
    try:
        pending: deque[Future] = deque(pool.submit(next, it, _END) for _ in range(depth))
        while True:
            item = pending.popleft().result()
            if item is _END:
                return
            pending.append(pool.submit(next, it, _END))
            yield item
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        close = getattr(it, "close", None)
        if close is not None:  # a generator's own clean-up (open files), in this thread
            close()
