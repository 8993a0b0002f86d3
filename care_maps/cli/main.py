"""Entry point of the ``care`` program.

Each stage's commands live in their own module here and register themselves on ``app``.
No traceback reaches a user: every expected fault (:func:`one_line`) becomes one line on
stderr and exit code 1; an unexpected exception prints one line and the path of a file
holding its full traceback (``--debug`` anywhere on the command line shows it instead).
"""

from __future__ import annotations

import _thread
import atexit
import contextlib
import datetime
import errno
import inspect
import json
import os
import signal
import sys
import tempfile
import threading
import traceback
import types
from pathlib import Path
from typing import Any

import typer

from care_maps.cli import INTERRUPTED as _INTERRUPTED
from care_maps.cli import stop_while_loading
from care_maps.cli.options import finite_numbers
from care_maps.cli.values import plain_values
from care_maps.core.errors import CareError
from care_maps.core.notices import print_notices
from care_maps.runtime.malloc import keep_freed_memory
from care_maps.runtime.signals import (
    STOPS,
    WORKER_GRACE_S,
    exit_code,
    release_semaphores,
    stop_line,
)
from care_maps.runtime.threads import Work, use_threads

_GRACE_S = 0.8
"""How long an interruption (Ctrl-C, SIGTERM, SIGHUP: :data:`care_maps.runtime.signals.STOPS`) may
take to unwind (staged outputs removed on the way, workers stopped) before the process
leaves anyway: a long call in compiled code does not see the KeyboardInterrupt until it
returns. What such an exit leaves is a temporary named for a dead process, which the next
run in that place sweeps."""


_SAID = threading.Event()
"""Set once the interruption's line is on stderr (it is said once, whoever says it)."""
_stopped_by: int | None = None
"""The signal that interrupted this run (the first one), which sets its line and exit code."""
_PROGRAM = (__name__ == "__main__" or sys.argv[0].rsplit("/", 1)[-1] == "care") and (
    "multiprocessing" not in sys.modules or sys.modules["multiprocessing"].parent_process() is None
)
"""Whether this process is the ``care`` program: not a caller of :func:`main` (a test), nor
one of its worker processes (which leave the interruption to the program). A spawned
worker has imported multiprocessing before this module; the program need not (0.004 s)."""
_PID = os.getpid()
"""The program's process (a forked worker inherits the handlers, not the role)."""
_watchdog: threading.Timer | None = None


def _signum() -> int:
    """The signal this run was interrupted by (a KeyboardInterrupt of unknown origin is
    Ctrl-C's)."""
    return signal.SIGINT if _stopped_by is None else _stopped_by


def _say(*, raw: bool = False) -> None:
    """Print the interruption's line, once; a closed terminal (SIGHUP) may refuse it.
    ``raw``: straight to file descriptor 2, from another thread than the main one (which may
    hold ``sys.stderr``'s lock)."""
    if _SAID.is_set():
        return
    _SAID.set()
    with contextlib.suppress(OSError, ValueError):
        if raw:
            os.write(2, stop_line(_signum()))
        else:
            typer.echo(stop_line(_signum()).decode().rstrip(), err=True)


def _stop_workers(grace: float | None) -> None:
    """:func:`care_maps.runtime.parallel.stop_workers`, if that module is loaded (without it no worker
    was started; importing it from a signal handler could find it half-imported)."""
    parallel = sys.modules.get("care_maps.runtime.parallel")
    stop = getattr(parallel, "stop_workers", None)
    if stop is not None:
        with contextlib.suppress(Exception):
            stop(grace=grace)


def _stop_now(signum: int, frame: object) -> None:
    """Leave at once with exit code 128 + N: the end of the grace after an interruption, or
    an interruption while the program exits. The workers are killed first: left alone they
    would run their tasks to the end."""
    global _stopped_by
    if os.getpid() != _PID:  # a forked worker: the program says it
        os._exit(exit_code(signum))
    if _stopped_by is None:
        _stopped_by = signum
    _stop_workers(0.0)
    release_semaphores()  # after any release under way in another thread has ended
    _say(raw=True)
    os._exit(exit_code(_signum()))


__all__ = ["app", "build_command", "main", "one_line"]


