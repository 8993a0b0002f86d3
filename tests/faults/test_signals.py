"""Every signal that stops a job is an interruption, and output names stay within the
system's limits.

SIGTERM (SLURM, Kubernetes, Ray, systemd) and SIGHUP (a closed terminal) end ``care`` as
Ctrl-C does: its workers stop within a second, what it staged is removed, one line, exit
code 128 + N. Each case starts ``care`` as its own process and sends the real signal once a
state it can see is reached (a temporary appearing, a worker started), never after a fixed
delay. A temporary a dead run left is swept by the next run there, an up-to-date one too.
A name or path too long for the system is refused before any work, in one line; a
250-byte name still works where ``care`` names the temporaries itself.
"""

from __future__ import annotations

import contextlib
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.cli import care_popen, care_process
from tests.support.faults import EVAL_FLAGS, assert_fault, leftovers, snapshot
from tests.support.processes import alive, appears, children, loading, wait_for

pytestmark = pytest.mark.slow

WITHIN = 1.5
"""Seconds from the signal to the program's exit (its grace is care_maps.cli.main._GRACE_S)."""
SAMPLE = Path(__file__).resolve().parents[2] / "care_maps" / "data" / "sample" / "scene_000.mcap"
"""The bundled sample recording: long enough (80 frames) for a worker to be seen at work."""
RAY_SHUTDOWN_S = 3.0
"""What a local Ray's shutdown may add to a stopped ``--ray`` run's exit (its daemons end
with the program), on a busy machine."""
CODES = {signal.SIGTERM: 143, signal.SIGHUP: 129, signal.SIGINT: 130}
"""Exit code of a run stopped by each signal (128 + N)."""


def _stop(proc: subprocess.Popen[str], signum: int) -> tuple[int, str, float]:
    """Send ``signum`` to ``proc``: (exit code, stderr, seconds its exit took)."""
    sent = time.monotonic()
    proc.send_signal(signum)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    return proc.returncode, err, time.monotonic() - sent


def _dead_pid() -> int:
    """The id of a process that has ended (one of ours, waited for)."""
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    return int(done.stdout)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_fuse_grid_overwrite_stopped_by_signal(copy_good, signum: int) -> None:
    store = copy_good("store")
    before = snapshot(store)
    proc = care_popen("fuse", "grid", store, "--overwrite", "--cell-size", "0.05")
    assert wait_for(proc, appears(store, ".cell_views.parquet.tmp-*")), proc.communicate()
    code, err, took = _stop(proc, signum)
    assert_fault(code, err, r"^error: interrupted by SIG", exit_code=CODES[signum],
                 clean=(store.parent,))  # fmt: skip
    assert took < WITHIN, took
    assert {k: v for k, v in snapshot(store).items() if k in before} == before
    assert care_process("check", store).returncode == 0


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_ingest_force_stopped_by_signal(copy_good, recording: Path, signum: int) -> None:
    store = copy_good("store")
    before = snapshot(store)
    proc = care_popen("ingest", recording, "--out", store, "--encoder", "labels", "--force")
    staging = appears(store.parent, ".store.tmp-*/views.parquet")
    assert wait_for(proc, staging), proc.communicate()
    code, err, took = _stop(proc, signum)
    assert_fault(code, err, r"^error: interrupted by SIG", exit_code=CODES[signum],
                 clean=(store.parent,), intact=before)  # fmt: skip
    assert took < WITHIN, took


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_stopped_while_loading(recording: Path, tmp_path: Path, signum: int) -> None:
    """A job stopped while the program still loads its modules (a scheduler that cancels a
    job just started): one line and 128 + N, not a silent death by the signal."""
    proc = care_popen("ingest", recording, "--out", tmp_path / "store")
    assert wait_for(proc, loading(proc)), proc.communicate()
    code, err, took = _stop(proc, signum)
    assert_fault(code, err, r"^error: interrupted by SIG", exit_code=CODES[signum],
                 clean=(tmp_path,))  # fmt: skip
    assert took < WITHIN, took
    assert not (tmp_path / "store").exists()


def test_eval_workers_stopped_by_sigterm(good: Path, copy_good) -> None:
    """``care eval --workers 2`` over earlier results: the workers and multiprocessing's
    resource tracker end with the program, the staged evaluation is removed, the earlier
    results stay as they were."""
    ev = copy_good("eval")
    before = snapshot(ev)
    args = list(EVAL_FLAGS)
    args[args.index("--workers") + 1] = "2"
    args[args.index("--seeds") + 1] = "3"  # not the cached scene's: a worker evaluates it
    proc = care_popen("eval", good / "store", "--out", ev, *args)
    seen: set[int] = set()

    def working() -> bool:  # a worker (beside the resource tracker) started, the output staged
        seen.update(children(proc.pid))
        return len(seen) >= 2 and any(ev.parent.glob(f".{ev.name}.tmp-*"))

    assert wait_for(proc, working), proc.communicate()
    code, err, took = _stop(proc, signal.SIGTERM)
    assert_fault(code, err, r"^error: interrupted by SIGTERM", exit_code=143,
                 clean=(ev.parent,), intact=before)  # fmt: skip
    assert took < WITHIN, took
    _all_ended(seen)


