"""Outputs of many files change as one unit: an evaluation (``care eval``) and the evaluation
and stores of ``care run``, killed at any instant over earlier results, are the old version
or the new one, byte for byte, never a mix; a re-run then finishes and leaves no temporary;
``care check`` verifies an evaluation and names a damaged file.

Kill points are deterministic: the command runs in a child process whose file-system calls
(``os.replace``, ``os.rename``, ``os.link``, ``os.unlink``, ``os.rmdir``, ``os.mkdir`` and
``care_maps.core.outputs.exchange``) on the output's folder are counted; before each one the child
copies the folder aside (what a kill at that instant leaves behind, since nothing happens on
disk between two such calls that is not in a temporary), or kills itself with ``SIGKILL``
at the chosen one. One run of the child so gives every kill point of the command.
"""

from __future__ import annotations

import base64
import errno
import hashlib
import os
import pickle
import re
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.support.cli import call_main, care_popen
from tests.support.faults import EVAL_FLAGS, assert_fault, leftovers

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
NEW_MAPS = ("--maps", "instances,grid")
"""The new evaluation over the earlier one (``--maps instances``)."""

HOOK = r"""
import errno, os, shutil, signal, sys

WATCH = os.path.realpath(os.environ["CARE_HOOK_WATCH"])
SNAPS = os.environ.get("CARE_HOOK_SNAPSHOTS")
KILL_AT = int(os.environ.get("CARE_HOOK_KILL_AT") or 0)
count = 0
busy = False


def _watched(args, kwargs):
    fd = kwargs.get("dir_fd", kwargs.get("src_dir_fd"))
    for arg in args:
        if isinstance(arg, (str, bytes, os.PathLike)):
            path = os.fsdecode(os.fspath(arg))
            if fd is not None and not os.path.isabs(path):
                path = os.path.join(os.readlink(f"/proc/self/fd/{fd}"), path)
            path = os.path.realpath(path)
            if path == WATCH or path.startswith(WATCH + os.sep):
                return True
    return False


def _counted(owner, name):
    real = getattr(owner, name)

    def op(*args, **kwargs):
        global count, busy
        if not busy and _watched(args, kwargs):
            busy = True
            try:
                count += 1
                if SNAPS:
                    shutil.copytree(WATCH, os.path.join(SNAPS, f"{count:05d}"), symlinks=True)
                    with open(os.path.join(SNAPS, "ops.log"), "a") as log:
                        log.write(f"{count} {name} {' '.join(map(str, args))}\n")
                if count == KILL_AT:
                    os.kill(os.getpid(), signal.SIGKILL)
            finally:
                busy = False
        return real(*args, **kwargs)

    setattr(owner, name, op)


import care_maps.core.outputs as outputs

if os.environ.get("CARE_HOOK_NO_EXCHANGE"):
    def _unsupported(a, b):
        raise OSError(errno.EINVAL, "RENAME_EXCHANGE not supported here", str(a))

    outputs.exchange = _unsupported
for name in ("replace", "rename", "link", "unlink", "rmdir", "mkdir"):
    _counted(os, name)
_counted(outputs, "exchange")
exec(os.environ["CARE_HOOK_MAIN"])
"""

EVAL_MAIN = "from care_maps.cli.main import main\nsys.argv = ['care', *sys.argv[1:]]\nmain()"
RUN_MAIN = (
    "import base64, pickle\nfrom care_maps.evaluate.pipeline import run_all\n"
    "*args, run = pickle.loads(base64.b64decode(os.environ['CARE_HOOK_ARGS']))\n"
    "run_all(*args, run=run)"
)