def _program() -> typer.Typer:
    """The ``care`` group, no command registered yet."""
    program = typer.Typer(
        name="care",
        help="CARe maps: recordings in, open-vocabulary maps, queries and context-aware "
        "replanning out. Add --debug to any command to see the full traceback of an "
        "unexpected error.",
        no_args_is_help=True,
        pretty_exceptions_enable=False,
        add_completion=False,
        rich_markup_mode=None,
    )
    program.callback()(_group)
    return program


def _group() -> None:
    # a callback keeps `care` a group of commands when a run registers one command alone
    # (typer runs a lone command as the program itself, without its name)
    pass


app = _program()


COMMAND_MODULES: dict[str, str] = {
    "ingest": "ingest_cmd",
    "topics": "ingest_cmd",
    "sample": "sample_cmd",
    "fuse": "fuse_cmd",
    "query": "query_cmd",
    "replan": "query_cmd",
    "eval": "eval_cmd",
    "run": "run_cmd",
    "explore": "explore_cmd",
    "frame": "frame_cmd",
    "check": "check_cmd",
}
"""Which module of :mod:`care_maps.cli` registers each command, in ``care --help``'s order:
a run of one command imports that module alone (the others' stages cost start-up it does
not need). ``tests/care_cli/test_registration.py`` checks it against what each module
registers."""
_registered: set[str] = set()


def _register(command: str | None = None) -> None:
    """Register the module of ``command`` on :data:`app`, or every module (``None`` or a name
    no module registers: ``--help`` and the usage error list them all). Registering twice
    is a no-op."""
    import importlib

    wanted = COMMAND_MODULES.get(command or "")
    for name in dict.fromkeys(COMMAND_MODULES.values()):
        if name in _registered or (wanted is not None and name != wanted):
            continue
        importlib.import_module(f"care_maps.cli.{name}").register(app)
        _registered.add(name)
    _plain_help(app)


def _listing() -> typer.Typer | None:
    """The ``care`` group as ``care --help`` (or a usage error naming no command) lists it:
    each command's help read from its module's source, no command module imported (their
    stages' configs cost 0.2 s of imports, for a list of names). The source is read, not
    copied: ``register`` adds each command as ``app.command("name")(function)`` (the
    function's docstring is its help) or a group as ``app.add_typer(group, name="name")``
    (``group = typer.Typer(help=...)``). None where a module registers otherwise: every
    module is then imported. ``tests/care_cli/test_registration.py`` checks the list is
    the one the registered commands give."""
    import ast
    import importlib.util

    commands: list[tuple[str, str]] = []
    groups: list[tuple[str, str]] = []
    for module in dict.fromkeys(COMMAND_MODULES.values()):
        spec = importlib.util.find_spec(f"care_maps.cli.{module}")
        if spec is None or spec.origin is None:
            return None
        found = _registered_in(ast.parse(Path(spec.origin).read_text("utf-8")))
        if found is None:
            return None
        commands += found[0]
        groups += found[1]
    listing = _program()
    for name, help_ in commands:
        listing.command(name, help=help_)(_group)
    for name, help_ in groups:
        listing.add_typer(typer.Typer(help=help_, rich_markup_mode=None), name=name)
    _plain_help(listing)
    return listing


def _registered_in(tree: Any) -> tuple[list[tuple[str, str]], list[tuple[str, str]]] | None:
    """(commands, groups), each (name, help), that a command module's ``register`` adds,
    read from the module's syntax tree; None for any other form of registration."""
    import ast

    functions = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
    assigned = {
        n.targets[0].id: n.value
        for n in tree.body
        if isinstance(n, ast.Assign) and len(n.targets) == 1 and isinstance(n.targets[0], ast.Name)
    }

    def text(node: ast.AST | None) -> str | None:
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            return node.value
        return None

    def keyword(call: ast.AST | None, name: str) -> str | None:
        if not isinstance(call, ast.Call):
            return None
        return next((text(k.value) for k in call.keywords if k.arg == name), None)

    commands, groups = [], []
    for stmt in functions["register"].body if "register" in functions else [None]:
        if isinstance(stmt, ast.Expr) and text(stmt.value) is not None:
            continue  # its docstring
        call = stmt.value if isinstance(stmt, ast.Expr) else None
        if not isinstance(call, ast.Call) or len(call.args) != 1:
            return None
        (arg,) = call.args
        made = call.func
        if (
            isinstance(made, ast.Call)
            and ast.unparse(made.func) == "app.command"
            and len(made.args) == 1
            and text(made.args[0]) is not None
            and isinstance(arg, ast.Name)
            and arg.id in functions
        ):
            commands.append((text(made.args[0]) or "", ast.get_docstring(functions[arg.id]) or ""))
            continue
        name = keyword(call, "name")
        help_ = keyword(assigned.get(arg.id), "help") if isinstance(arg, ast.Name) else None
        if ast.unparse(made) != "app.add_typer" or name is None or help_ is None:
            return None
        groups.append((name, help_))
    return commands, groups


