"""Entry point of the ``care`` program.

Each stage's commands live in their own module here and register themselves on ``app``.
Any :class:`care.errors.CareError` becomes one line on stderr and exit code 1.
"""

from __future__ import annotations

import sys

import typer

from care.errors import CareError
from care.malloc import keep_freed_memory
from care.threads import Work, use_threads

app = typer.Typer(
    name="care",
    help="CARe maps: recordings in, open-vocabulary maps, queries and context-aware replanning out.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


def _register() -> None:
    from care_cli import eval_cmd, fuse_cmd, ingest_cmd, sample_cmd

    for module in (ingest_cmd, sample_cmd, fuse_cmd, eval_cmd):
        module.register(app)


def main() -> None:
    """Run the CLI, turning project errors into one line and a non-zero exit."""
    keep_freed_memory()  # per-frame stages reuse resident pages (see care.malloc)
    use_threads(Work.DEFAULT)  # thread pools sized by kind of work (see care.threads)
    _register()
    try:
        app()
    except CareError as err:
        typer.echo(f"error: {err}", err=True)
        sys.exit(1)


if __name__ == "__main__":
    main()
