"""``care ARGS`` as a test runs it: in this process (fast; exit code, stdout, stderr through
pytest's capture), or in a fresh one (``python -m care_maps.cli.main``), optionally under an
``RLIMIT_FSIZE`` or as a terminal's job to signal."""

from __future__ import annotations

import ctypes
import os
import resource
import signal
import subprocess
import sys
from pathlib import Path
from typing import Final, TypeAlias

import pytest

ROOT: Final = Path(__file__).resolve().parents[2]
"""The checkout: a fresh process runs here, with it first on ``PYTHONPATH``."""

Outcome: TypeAlias = tuple[int, str, str]
"""``(exit code, stdout, stderr)`` of one in-process run."""


def call_main(*args: object) -> str | int | None:
    """Run ``care ARGS`` in this process through ``care_maps.cli.main.main``, ``sys.argv``
    restored after: the code of the ``SystemExit`` it ended with, as raised (None when it
    returned or exited without one)."""
    from care_maps.cli import main as cli

    argv = sys.argv
    sys.argv = ["care", *map(str, args)]
    try:
        cli.main()
    except SystemExit as exc:
        return exc.code
    finally:
        sys.argv = argv
    return None


def run_in_process(capsys: pytest.CaptureFixture[str], *args: object) -> Outcome:
    """Run ``care ARGS`` in this process (:func:`call_main`): (exit code, stdout, stderr),
    read from ``capsys`` (which it empties)."""
    code = int(call_main(*args) or 0)
    out, err = capsys.readouterr()
    return code, out, err


class InProcessCli:
    """``care`` in this process, bound to a test's ``capsys``: ``cli(*args)`` is
    :func:`run_in_process`."""

    def __init__(self, capsys: pytest.CaptureFixture[str]) -> None:
        self.capsys = capsys

    def __call__(self, *args: object) -> Outcome:
        return run_in_process(self.capsys, *args)


def care_env() -> dict[str, str]:
    """A fresh process's environment: no progress bars, the checkout importable, one
    OpenMP thread unless the caller's says otherwise."""
    env = dict(os.environ)
    env["TQDM_DISABLE"] = "1"
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("OMP_NUM_THREADS", "1")
    return env


def drop_dac() -> None:
    """Without CAP_DAC_OVERRIDE / CAP_DAC_READ_SEARCH, so chmod binds even for root."""
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        libc.prctl(24, cap, 0, 0, 0)  # PR_CAPBSET_DROP; EPERM when not root: nothing to drop


def care_process(
    *args: object, fsize: int | None = None, timeout: float = 300
) -> subprocess.CompletedProcess[str]:
    """Run ``care ARGS`` in a fresh process (optionally under an ``RLIMIT_FSIZE``)."""

    def preexec() -> None:
        drop_dac()
        if fsize is not None:  # Python ignores SIGXFSZ: writes past it fail with EFBIG
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    return subprocess.run(
        [sys.executable, "-m", "care_maps.cli.main", *map(str, args)],
        cwd=ROOT,
        env=care_env(),
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=preexec,
        check=False,
    )


def as_a_terminal_job() -> None:
    """The child as a job a terminal or a scheduler started: SIGHUP and SIGTERM at their
    default, whatever the test runner inherited (under ``nohup`` SIGHUP is ignored, and the
    program rightly keeps ignoring it), and without CAP_DAC_* (:func:`drop_dac`)."""
    for signum in (signal.SIGHUP, signal.SIGTERM):
        signal.signal(signum, signal.SIG_DFL)
    drop_dac()


def care_popen(*args: object) -> subprocess.Popen[str]:
    """Start ``care ARGS`` in a fresh process as a terminal's job (:func:`as_a_terminal_job`),
    stdout and stderr piped."""
    return subprocess.Popen(
        [sys.executable, "-m", "care_maps.cli.main", *map(str, args)],
        cwd=ROOT,
        env=care_env(),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=as_a_terminal_job,
    )


def after_care(argv: list[str], expression: str, cwd: Path | None = None) -> str:
    """``repr`` of ``expression`` (Python, ``sys`` in scope) evaluated in a fresh interpreter
    after ``care ARGV`` ran there through ``care_maps.cli.main.main``: what a command
    imported, for the start-up tests."""
    code = (
        "import sys\n"
        "from care_maps.cli import main as cli\n"
        f"sys.argv = ['care', *{argv!r}]\n"
        "try:\n"
        "    cli.main()\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print(repr({expression}))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=cwd
    )
    return done.stdout.strip().splitlines()[-1]