def test_run_workers_stopped_by_sigterm(tmp_path: Path) -> None:
    """``care run --workers 2`` stopped while a worker stages its store: the worker unwinds
    its task, every process ends, and the output this run created is gone."""
    out = tmp_path / "out"
    proc = care_popen("run", SAMPLE, "--out", out, "--workers", "2", "--encoder", "labels")
    seen: set[int] = set()

    def staging() -> bool:  # a worker (beside the resource tracker) stages the store
        seen.update(children(proc.pid))
        return len(seen) >= 2 and any((out / "stores").glob(".*.tmp-*/views.parquet"))

    assert wait_for(proc, staging), proc.communicate()
    code, err, took = _stop(proc, signal.SIGTERM)
    assert_fault(code, err, r"^error: interrupted by SIGTERM", exit_code=143,
                 clean=(tmp_path,))  # fmt: skip
    assert took < WITHIN, took
    _all_ended(seen)
    assert not out.exists()


def _all_ended(pids: set[int]) -> None:
    """Every one of ``pids`` (a run's workers, its resource tracker) has ended, within a
    second of the program."""
    deadline = time.monotonic() + 1.0
    while any(map(alive, pids)) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not [pid for pid in pids if alive(pid)]


def test_up_to_date_ingest_sweeps_a_dead_runs_temporaries(care, copy_good, recording: Path) -> None:
    """A run killed outright (SIGKILL, a node lost) leaves its temporaries; the next run in
    that place removes them, also when it has nothing to do."""
    store = copy_good("store")
    dead = _dead_pid()
    beside = store.parent / f".store.tmp-{dead}"
    (beside / "views.parquet").parent.mkdir()
    (beside / "views.parquet").write_bytes(b"half")
    inside = store / f".cell_views.parquet.tmp-{dead}"
    inside.write_bytes(b"half")
    code, _, err = care("ingest", recording, "--out", store, "--encoder", "labels")
    assert code == 0, err
    assert not beside.exists()
    assert not inside.exists()
    assert not leftovers(store.parent)


LONG = "s" * 250
"""A name of 250 bytes: legal, but ``.<name>.tmp-<pid>`` is not."""


def test_eval_out_of_a_long_name(care, good: Path, tmp_path: Path) -> None:
    out = tmp_path / LONG
    code, _, err = care("eval", good / "store", "--out", out, *EVAL_FLAGS)
    assert code == 0, err
    assert care("check", out)[0] == 0
    assert not leftovers(tmp_path)


def test_fuse_a_store_of_a_long_name(care, copy_good) -> None:
    store = copy_good("store")
    store = store.rename(store.with_name(LONG))
    code, _, err = care("fuse", "grid", store, "--overwrite")
    assert code == 0, err
    assert care("check", store)[0] == 0
    assert not leftovers(store.parent)


def test_ingest_out_of_a_long_name(care, recording: Path, tmp_path: Path) -> None:
    out = tmp_path / LONG
    code, _, err = care("ingest", recording, "--out", out, "--encoder", "labels")
    assert code == 0, err
    assert care("check", out)[0] == 0
    assert not leftovers(tmp_path)


def test_ingest_out_of_a_too_long_name(care, recording: Path, tmp_path: Path) -> None:
    code, _, err = care("ingest", recording, "--out", tmp_path / ("s" * 256), "--encoder", "labels")
    assert_fault(code, err, r"^error: --out .*name of 256 bytes.*choose a shorter name",
                 clean=(tmp_path,))  # fmt: skip
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["ingest", "eval"])
def test_out_path_too_long(care, good: Path, recording: Path, tmp_path: Path, command):
    out = Path(tmp_path, *["d" * 200] * 21, "out")
    args = {
        "ingest": ("ingest", recording, "--out", out, "--encoder", "labels"),
        "eval": ("eval", good / "store", "--out", out, *EVAL_FLAGS),
    }[command]
    code, _, err = care(*args)
    assert_fault(code, err, r"^error: --out .*path of \d+ bytes.*choose a shorter path",
                 clean=(tmp_path,))  # fmt: skip
    assert list(tmp_path.iterdir()) == []


_RAY_LOG = re.compile(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+\s+(INFO|WARNING) ")
"""Ray's own start-up lines ("Started a local Ray instance", its token notice), printed by
every ``--ray`` run."""


def _descendants(pid: int) -> dict[int, str]:
    """Every process below ``pid``, with its command line (Ray's workers are the raylet's)."""
    found: dict[int, str] = {}
    todo = [pid]
    while todo:
        for child in children(todo.pop()):
            with contextlib.suppress(OSError):
                found[child] = Path(f"/proc/{child}/cmdline").read_text().replace("\0", " ")
                todo.append(child)
    return found


def test_eval_ray_task_stopped_by_sigterm(good: Path, copy_good) -> None:
    """``care eval --ray`` stopped while a Ray task evaluates a scene: the program takes
    SIGTERM back from Ray (whose handler would exit 1 without a word), cancels the task,
    shuts down the local Ray it started, and leaves the earlier results as they were."""
    pytest.importorskip("ray")
    ev = copy_good("eval")
    before = snapshot(ev)
    args = list(EVAL_FLAGS)
    args[args.index("--seeds") + 1] = "5000"  # a task that runs for a while
    proc = care_popen("eval", good / "store", "--out", ev, *args, "--ray")
    seen: dict[int, str] = {}

    def evaluating() -> bool:  # our Ray task runs, the output staged
        seen.update(_descendants(proc.pid))
        task = any(cmd.startswith("ray::_in_worker") for cmd in seen.values())
        return task and any(ev.parent.glob(f".{ev.name}.tmp-*"))

    assert wait_for(proc, evaluating), proc.communicate()
    code, err, took = _stop(proc, signal.SIGTERM)
    err = "\n".join(line for line in err.split("\n") if not _RAY_LOG.search(line))
    assert_fault(code, err, r"^error: interrupted by SIGTERM", exit_code=143,
                 clean=(ev.parent,), intact=before)  # fmt: skip
    assert took < WITHIN + RAY_SHUTDOWN_S, took
    _all_ended(set(seen))
