"""The ``care`` command-line program: sits on top and imports the stages.

Importing the package is the first thing the program does (``python -m care_maps.cli.main`` and
the ``care`` script alike), so a Ctrl-C, SIGTERM or SIGHUP while it loads is handled from
here on: one line and exit code 128 + N (:mod:`care_maps.cli.main` takes over once a command
runs), not a traceback from whichever import it interrupted nor a silent death by the
signal.
"""

from __future__ import annotations

import os
import signal
import sys

from care_maps.runtime.signals import exit_code, stop_line

INTERRUPTED = 130
"""Exit code of a run stopped by Ctrl-C (128 + SIGINT), as shells report it."""


def stop_while_loading(signum: int, frame: object) -> None:
    """An interruption before any command runs: nothing is written yet, so leave at once."""
    os.write(2, stop_line(signum))
    os._exit(exit_code(signum))


def _is_program() -> bool:
    """Whether this process is starting the ``care`` program (``sys.argv[0]`` is ``-m``
    while ``python -m`` looks for the module), not a test or a worker importing it."""
    return sys.argv[:1] == ["-m"] or sys.argv[0].rsplit("/", 1)[-1] == "care"


_DEFAULTS = {
    signal.SIGINT: signal.default_int_handler,
    signal.SIGTERM: signal.SIG_DFL,
    signal.SIGHUP: signal.SIG_DFL,
}
"""The interrupting signals and their handlers where nothing changed them (one ignored, as
``nohup`` asks, stays ignored)."""

if _is_program():
    for _signum, _default in _DEFAULTS.items():
        if signal.getsignal(_signum) is _default:
            signal.signal(_signum, stop_while_loading)
