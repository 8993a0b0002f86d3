"""Compiled kernels: one decorator, so every kernel is built the same way.

The few loops that NumPy cannot express without many full-size temporaries (the grid's
per-pixel pass, the in-place merge of the state) are compiled by numba with ``nogil`` (the
grid's pipeline runs them on background threads) and their machine code cached on disk, so
a process loads it instead of compiling for seconds. numba keeps the cache beside the module,
or in its user cache directory (``NUMBA_CACHE_DIR`` chooses another) when that is
read-only.

The cache is a convenience, never a reason to fail: where no cache location can be written
the kernels are compiled once per process, and where the cache cannot be read or written (a
damaged index, a full disk) the kernel says so in one line and compiles in memory.
"""

from __future__ import annotations

import functools
import pickle
import sys
from collections.abc import Callable
from typing import Any

import numba

__all__ = ["CACHE_ERRORS", "kernel"]

CACHE_ERRORS = (pickle.UnpicklingError, EOFError, OSError)
"""What reading or writing numba's cache raises when its files are damaged or the disk is
full (a kernel itself raises none of them)."""


class _Kernel:
    """A numba kernel cached on disk, that falls back to compiling in memory."""

    def __init__(self, fn: Callable) -> None:
        self._fn = fn
        try:
            self._compiled = numba.njit(cache=True, nogil=True)(fn)
        except RuntimeError:  # "cannot cache function ...: no locator available"
            self._compiled = numba.njit(nogil=True)(fn)
        functools.update_wrapper(self, fn)

    def __call__(self, *args: Any) -> Any:
        try:
            return self._compiled(*args)
        except CACHE_ERRORS as error:
            where = f"{self._fn.__module__}.{self._fn.__name__}"
            print(
                f"warning: numba's cache of {where} cannot be used ({type(error).__name__}: "
                f"{error}); compiling it in memory (delete the module's __pycache__ "
                "numba files, or set NUMBA_CACHE_DIR, to cache it again)",
                file=sys.stderr,
            )
            self._compiled = numba.njit(nogil=True)(self._fn)
            return self._compiled(*args)


def kernel(fn: Callable) -> Callable:
    """``numba.njit(cache=True, nogil=True)``, with the fall-backs above.

    No fast-math: a kernel does its floating-point operations in the order written, so it
    can reproduce array code bit for bit.
    """
    return _Kernel(fn)