def _hooked(
    main: str,
    *args: object,
    watch: Path,
    snapshots: Path | None = None,
    kill_at: int = 0,
    no_exchange: bool = False,
    payload: object = None,
) -> subprocess.CompletedProcess[str]:
    """Run ``main`` (Python code) with ``args`` in a child whose file-system calls under
    ``watch`` are counted: a copy of ``watch`` in ``snapshots/NNNNN`` before call N, or
    ``SIGKILL`` at call ``kill_at``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("CARE_HOOK_")}
    env.update(
        TQDM_DISABLE="1",
        OMP_NUM_THREADS="1",
        PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""),
        CARE_HOOK_WATCH=str(watch),
        CARE_HOOK_MAIN=main,
    )
    if snapshots is not None:
        snapshots.mkdir(parents=True, exist_ok=True)
        env["CARE_HOOK_SNAPSHOTS"] = str(snapshots)
    if kill_at:
        env["CARE_HOOK_KILL_AT"] = str(kill_at)
    if no_exchange:
        env["CARE_HOOK_NO_EXCHANGE"] = "1"
    if payload is not None:
        env["CARE_HOOK_ARGS"] = base64.b64encode(pickle.dumps(payload)).decode()
    return subprocess.run(
        [sys.executable, "-c", HOOK, *map(str, args)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


def _files(root: Path) -> dict[str, str]:
    """Every file under ``root`` (hidden ones too, not lock files): relative path -> hash."""
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(Path(root).rglob("*"))
        if p.is_file() and not p.name.endswith(".lock")
    }


def _others(folder: Path, name: str) -> tuple[str, ...]:
    """The temporaries and lock of output ``name`` beside it in ``folder``, their pid left
    out."""
    return tuple(
        sorted(
            re.sub(r"-\d+$", "-PID", p.name)
            for p in folder.iterdir()
            if p.name.startswith(f".{name}.")
        )
    )


def _snapshots(root: Path) -> list[Path]:
    return sorted(p for p in root.iterdir() if p.is_dir())


def _ops(root: Path) -> list[str]:
    return (root / "ops.log").read_text().splitlines()


@dataclass(frozen=True)
class Versions:
    """An output's earlier version and the one a command makes over it."""

    old: Path
    new: Path

    def which(self, out: Path) -> str:
        """``old``, ``new``, ``missing`` or ``MIXED``: what ``out`` holds."""
        if not out.exists():
            return "missing"
        files = _files(out)
        if files == _files(self.old):
            return "old"
        return "new" if files == _files(self.new) else "MIXED"


def _cli(*args: object) -> None:
    """``care ARGS`` in this process (for fixtures of a wider scope than ``care``)."""
    code = call_main(*args)
    assert not code, (args, code)


@pytest.fixture(scope="module")
def evals(good: Path, tmp_path_factory: pytest.TempPathFactory) -> Versions:
    """``care eval --maps instances`` and then ``--maps instances,grid`` over it."""
    root = tmp_path_factory.mktemp("atomic_evals")
    os.environ["TQDM_DISABLE"] = "1"
    _cli("eval", good / "store", "--out", root / "old", *EVAL_FLAGS, "--maps", "instances")
    shutil.copytree(root / "old", root / "new")
    _cli("eval", good / "store", "--out", root / "new", *EVAL_FLAGS, *NEW_MAPS)
    versions = Versions(root / "old", root / "new")
    assert _files(versions.old) != _files(versions.new)
    assert not list(root.rglob(".*"))  # nothing left beside or inside them
    return versions


def _over_old(evals: Versions, folder: Path) -> Path:
    folder.mkdir(parents=True)
    shutil.copytree(evals.old, folder / "ev")
    return folder / "ev"


def _resume_eval(care, good: Path, evals: Versions, snapshot: Path, where: Path) -> None:
    """From what a kill left (``snapshot``), the same command again: it finishes, and
    leaves the new version and no temporary."""
    shutil.copytree(snapshot, where, symlinks=True)
    code, _, err = care("eval", good / "store", "--out", where / "ev", *EVAL_FLAGS, *NEW_MAPS)
    assert code == 0, err
    assert evals.which(where / "ev") == "new"
    assert not leftovers(where)


def _one_of_each(snaps: list[Path], state) -> dict[tuple, Path]:
    """The first snapshot of each distinct state."""
    firsts: dict[tuple, Path] = {}
    for snap in snaps:
        firsts.setdefault(state(snap), snap)
    return firsts


# -- (a) the reported case ------------------------------------------------------------------


def test_eval_killed_when_attempts_change_is_old_or_new(
    care, good: Path, evals: Versions, tmp_path: Path
) -> None:
    """``care eval --maps instances,grid`` over ``--maps instances`` results, killed the
    moment ``attempts.parquet`` changes: the folder is the old results or the new."""
    out = _over_old(evals, tmp_path / "w")
    before = (out / "attempts.parquet").stat()
    proc = care_popen("eval", good / "store", "--out", out, *EVAL_FLAGS, *NEW_MAPS)
    deadline = time.monotonic() + 240
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            now = (out / "attempts.parquet").stat()
        except FileNotFoundError:
            break
        if (now.st_ino, now.st_size, now.st_mtime_ns) != (
            before.st_ino,
            before.st_size,
            before.st_mtime_ns,
        ):
            break
        time.sleep(0.001)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    assert evals.which(out) in ("old", "new")
    code, _, err = care("eval", good / "store", "--out", out, *EVAL_FLAGS, *NEW_MAPS)
    assert code == 0, err
    assert evals.which(out) == "new"
    assert not leftovers(out.parent)


