"""Watching a running ``care`` process from outside: waiting for a state it can be seen in
(never a fixed delay, which a busy machine stretches past any margin), its children, whether
it still runs."""

from __future__ import annotations

import contextlib
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Final

WAIT_S: Final = 120.0
"""How long a test waits for a state it signals at: generous, for a loaded CI machine."""


def wait_for(
    proc: subprocess.Popen[str], seen: Callable[[], object], timeout: float = WAIT_S
) -> bool:
    """Poll until ``seen()`` is true while ``proc`` runs: whether it was (False: ``proc``
    ended first). A fault test signals at a state it can see (a temporary appearing, a module
    loaded), never after a fixed delay, which a busy machine stretches past any margin."""
    deadline = time.monotonic() + timeout
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            if seen():
                return proc.poll() is None
        except OSError:  # a path that vanished while looked at
            pass
        time.sleep(0.002)
    assert time.monotonic() < deadline, f"not seen within {timeout} s"
    return False


def loading(proc: subprocess.Popen[str]) -> Callable[[], bool]:
    """The program is loading its modules: numpy's compiled core is mapped (the first big
    import, past the interpreter's own start-up)."""
    maps = Path(f"/proc/{proc.pid}/maps")
    return lambda: "_multiarray_umath" in maps.read_text()


def appears(folder: Path, pattern: str) -> Callable[[], bool]:
    """A path matching ``pattern`` exists in ``folder`` (a temporary, a lock, a table)."""
    return lambda: any(Path(folder).glob(pattern))


def children(pid: int) -> set[int]:
    """The processes whose parent is ``pid`` (its workers, multiprocessing's resource
    tracker)."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, ValueError, IndexError):
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:
                found.add(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie is not running)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"