def _command(argv: list[str]) -> str | None:
    """The command named on a command line (its first word that is not an option)."""
    return next((arg for arg in argv if not arg.startswith("-")), None)


def _plain_help(typer_app: typer.Typer) -> None:
    """Each command's help from its docstring without the markup written for the code's
    reader (``--help`` shows text, not reStructuredText)."""
    from care_maps.cli.options import plain

    for command in typer_app.registered_commands:
        doc = command.help or inspect.getdoc(command.callback) or ""
        command.help = plain(doc)
    for group in typer_app.registered_groups:
        if group.typer_instance is not None:
            _plain_help(group.typer_instance)


def build_command(program: typer.Typer | None = None) -> Any:
    """The click command of ``program`` (default :data:`app`, the commands registered so
    far) as a run parses it: plain values converted without pydantic
    (:mod:`care_maps.cli.values`), and NaN and infinities refused for every option."""
    command = typer.main.get_command(program or app)
    plain_values(command)
    finite_numbers(command)
    return command


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
        from care_maps.core.outputs import disk_full

        return str(disk_full(Path(err.filename or "."), 0, err))
    if isinstance(err, OSError) and err.errno == errno.ENAMETOOLONG:
        name = str(err.filename)
        name = name if len(name) <= 120 else f"{name[:60]}...{name[-50:]}"
        return f"{name}: file name or path too long for this system; choose a shorter one"
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


def _interrupt(signum: int, frame: object) -> None:
    """Ctrl-C, SIGTERM or SIGHUP while a command runs: tell the workers to stop, unwind with
    KeyboardInterrupt (every staged output is removed on the way), and leave within
    :data:`_GRACE_S` of the first signal whatever happens."""
    global _watchdog, _stopped_by
    if os.getpid() != _PID:  # a forked worker: its task ends, the program decides
        raise KeyboardInterrupt
    if _stopped_by is None:
        _stopped_by = signum
    _stop_workers(None)  # signals only: the pools' own locks may be held right now
    if _watchdog is None:
        _watchdog = threading.Timer(_GRACE_S, _stop_now, args=(signum, None))
        _watchdog.daemon = True
        _watchdog.start()
    raise KeyboardInterrupt


