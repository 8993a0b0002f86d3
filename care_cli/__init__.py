"""The ``care`` command-line program: sits on top and imports the stages.

Importing the package is the first thing the program does (``python -m care_cli.main`` and
the ``care`` script alike), so a Ctrl-C while it loads is handled from here on: one line and
exit code 130 (:mod:`care_cli.main` takes over once a command runs), not a traceback from
whichever import it interrupted.
"""

from __future__ import annotations

import os
import signal
import sys

INTERRUPTED = 130
"""Exit code of a run stopped by Ctrl-C (128 + SIGINT), as shells report it."""
INTERRUPTED_LINE = b"error: interrupted; nothing half-written was left behind\n"
"""What a Ctrl-C prints, whenever it comes."""


def stop_while_loading(signum: int, frame: object) -> None:
    """Ctrl-C before any command runs: nothing is written yet, so leave at once."""
    os.write(2, INTERRUPTED_LINE)
    os._exit(INTERRUPTED)


def _is_program() -> bool:
    """Whether this process is starting the ``care`` program (``sys.argv[0]`` is ``-m``
    while ``python -m`` looks for the module), not a test or a worker importing it."""
    return sys.argv[:1] == ["-m"] or sys.argv[0].rsplit("/", 1)[-1] == "care"


if _is_program() and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
    signal.signal(signal.SIGINT, stop_while_loading)
