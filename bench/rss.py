"""Peak resident memory of this process, for the benchmarks' child processes.

``getrusage(...).ru_maxrss`` is no use in a child: Linux carries the parent's peak across
``fork`` and ``exec``, so a small child of a big benchmark process reports the parent's
figure (measured: 409 MB for a 14 MB child of a 400 MB parent). ``VmHWM`` belongs to the
process image and starts afresh at ``exec``.
"""

from __future__ import annotations

import resource

__all__ = ["current_rss_mb", "peak_rss_mb"]


def _status_mb(field: str) -> float | None:
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def peak_rss_mb() -> float:
    """Peak resident set of this process image in MB (``ru_maxrss`` where no /proc)."""
    peak = _status_mb("VmHWM")
    return peak if peak is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def current_rss_mb() -> float:
    """Resident set now in MB (the peak where no /proc)."""
    now = _status_mb("VmRSS")
    return now if now is not None else peak_rss_mb()
