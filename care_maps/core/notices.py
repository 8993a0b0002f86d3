"""Lines a stage says to the person running it while it goes on (not faults: those raise).

Library code logs them on the ``care`` logger (:func:`notice`); the CLI prints each as one
line on stderr (:func:`print_notices`), and a program embedding the stages routes them like
any logging. Used where a run does something a user would not expect but asked for, such as
a re-ingest dropping the maps built from the old store.
"""

from __future__ import annotations

import logging
import sys

__all__ = ["LOGGER_NAME", "notice", "print_notices"]

LOGGER_NAME = "care"


def notice(line: str) -> None:
    """Say ``line`` (one line, naming the file and what to do) to whoever runs the stage."""
    logging.getLogger(LOGGER_NAME).warning(line)


class _StderrLines(logging.Handler):
    """Each record as its bare message on the stderr of the moment (a test's capture too),
    on a line of its own above any progress bar being drawn."""

    def emit(self, record: logging.LogRecord) -> None:
        from tqdm import tqdm

        tqdm.write(self.format(record), file=sys.stderr)


def print_notices() -> None:
    """Print notices on stderr, once however often it is called (the CLI calls it)."""
    log = logging.getLogger(LOGGER_NAME)
    if not any(isinstance(h, _StderrLines) for h in log.handlers):
        log.addHandler(_StderrLines())
        log.setLevel(logging.INFO)
        log.propagate = False