# -- (b) a kill at every step ---------------------------------------------------------------


def test_eval_killed_anywhere_is_old_or_new(
    care, good: Path, evals: Versions, tmp_path: Path
) -> None:
    out = _over_old(evals, tmp_path / "w")
    snaps_dir = tmp_path / "snaps"
    r = _hooked(
        EVAL_MAIN, "eval", good / "store", "--out", out, *EVAL_FLAGS, *NEW_MAPS,
        watch=out.parent, snapshots=snaps_dir,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert evals.which(out) == "new"
    snaps = _snapshots(snaps_dir)
    assert len(snaps) >= 10, _ops(snaps_dir)
    states = {snap.name: (evals.which(snap / "ev"), _others(snap, "ev")) for snap in snaps}
    assert {which for which, _ in states.values()} == {"old", "new"}, states
    # the window between the swap and the removal of the previous version was seen
    assert ("new", (".ev.lock", ".ev.tmp-PID")) in states.values(), states
    # resumed from inside the staging and from between the swap and the clean-up
    firsts = _one_of_each(snaps, lambda s: states[s.name])
    staged = [snap for state, snap in firsts.items() if ".ev.tmp-PID" in state[1]]
    assert len(staged) == 2, firsts
    for i, snap in enumerate(staged):
        _resume_eval(care, good, evals, snap, tmp_path / f"resume{i}")


# -- (c) care run ---------------------------------------------------------------------------


def _serial():
    """How the fault suite's ``care run`` runs: one recording after another, no bars."""
    from care_maps.runtime.execution import Execution

    return Execution(workers=1, progress=False)


def _run_config(seeds: int):
    """``care run`` on the fault suite's recording: its maps as the ``good`` store's, the
    evaluation as ``EVAL_FLAGS`` but for ``seeds``."""
    from care_maps.evaluate.config import EvalConfig, RunConfig
    from care_maps.fuse.grid import GridConfig
    from care_maps.fuse.instances import InstanceConfig

    evaluation = EvalConfig(seeds=seeds, bootstrap=10, k_grid=(4, 8), k_instances=(2, 4))
    return RunConfig(
        encoder="labels", grid=GridConfig(cell_size=0.1),
        instances=InstanceConfig(proposals="labels"), evaluation=evaluation, rrd_ingest=False,
    )  # fmt: skip


@dataclass(frozen=True)
class Runs:
    old: Path
    new: Path


@pytest.fixture(scope="module")
def runs(recording: Path, tmp_path_factory: pytest.TempPathFactory) -> Runs:
    """``care run`` with 1 seed, then with 2 over it (the maps stay, the evaluation changes)."""
    from care_maps.evaluate.pipeline import run_all

    root = tmp_path_factory.mktemp("atomic_runs")
    run_all(recording, root / "old", _run_config(1), run=_serial())
    shutil.copytree(root / "old", root / "new")
    run_all(recording, root / "new", _run_config(2), run=_serial())
    runs = Runs(root / "old", root / "new")
    assert _files(runs.old / "stores") == _files(runs.new / "stores")
    assert _files(runs.old / "eval") != _files(runs.new / "eval")
    return runs


def _run_state(runs: Runs, run: Path) -> tuple[str, tuple[str, ...]]:
    """Which evaluation ``run/eval`` is (its stores must be the same throughout)."""
    assert _files(run / "stores") == _files(runs.old / "stores")
    return Versions(runs.old / "eval", runs.new / "eval").which(run / "eval"), _others(run, "eval")


def test_run_killed_anywhere_is_old_or_new(
    care, recording: Path, runs: Runs, tmp_path: Path
) -> None:
    from care_maps.evaluate.pipeline import run_all

    run = tmp_path / "w" / "run"
    shutil.copytree(runs.old, run)
    snaps_dir = tmp_path / "snaps"
    r = _hooked(
        RUN_MAIN, watch=run.parent, snapshots=snaps_dir,
        payload=(recording, run, _run_config(2), _serial()),
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    snaps = _snapshots(snaps_dir)
    assert len(snaps) >= 10, _ops(snaps_dir)
    states = {snap.name: _run_state(runs, snap / "run") for snap in snaps}
    assert {which for which, _ in states.values()} == {"old", "new"}, states
    assert any(w == "new" and ".eval.tmp-PID" in o for w, o in states.values()), states
    # resumed from between the swap and the clean-up: the dead run's temporary (the
    # previous evaluation) is swept, not taken for anything
    after = [s for s in snaps if states[s.name] == ("new", (".eval.lock", ".eval.tmp-PID"))]
    assert after, states
    snap = after[0]
    where = tmp_path / "resume"
    shutil.copytree(snap, where, symlinks=True)
    run_all(recording, where / "run", _run_config(2), run=_serial())
    assert _run_state(runs, where / "run")[0] == "new"
    assert not leftovers(where)
    code, out, err = care("check", where / "run")
    assert code == 0, err
    assert out.strip() == f"{where / 'run'}: ok (1 stores and its evaluation verified)"


# -- (d) care check -------------------------------------------------------------------------


def test_check_verifies_an_evaluation(care, good: Path, evals: Versions, tmp_path: Path) -> None:
    out = tmp_path / "ev"
    shutil.copytree(evals.new, out)
    files = len([p for p in out.rglob("*") if p.is_file()]) - 1  # not the marker
    code, stdout, err = care("check", out)
    assert (code, err) == (0, "")
    assert stdout.strip() == f"{out}: ok ({files} files verified)"
    for damage in ("summary.parquet", "scenes/store.parquet", "plots/success_grid_exclude-1m.png"):
        path = out / damage
        kept = path.read_bytes()
        if damage.endswith(".png"):
            path.unlink()
        else:
            path.write_bytes(kept[:500])
        code, _, err = care("check", out)
        assert_fault(
            code, err, rf"^error: {re.escape(str(path))}: missing, truncated or altered since it "
            rf"was written; re-run `care eval` with --out {re.escape(str(out))}",
            clean=(tmp_path,),
        )  # fmt: skip
        path.write_bytes(kept)
    # a re-run writes what is damaged again, the cached scene included
    for damage in ("summary.parquet", "scenes/store.parquet"):
        (out / damage).write_bytes((out / damage).read_bytes()[:500])
    code, _, err = care("eval", good / "store", "--out", out, *EVAL_FLAGS, *NEW_MAPS)
    assert code == 0, err
    assert evals.which(out) == "new"
    assert care("check", out)[0] == 0


# -- (e) without RENAME_EXCHANGE ------------------------------------------------------------


def test_eval_killed_anywhere_without_exchange(
    care, good: Path, evals: Versions, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Where the two directories cannot be exchanged, the old one is renamed aside and the
    new one into place: a kill between the two leaves the output missing, and the next run
    or ``care check`` puts the old version back."""
    from care_maps.core import outputs

    def unsupported(a: Path, b: Path) -> None:
        raise OSError(errno.EINVAL, "RENAME_EXCHANGE not supported here", str(a))

    monkeypatch.setattr(outputs, "exchange", unsupported)
    out = _over_old(evals, tmp_path / "w")
    snaps_dir = tmp_path / "snaps"
    args = ("eval", good / "store", "--out", out, *EVAL_FLAGS, *NEW_MAPS)
    r = _hooked(EVAL_MAIN, *args, watch=out.parent, snapshots=snaps_dir, no_exchange=True)
    assert r.returncode == 0, r.stderr
    assert evals.which(out) == "new"
    assert not leftovers(out.parent)
    snaps = _snapshots(snaps_dir)
    states = {snap.name: (evals.which(snap / "ev"), _others(snap, "ev")) for snap in snaps}
    assert {which for which, _ in states.values()} == {"old", "new", "missing"}, states
    for snap in snaps:
        if states[snap.name][0] == "missing":  # the previous version is aside, whole
            (aside,) = snap.glob(".ev.old-*")
            assert Versions(evals.old, evals.new).which(aside) == "old"
    # killed between the two renames: `care check` puts the previous version back, and so
    # does the next run, which then finishes
    missing = next(s for s in snaps if states[s.name][0] == "missing")
    for where in (tmp_path / "checked", tmp_path / "resumed"):
        shutil.copytree(missing, where, symlinks=True)
    code, stdout, err = care("check", tmp_path / "checked" / "ev")
    assert (code, err) == (0, "")
    assert stdout.startswith(f"{tmp_path / 'checked' / 'ev'}: ok")
    assert evals.which(tmp_path / "checked" / "ev") == "old"
    assert _others(tmp_path / "checked", "ev") == (".ev.lock", ".ev.tmp-PID")  # a run sweeps
    code, _, err = care(*args[:2], "--out", tmp_path / "resumed" / "ev", *args[4:])
    assert code == 0, err
    assert evals.which(tmp_path / "resumed" / "ev") == "new"
    assert not leftovers(tmp_path / "resumed")
