"""Option values converted without pydantic, for the values whose conversion is plain.

typer 0.29 converts every parameter's value, even an option left out (``None``), through a
pydantic ``TypeAdapter`` it builds on first use: a command pays pydantic's import (some
0.05 s) and an adapter per option at every start, though nearly every value it sees is an
option left out, a default of the option's own type, a number, a name or a path.
:func:`plain_values` converts those here, to the very values typer's conversion gives
(``tests/care_cli/test_values.py`` checks every parameter of every command against it),
and hands anything else (a bound not met, an unknown choice, an unreadable path, a number
written another way) to typer's own conversion, whose error the user then sees as before.
"""

from __future__ import annotations

import enum
import os
import re
import typing
from pathlib import Path
from typing import Any

__all__ = ["plain_values"]

_TYPERS = object()
"""A value :func:`_plain` leaves to typer's own conversion."""
_INT = re.compile(r"-?(0|[1-9][0-9]{0,17})")
_FLOAT = re.compile(r"-?(0|[1-9][0-9]{0,17})(\.[0-9]{1,17})?([eE][-+]?[0-9]{1,3})?")
_PLAIN_PATH = {
    "path_type": None,
    "exists": False,
    "file_okay": True,
    "dir_okay": True,
    "writable": False,
    "resolve_path": False,
    "allow_dash": False,
}
"""The path settings under which typer's path is ``Path(text)`` (no check but readable)."""


def plain_values(command: Any) -> None:
    """Convert the plain values of every parameter of ``command`` and of its subcommands
    here, and the others as typer does. Wraps each parameter's ``process_value`` (as
    :func:`care_maps.cli.options.finite_numbers` does, which wraps this in turn)."""
    for param in command.params:
        _wrap(param)
    make_help = command.get_help_option

    def get_help_option(ctx: Any) -> Any:  # --help: an option click makes when parsing
        option = make_help(ctx)
        if option is not None:
            _wrap(option)
        return option

    command.get_help_option = get_help_option
    for sub in getattr(command, "commands", {}).values():
        plain_values(sub)


def _wrap(param: Any) -> None:
    if not hasattr(param, "type_descriptor") or getattr(param, "_care_plain", False):
        return  # not typer's parameter (click's own), or wrapped already
    param._care_plain = True
    typers = param.process_value

    def process_value(ctx: Any, value: Any) -> Any:
        if param.required and value in (None, (), []):
            return typers(ctx, value)  # typer's own "missing" error
        converted = _convert(param, ctx, value)
        if converted is _TYPERS:
            return typers(ctx, value)
        if param.callback is not None:
            converted = param.callback(ctx, param, converted)
        return converted

    param.process_value = process_value


def _convert(param: Any, ctx: Any, value: Any) -> Any:
    """What typer's conversion of ``value`` gives, or :data:`_TYPERS`."""
    descriptor = param.type_descriptor
    annotation, info = descriptor.annotation, descriptor.parameter_info
    if value is None:  # left out: typer converts it to nothing
        return () if param.multiple or param.nargs == -1 else None
    if info.parser is not None:
        return _TYPERS
    if typing.get_origin(annotation) is list:
        if not isinstance(value, list | tuple):
            return _TYPERS
        (item,) = typing.get_args(annotation)
        items = [_plain(item, info, ctx, v) for v in value]
        return _TYPERS if any(v is _TYPERS for v in items) else items
    if param.multiple or param.nargs != 1:
        return _TYPERS
    return _plain(annotation, info, ctx, value)


def _plain(annotation: Any, info: Any, ctx: Any, value: Any) -> Any:
    """One value of type ``annotation`` as typer converts it, or :data:`_TYPERS`."""
    if annotation is str:
        return value if isinstance(value, str) else _TYPERS
    if annotation is bool:
        return value if type(value) is bool else _TYPERS
    if annotation is int or annotation is float:
        return _number(annotation, info, value)
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return _choice(annotation, info, ctx, value)
    if annotation is Path and all(getattr(info, k) == v for k, v in _PLAIN_PATH.items()):
        return _path(info, value)
    return _TYPERS


def _number(kind: type, info: Any, value: Any) -> Any:
    if type(value) is str and (_INT if kind is int else _FLOAT).fullmatch(value):
        value = kind(value)
    if type(value) is not kind or info.clamp:
        return _TYPERS
    if (info.min is not None and not value >= info.min) or (
        info.max is not None and not value <= info.max
    ):
        return _TYPERS  # typer's bound error
    return value


def _choice(kind: type[enum.Enum], info: Any, ctx: Any, value: Any) -> Any:
    if isinstance(value, kind):
        return value
    if type(value) is not str or getattr(ctx, "token_normalize_func", None) is not None:
        return _TYPERS
    fold = (lambda s: s) if info.case_sensitive else str.casefold
    wanted = fold(value)
    return next((m for m in kind if fold(str(m.value)) == wanted), _TYPERS)


def _path(info: Any, value: Any) -> Any:
    if type(value) is str and value:
        value = Path(value)
    if not isinstance(value, Path):
        return _TYPERS
    try:
        value.stat()
    except OSError:  # missing, or a name too long to look up: typer's own test
        return value
    if info.readable and not os.access(value, os.R_OK):
        return _TYPERS  # typer's "not readable" error
    return value