def _raise_again(unraisable: Any) -> None:
    """``sys.unraisablehook`` of the program: a KeyboardInterrupt that Python had to drop (it
    came while a weakref callback or a ``__del__`` ran, say, during an import) is raised
    again in the main thread instead of printed as "Exception ignored". Once the run is
    interrupted, any other one is dropped: it comes from the finaliser of an object the
    interruption left half-built (a progress bar stopped inside its constructor has no
    position to clear), and the run's one line says what happened. Anything else is
    reported as Python reports it."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        _thread.interrupt_main(signal.SIGINT)
        return
    if _stopped_by is not None:
        return
    sys.__unraisablehook__(unraisable)


def _handlers_before() -> dict[int, Any]:
    """The handler of each interrupting signal before this run (ours of an earlier run in
    this process, or the loading one, count as the default)."""
    before: dict[int, Any] = {}
    for signum in STOPS:
        handler = signal.getsignal(signum)
        if handler in (_stop_now, stop_while_loading, _interrupt):
            handler = signal.default_int_handler if signum == signal.SIGINT else signal.SIG_DFL
        before[signum] = handler
    return before


def _answered(before: dict[int, Any]) -> list[int]:
    """The interrupting signals this run answers: those not ignored when it started (a job
    started with one ignored, by ``nohup`` or ``cmd &`` in a script, keeps ignoring it)."""
    return [signum for signum, handler in before.items() if handler is not signal.SIG_IGN]


def main() -> None:
    """Run the CLI, turning every fault into one line and a non-zero exit."""
    if threading.current_thread() is not threading.main_thread():
        _main()
        return
    global _watchdog, _stopped_by
    _SAID.clear()
    _watchdog, _stopped_by = None, None  # no interruption yet in this run
    before = _handlers_before()
    for signum in _answered(before):
        signal.signal(signum, _interrupt)
    if _PROGRAM and signal.SIGINT in _answered(before):
        sys.unraisablehook = _raise_again
    try:
        _main()
    except SystemExit as done:
        if not _PROGRAM:
            raise
        _leave(done.code, _answered(before))
    finally:
        for signum in _answered(before):
            signal.signal(signum, before[signum])
        if _watchdog is not None:
            _watchdog.cancel()


def _exit_interrupted() -> None:
    """Exit code 128 + N once the outputs are unwound and the workers have ended (they
    unwind their own tasks meanwhile; one that takes longer is killed)."""
    _stop_workers(WORKER_GRACE_S)
    if _PROGRAM:  # the outputs are unwound; an interpreter whose KeyboardInterrupt went
        # through an exec() of text (numpy's and scipy's imports do) would end by the
        # signal instead of exit code 128 + N (CPython's unhandled-interrupt flag)
        with contextlib.suppress(OSError, ValueError):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(exit_code(_signum()))
    sys.exit(exit_code(_signum()))


def _leave(code: object, answered: list[int]) -> None:
    """End the program with ``code`` here, with the interrupting signals still answered,
    instead of in the interpreter's teardown: that resets the signal handlers before it
    frees the modules (torch's take a while), and a signal then would end the process by
    it, without its line. The exit functions (a local Ray's shutdown, the pools' joins) run
    first."""
    for signum in answered:
        signal.signal(signum, _stop_now)
    atexit._run_exitfuncs()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code if isinstance(code, int) else 0 if code is None else 1)


def _main() -> None:
    debug = "--debug" in sys.argv[1:] or os.environ.get("CARE_DEBUG") == "1"
    sys.argv = [a for a in sys.argv if a != "--debug"]
    click_errors: types.ModuleType  # one of two modules of the same exceptions
    try:  # typer vendors click
        from typer._click import exceptions as click_errors
    except ImportError:  # pragma: no cover - older typer
        from click import exceptions as click_errors

    try:
        print_notices()  # what a stage says as it goes on: one line each on stderr
        keep_freed_memory()  # per-frame stages reuse resident pages (see care_maps.runtime.malloc)
        use_threads(
            Work.DEFAULT
        )  # thread pools sized by kind of work (see care_maps.runtime.threads)
        named = _command(sys.argv[1:])
        listing = None if named in COMMAND_MODULES else _listing()
        if listing is None:
            _register(named)
        code = build_command(listing or app)(standalone_mode=False)
        if code == _INTERRUPTED:  # typer turns Ctrl-C into exit code 130, silently
            raise KeyboardInterrupt
        sys.exit(code if isinstance(code, int) else 0)
    except click_errors.NoArgsIsHelpError as err:  # `care`, `care fuse`: the help, exit 2
        typer.echo(err.format_message())
        sys.exit(err.exit_code)
    except click_errors.ClickException as err:  # usage: a bad option value, a missing argument
        if not err.format_message().strip():  # no arguments: the help was shown
            sys.exit(err.exit_code)
        ctx = getattr(err, "ctx", None)
        path = ctx.command_path if ctx is not None else "care"
        typer.echo(f"error: {_first_line(err.format_message())} (see `{path} --help`)", err=True)
        sys.exit(err.exit_code)
    except (KeyboardInterrupt, typer.Abort):
        _say()
        _exit_interrupted()
    except Exception as err:
        if _watchdog is not None and os.getpid() == _PID:
            # after an interruption, whatever failed next failed because of it (an import
            # cut half-way fails again when retried): it is the interruption that is reported
            _say()
            _exit_interrupted()
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
