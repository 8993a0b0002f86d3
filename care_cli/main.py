"""Entry point of the ``care`` program.

Each stage's commands live in their own module here and register themselves on ``app``.
No traceback reaches a user: every expected fault (:func:`one_line`) becomes one line on
stderr and exit code 1; an unexpected exception prints one line and the path of a file
holding its full traceback (``--debug`` anywhere on the command line shows it instead).
"""

from __future__ import annotations

import datetime
import errno
import json
import os
import sys
import tempfile
import traceback
from pathlib import Path

import typer

from care.errors import CareError
from care.malloc import keep_freed_memory
from care.threads import Work, use_threads

__all__ = ["app", "main", "one_line"]

app = typer.Typer(
    name="care",
    help="CARe maps: recordings in, open-vocabulary maps, queries and context-aware replanning "
    "out. Add --debug to any command to see the full traceback of an unexpected error.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


_INTERRUPTED = 130
"""Exit code of a run stopped by Ctrl-C (128 + SIGINT), as shells report it."""


def _register() -> None:
    from care_cli import check_cmd, eval_cmd, fuse_cmd, ingest_cmd, sample_cmd

    for module in (ingest_cmd, sample_cmd, fuse_cmd, eval_cmd, check_cmd):
        module.register(app)


def _first_line(text: str) -> str:
    return text.strip().splitlines()[0] if text.strip() else ""


def one_line(err: BaseException) -> str | None:
    """The one line an expected fault gets (None: not an expected fault)."""
    if isinstance(err, CareError):
        return _first_line(str(err)) if "\n" in str(err) else str(err)
    if isinstance(err, PermissionError):
        return (
            f"permission denied: {err.filename or err}; fix the permissions of that path "
            "or choose another one"
        )
    if isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        from care.outputs import disk_full

        return str(disk_full(Path(err.filename or "."), 0, err))
    if isinstance(err, OSError) and err.errno == errno.EROFS:
        return f"{err.filename}: read-only file system; choose a writable output path"
    if isinstance(err, MemoryError):
        return (
            "out of memory; use a coarser setting (e.g. a larger --cell-size or --stride) or "
            "a machine with more memory"
        )
    if isinstance(err, json.JSONDecodeError):
        return f"invalid JSON at line {err.lineno} column {err.colno}: {err.msg}; fix the file"
    try:
        import yaml

        if isinstance(err, yaml.YAMLError):
            return f"invalid YAML: {_first_line(str(err))}; fix the file"
    except ImportError:  # pragma: no cover - yaml comes with rosbags
        pass
    import pyarrow as pa

    if isinstance(err, pa.ArrowException):
        return (
            f"a table could not be read ({_first_line(str(err))}); run `care check STORE` "
            "to find it, then the command it names rebuilds it"
        )
    return None


def _write_traceback(err: BaseException) -> Path:
    """Write ``err``'s full traceback to a file and return its path."""
    folder = Path(os.environ.get("CARE_TRACEBACK_DIR") or tempfile.gettempdir())
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%S")
    fd, name = tempfile.mkstemp(prefix=f"care-traceback-{stamp}-", suffix=".txt", dir=folder)
    with os.fdopen(fd, "w") as f:
        f.write(" ".join(sys.argv) + "\n\n")
        f.write("".join(traceback.format_exception(err)))
    return Path(name)


def main() -> None:
    """Run the CLI, turning every fault into one line and a non-zero exit."""
    debug = "--debug" in sys.argv[1:] or os.environ.get("CARE_DEBUG") == "1"
    sys.argv = [a for a in sys.argv if a != "--debug"]
    keep_freed_memory()  # per-frame stages reuse resident pages (see care.malloc)
    use_threads(Work.DEFAULT)  # thread pools sized by kind of work (see care.threads)
    try:  # typer vendors click
        from typer._click import exceptions as click_errors
    except ImportError:  # pragma: no cover - older typer
        from click import exceptions as click_errors

    try:
        _register()
        code = app(standalone_mode=False)
        if code == _INTERRUPTED:  # typer turns Ctrl-C into exit code 130, silently
            raise KeyboardInterrupt
        sys.exit(code if isinstance(code, int) else 0)
    except click_errors.ClickException as err:  # usage: a bad option value, a missing argument
        if not err.format_message().strip():  # no arguments: the help was shown
            sys.exit(err.exit_code)
        ctx = getattr(err, "ctx", None)
        command = ctx.command_path if ctx is not None else "care"
        typer.echo(f"error: {_first_line(err.format_message())} (see `{command} --help`)", err=True)
        sys.exit(err.exit_code)
    except (KeyboardInterrupt, typer.Abort):
        typer.echo("error: interrupted; nothing half-written was left behind", err=True)
        sys.exit(_INTERRUPTED)
    except Exception as err:
        if debug:
            raise
        line = one_line(err)
        if line is None:
            try:
                where = f"full traceback in {_write_traceback(err)}"
            except OSError:
                where = "no traceback file could be written"
            line = (
                f"internal error {type(err).__name__}: {_first_line(str(err))[:200]}; "
                f"{where} (re-run with --debug to see it); please report it"
            )
        typer.echo(f"error: {line}", err=True)
        sys.exit(1)


if __name__ == "__main__":
    main()
