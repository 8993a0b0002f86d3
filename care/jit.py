"""Compiled kernels: one decorator, so every kernel is built the same way.

The few loops that NumPy cannot express without many full-size temporaries (the grid's
per-pixel pass, the in-place merge of the state) are compiled by numba with ``nogil`` (the
grid's pipeline runs them on background threads) and their machine code cached on disk, so
a process loads it instead of compiling for seconds. numba keeps the cache beside the module,
or in its user cache directory (``NUMBA_CACHE_DIR`` chooses another) when that is
read-only; where neither can be written, the kernels are compiled once per process instead
of failing at import.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import numba

__all__ = ["kernel"]

F = TypeVar("F", bound=Callable)


def kernel(fn: F) -> F:
    """``numba.njit(cache=True, nogil=True)``, without the cache where none can be kept.

    No fast-math: a kernel does its floating-point operations in the order written, so it
    can reproduce array code bit for bit.
    """
    try:
        return numba.njit(cache=True, nogil=True)(fn)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        return numba.njit(nogil=True)(fn)
