"""Keep freed memory mapped, so per-frame arrays reuse resident pages.

glibc returns large freed blocks to the kernel (``munmap`` above a dynamic threshold, a trim
of the heap top otherwise). A per-frame pipeline that allocates and frees megabytes of
temporaries per frame then takes a page fault for every 4 KiB of every new array, and on
virtual machines that costs more than the arithmetic on them: the grid's per-pixel
geometry at 640x480 took 16 ms per frame that way and 5 ms with the thresholds pinned
(``bench/fuse.py``). Pinning them keeps freed pages in the heap for the next frame. Peak
memory stays about the same (ingest of 211 frames with the labels encoder: 1339 MB against
1334 MB); freed memory is just not handed back before exit.

Called once by the ``care`` program and the benchmarks; a library importer keeps its own
allocator settings. A no-op where the C library is not glibc.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

__all__ = ["keep_freed_memory", "resident_bytes"]

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_MMAP_MAX_THRESHOLD = 32 << 20  # glibc's upper limit on 64-bit: larger blocks stay mmap'ed
_NO_TRIM = 2**31 - 1  # the largest an int holds: 2 GiB free at the heap top before a trim


def keep_freed_memory() -> bool:
    """Pin glibc's mmap and trim thresholds; True when the C library took both settings."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_MAX_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, _NO_TRIM)
    )


def resident_bytes() -> int:
    """Resident memory of this process now (0 where ``/proc`` is missing): what a memory
    budget already has to carry before a stage allocates."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0
