"""Option values converted without pydantic (:mod:`care_maps.cli.values`) are typer's own:
every parameter of every command, fed the values a command line gives it (left out, its
default, well- and ill-formed numbers, names, paths), converts to the same value of the
same type, or fails with the same error, as through typer's conversion; and a query run
imports no pydantic."""

from __future__ import annotations

import enum
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import typer

from care_maps.cli import main as cli
from care_maps.cli.values import plain_values
from tests.support.cli import after_care

_TEXT = ("abc", "", "Chair", " 7")
_INTS = ("0", "7", "-3", "-0", "007", "+4", "1_000", "1.5", "2.0", " 7", "x", "9" * 25)
_FLOATS = ("0.5", "2", "1e-3", "-1.25", "-0", "nan", "inf", "-inf", ".5", "1.", "1_0", "x")
_PATHS = ("/tmp", "/nonexistent/x", "", "-", "relative/dir", "/etc/shadow", "/tmp/" + "n" * 300)


def _samples(annotation: Any, default: Any) -> list[Any]:
    out: list[Any] = [None, default]
    if typing.get_origin(annotation) is list:
        (item,) = typing.get_args(annotation)
        return [*out, (), *((v, v) for v in _samples(item, None)[2:])]
    if annotation is str:
        out += _TEXT
    elif annotation is bool:
        out += [True, False]
    elif annotation is int:
        out += [*_INTS, 5, 0, -1, 2.5]
    elif annotation is float:
        out += [*_FLOATS, 0.25, 3, float("nan")]
    elif annotation is Path:
        out += [*_PATHS, Path("/tmp")]
    elif isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        out += [*annotation, *(str(m.value) for m in annotation)]
        out += [str(m.value).upper() for m in annotation] + ["nope"]
    return out


def _pairs(ours: Any, theirs: Any, ctx: Any) -> Iterator[tuple[Any, Any, Any]]:
    """Each parameter of both command trees, with a context of its command."""
    here = typer.Context(theirs, parent=ctx, info_name=theirs.name)
    for mine, typers in zip(ours.params, theirs.params, strict=True):
        yield mine, typers, here
    yield ours.get_help_option(here), theirs.get_help_option(here), here
    for name, sub in getattr(theirs, "commands", {}).items():
        yield from _pairs(ours.commands[name], sub, here)


def _outcome(param: Any, ctx: Any, value: Any) -> tuple[str, Any]:
    try:
        got = param.process_value(ctx, value)
    except Exception as err:
        return "error", (type(err).__name__, str(err))
    return type(got).__name__, got


def test_plain_values_are_typers() -> None:
    cli._register()
    ours = typer.main.get_command(cli.app)
    plain_values(ours)
    theirs = typer.main.get_command(cli.app)
    checked = 0
    for mine, typers, ctx in _pairs(ours, theirs, None):
        if mine is None:
            continue
        annotation = typers.type_descriptor.annotation
        for value in _samples(annotation, typers.default):
            a, b = _outcome(mine, ctx, value), _outcome(typers, ctx, value)
            assert repr(a) == repr(b), (mine.name, value)  # repr: NaN is NaN
            checked += 1
    assert checked > 2000


@pytest.mark.parametrize("argv", [["query", "STORE", "chair", "--map", "grid"], ["--help"]])
def test_a_run_imports_no_pydantic(argv: list[str], tmp_path: Path) -> None:
    assert after_care(argv, "'pydantic' in sys.modules", cwd=tmp_path) == "False"
