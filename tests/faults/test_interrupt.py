"""Ctrl-C ends every command quickly with exit code 130 and one line, at any moment: while
the program loads, while it works, while it writes. What it was writing is removed, and
the earlier output is as it was.

Each case starts ``care`` as its own process (as a shell does) and sends SIGINT at a
spread of moments over the command's run; the line must come within a second, allowing
this test some slack for a loaded machine.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

MOMENTS = (0.15, 0.5, 1.0, 1.8, 2.6)
"""Seconds after the start at which Ctrl-C comes (the program loads for the first ~0.5 s)."""
WITHIN = 1.5
"""Seconds from Ctrl-C to exit: the program's grace is 0.8 s (care_cli.main._GRACE_S)."""


def _interrupt(fx, args: tuple[object, ...], after: float) -> tuple[int | None, str, float]:
    """Run ``care ARGS``, Ctrl-C it ``after`` seconds in: (exit code, stderr, seconds the
    exit took after the signal; 0 when it had finished before)."""
    proc = fx.care_popen(*args)
    time.sleep(after)
    if proc.poll() is not None:
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


def _check(fx, code: int | None, err: str, took: float) -> None:
    if code == 0:
        # finished before the signal came, or the signal came as the finished program was
        # exiting (a poll then a send is a race): the callers check the outputs are whole
        assert took < WITHIN, took
        return
    # on a loaded machine the unwinding may outlast the grace: what it left is a temporary
    # of a dead process, which the re-run each test makes must sweep (checked there)
    fx.assert_fault(code, err, r"^error: interrupted", exit_code=130)
    assert took < WITHIN, took


@pytest.mark.parametrize("after", MOMENTS)
def test_ctrl_c_during_fuse_grid_overwrite(fx, copy_good, after: float) -> None:
    store = copy_good("store")
    before = fx.snapshot(store)
    code, err, took = _interrupt(fx, ("fuse", "grid", store, "--overwrite"), after)
    _check(fx, code, err, took)
    assert fx.snapshot(store) == before  # the old map, or the same map built again
    assert fx.care_process("fuse", "grid", store).returncode == 0
    assert not fx.leftovers(store.parent)


@pytest.mark.parametrize("after", MOMENTS)
def test_ctrl_c_during_ingest(fx, recording: Path, tmp_path: Path, after: float) -> None:
    out = tmp_path / "store"
    code, err, took = _interrupt(fx, ("ingest", recording, "--out", out), after)
    _check(fx, code, err, took)
    if out.exists():  # committed whole before the signal came, or not at all
        assert fx.care_process("check", out).returncode == 0
    assert fx.care_process("ingest", recording, "--out", out).returncode == 0
    assert not fx.leftovers(tmp_path)


@pytest.mark.parametrize("after", MOMENTS[1::2])
def test_ctrl_c_during_eval_over_earlier_results(fx, good: Path, copy_good, after: float) -> None:
    ev = copy_good("eval")
    before = fx.snapshot(ev)
    code, err, took = _interrupt(fx, ("eval", good / "store", "--out", ev, *fx.EVAL_FLAGS), after)
    _check(fx, code, err, took)
    assert fx.snapshot(ev) == before  # the same inputs: the old results or identical new ones
    assert fx.care_process("eval", good / "store", "--out", ev, *fx.EVAL_FLAGS).returncode == 0
    assert not fx.leftovers(ev.parent)
    assert fx.snapshot(ev) == before


def test_a_job_started_to_ignore_ctrl_c_keeps_ignoring_it(fx, copy_good) -> None:
    """A shell's background job (``care ... &`` in a script) starts with SIGINT ignored; it is
    not ours to undo that (``nohup`` relies on it)."""
    import subprocess
    import sys

    store = copy_good("store")
    proc = subprocess.Popen(
        [sys.executable, "-c", "import signal, runpy, sys; signal.signal(signal.SIGINT, "
         "signal.SIG_IGN); sys.argv = ['care', 'fuse', 'grid', sys.argv[1], '--overwrite'];"
         " runpy.run_module('care_cli.main', run_name='__main__')", str(store)],
        cwd=Path(__file__).resolve().parents[2], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )  # fmt: skip
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
