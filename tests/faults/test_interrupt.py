"""Ctrl-C ends every command quickly with exit code 130 and one line, at any moment: while
the program loads, while it works, while it writes. What it was writing is removed, and
the earlier output is as it was.

Each case starts ``care`` as its own process (as a shell does) and sends SIGINT at a
spread of moments over the command's run, each a state the test can see (the program
loading its modules, its lock taken, its temporary staged, its output committed) rather
than a fixed delay, which a loaded machine stretches past any margin; the line must come
within a second, allowing this test some slack for a loaded machine.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.support.cli import care_popen, care_process
from tests.support.faults import EVAL_FLAGS, assert_fault, leftovers, snapshot
from tests.support.processes import appears, loading, wait_for

pytestmark = pytest.mark.slow

WITHIN = 1.5
"""Seconds from Ctrl-C to exit: the program's grace is 0.8 s (care_maps.cli.main._GRACE_S)."""


def _changed(path: Path) -> Callable[[], bool]:
    """``path`` was replaced (a new file committed over it) or appeared."""
    path = Path(path)
    before = (path.stat().st_ino, path.stat().st_mtime_ns) if path.exists() else None
    return lambda: path.exists() and (path.stat().st_ino, path.stat().st_mtime_ns) != before


MOMENTS = ("loading", "locked", "staged", "committed")
"""States at which Ctrl-C comes: the program loading its modules, holding its output's lock,
writing its temporary, and having committed its output (about to exit)."""


def _interrupt(
    args: tuple[object, ...], at: Callable[[object], Callable[[], bool]]
) -> tuple[int | None, str, float]:
    """Run ``care ARGS``, Ctrl-C it once ``at(proc)()`` holds: (exit code, stderr, seconds the
    exit took after the signal; 0 when it had finished before)."""
    proc = care_popen(*args)
    if not wait_for(proc, at(proc)):
        _, err = proc.communicate()
        return proc.returncode, err, 0.0
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=30)
    except Exception:
        proc.kill()
        raise
    return proc.returncode, err, time.monotonic() - sent


def _check(code: int | None, err: str, took: float) -> None:
    if code == 0:
        # finished before the signal came, or the signal came as the finished program was
        # exiting (a poll then a send is a race): the callers check the outputs are whole
        assert took < WITHIN, took
        return
    # on a loaded machine the unwinding may outlast the grace: what it left is a temporary
    # of a dead process, which the re-run each test makes must sweep (checked there)
    assert_fault(code, err, r"^error: interrupted", exit_code=130)
    assert took < WITHIN, took


@pytest.mark.parametrize("moment", MOMENTS)
def test_ctrl_c_during_fuse_grid_overwrite(copy_good, moment: str) -> None:
    store = copy_good("store")
    before = snapshot(store)
    at = {
        "loading": loading,
        "locked": lambda _: appears(store.parent, f".{store.name}.lock"),
        "staged": lambda _: appears(store, ".cell_views.parquet.tmp-*"),
        "committed": lambda _: _changed(store / "cells.parquet"),
    }[moment]
    code, err, took = _interrupt(("fuse", "grid", store, "--overwrite"), at)
    _check(code, err, took)
    assert snapshot(store) == before  # the old map, or the same map built again
    assert care_process("fuse", "grid", store).returncode == 0
    assert not leftovers(store.parent)


@pytest.mark.parametrize("moment", MOMENTS)
def test_ctrl_c_during_ingest(recording: Path, tmp_path: Path, moment: str) -> None:
    out = tmp_path / "store"
    at = {
        "loading": loading,
        "locked": lambda _: appears(tmp_path, ".store.lock"),
        "staged": lambda _: appears(tmp_path, ".store.tmp-*/views.parquet"),
        "committed": lambda _: _changed(out / "meta.json"),
    }[moment]
    code, err, took = _interrupt(("ingest", recording, "--out", out), at)
    _check(code, err, took)
    if out.exists():  # committed whole before the signal came, or not at all
        assert care_process("check", out).returncode == 0
    assert care_process("ingest", recording, "--out", out).returncode == 0
    assert not leftovers(tmp_path)


@pytest.mark.parametrize("moment", MOMENTS[1:3])
def test_ctrl_c_during_eval_over_earlier_results(good: Path, copy_good, moment: str) -> None:
    ev = copy_good("eval")
    before = snapshot(ev)
    at = {
        "locked": lambda _: appears(ev.parent, f".{ev.name}.lock"),
        "staged": lambda _: appears(ev.parent, f".{ev.name}.tmp-*"),
    }[moment]
    code, err, took = _interrupt(("eval", good / "store", "--out", ev, *EVAL_FLAGS), at)
    _check(code, err, took)
    assert snapshot(ev) == before  # the same inputs: the old results or identical new ones
    assert care_process("eval", good / "store", "--out", ev, *EVAL_FLAGS).returncode == 0
    assert not leftovers(ev.parent)
    assert snapshot(ev) == before


def test_a_job_started_to_ignore_ctrl_c_keeps_ignoring_it(copy_good) -> None:
    """A shell's background job (``care ... &`` in a script) starts with SIGINT ignored; it is
    not ours to undo that (``nohup`` relies on it)."""
    import subprocess
    import sys

    store = copy_good("store")
    proc = subprocess.Popen(
        [sys.executable, "-c", "import signal, runpy, sys; signal.signal(signal.SIGINT, "
         "signal.SIG_IGN); sys.argv = ['care', 'fuse', 'grid', sys.argv[1], '--overwrite'];"
         " runpy.run_module('care_maps.cli.main', run_name='__main__')", str(store)],
        cwd=Path(__file__).resolve().parents[2], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )  # fmt: skip
    assert wait_for(proc, appears(store.parent, f".{store.name}.lock")), proc.communicate()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
