"""CLI options generated from the stages' frozen config dataclasses.

Why typer driven by the dataclass fields and not ``tyro``: typer 0.29 is already the CLI
(its one-line errors, lazy stage imports and the fault suite rest on it), tyro is not
installed here and no package can be downloaded at run time, and a generator of some
eighty lines gives each option exactly its field's default and its field's docstring as
help (:func:`care_maps.core.config.field_docs`). Nothing is typed twice: a command names the config
class and, where the CLI differs, how (an option name, a parser, a bound).

:func:`config_options` replaces one parameter of a command by one option per field and
hands the command an :class:`Options`: the values given on the command line, which win
over a map's recorded settings, which win over the config's defaults
(:meth:`Options.config`).

Every refusal of an option's text names that option as the user typed it (``--from``, not
the field ``start``): a parser raises ``ValueError`` with what is wrong, and :func:`parsed`
hands it to click, which names the option it was reading.
One parser per kind of value (:func:`point_xy`, :func:`care_maps.core.frames.check_frame_id` for every
field of :data:`care_maps.core.frames.FRAME_ID_FIELDS`), reused by every option of that kind.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import inspect
import math
import re
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Annotated, Any, TypeGuard, TypeVar, Union

import typer

from care_maps.core.config import field_docs, recorded_fields
from care_maps.core.errors import CareError
from care_maps.core.frames import FRAME_ID_FIELDS, check_frame_id

__all__ = [
    "GeneratedOption",
    "Options",
    "config_options",
    "csv_choices",
    "finite_numbers",
    "generated_options",
    "parsed",
    "plain",
    "point_xy",
    "with_choices",
]

C = TypeVar("C")

_CTX = "care_options_context"
"""Name of the click context parameter a generated command gets (to tell given options)."""


@dataclass(frozen=True)
class GeneratedOption:
    """One option made from a config field (what the tests compare with the config)."""

    param: str
    """The click parameter's name."""
    cls: type
    field: str
    parsed: bool
    """Read as text by a parser (its click default is None; the help shows the field's)."""
    choices: tuple[str, ...] = ()
    """The enum values it accepts (empty: not an enum option)."""


@dataclass(frozen=True)
class Options(typing.Generic[C]):
    """The options of one config class as a command received them."""

    cls: type[C]
    values: Mapping[str, Any]
    """Field -> value of every generated option (the config's default where not given)."""
    given: frozenset[str] = field(default_factory=frozenset)
    """Fields set on the command line."""

    def config(self, recorded: bytes | str | Mapping[str, Any] | None = None, **fixed: Any) -> C:
        """The config: ``fixed`` values, then the options given, then ``recorded`` values (a
        map's settings JSON), then the config's defaults."""
        if isinstance(recorded, Mapping):
            kept = dict(recorded)
        else:
            kept = recorded_fields(self.cls, recorded)
        given = {k: v for k, v in self.values.items() if k in self.given}
        return self.cls(**{**kept, **given, **fixed})


def _optional(tp: Any) -> Any:
    """``X`` of ``X | None`` (``tp`` itself otherwise)."""
    if typing.get_origin(tp) in (Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def _is_enum(tp: Any) -> TypeGuard[type[enum.Enum]]:
    return isinstance(tp, type) and issubclass(tp, enum.Enum)


def _text(value: Any) -> str:
    """How a default reads in ``--help`` (and is typed on the command line)."""
    if isinstance(value, tuple | list):
        return ",".join(_text(v) for v in value)
    return str(value.value if isinstance(value, enum.Enum) else value)


_CODE_REFERENCE = re.compile(r"\s*\((?::\w+:`[^`]+`[,;\s]*)+\)")
"""A parenthesis of code references only (``(:func:`a.b`)``): for the code's reader."""
_ROLE = re.compile(r":\w+:`~?(?:[\w.]+\.)?([^`.]+)`")


def plain(text: str) -> str:
    """A docstring as ``--help`` shows it: no reStructuredText markup. A parenthesis that only
    points into the code goes; another code reference keeps its last name; double back-quotes
    become plain text."""
    text = _CODE_REFERENCE.sub("", text)
    return _ROLE.sub(r"\1", text).replace("``", "")


def with_choices(help_: str, kind: type[enum.Enum], *, many: bool = False) -> str:
    """``help_`` followed by the enum's values (every enum option's help lists them)."""
    values = ", ".join(str(m.value) for m in kind)
    return f"{help_} Choices: {values}{' (comma-separated)' if many else ''}."


def csv_choices(item: type, name: str) -> Callable[[str | None], tuple[Any, ...] | None]:
    """A parser of comma-separated values of type ``item`` (an enum: only its values; a bad
    one is a usage error, exit 2, that lists them)."""

    def parse(value: str | None) -> tuple[Any, ...] | None:
        if value is None:
            return None
        parts = [v.strip() for v in value.split(",") if v.strip()]
        try:
            return tuple(item(v) for v in parts)
        except ValueError as err:
            allowed = f"; choose from {', '.join(_text(m) for m in item)}" if _is_enum(item) else ""
            msg = f"{value!r}: expected comma-separated {item.__name__} values{allowed}"
            raise typer.BadParameter(msg, param_hint=name) from err

    return parse


def _from_text(kind: type) -> Callable[[str], Any]:
    """The parser of a field whose type reads itself from the option's text (a classmethod
    ``from_text``, e.g. :class:`care_maps.ingest.intrinsics.CameraIntrinsics`); text it refuses is a
    usage error (exit 2) naming the option."""

    def parse(value: str) -> Any:
        try:
            return kind.from_text(value)  # type: ignore[attr-defined]
        except CareError as err:
            raise typer.BadParameter(str(err)) from err

    return parse


def point_xy(value: str) -> tuple[float, float]:
    """``x,y``: a map position in metres (``--from``, a ``--visited`` place).

    Checked here, while the command line is read, so the message names the option; a
    config's own check (:class:`care_maps.query.paths.PathConfig`) could only name its field."""
    parts = [p.strip() for p in value.split(",")]
    try:
        x, y = (float(p) for p in parts)
    except ValueError as err:
        msg = f"{value!r}: give a map position x,y (1.5,-2.0), two numbers in metres"
        raise ValueError(msg) from err
    if not (math.isfinite(x) and math.isfinite(y)):
        msg = f"{value!r}: a map position x,y must be two finite numbers of metres"
        raise ValueError(msg)
    return x, y


def parsed(parse: Callable[[str], Any]) -> Callable[[Any], Any]:
    """A typer ``callback`` that runs ``parse`` on an option's text (None: not given).

    What ``parse`` refuses with ``ValueError`` (or ``typer.BadParameter``) becomes a usage
    error, exit 2, in one line that click starts with the name of the option being read
    (``Invalid value for '--from': ...``): the name the user typed, whatever the field is
    called, and the same words for every option of a kind. A parser's own
    :class:`care_maps.core.errors.CareError` passes through (its message names the option itself)."""

    def convert(value: Any) -> Any:
        if value is None:
            return None
        try:
            return parse(value)
        except typer.BadParameter:
            raise
        except ValueError as err:
            raise typer.BadParameter(str(err)) from err

    return convert


def _option(
    cls: type, f: dataclasses.Field, hint: Any, name: str, parse: Callable | None, extra: dict
) -> tuple[Any, Any, GeneratedOption]:
    """``(annotation, default, record)`` of the option for field ``f``."""
    help_ = plain(field_docs(cls)[f.name] or f.name.replace("_", " "))
    decls = tuple(extra.pop("flags", ()))
    flag = decls[0].split("/")[0] if decls else "--" + name.replace("_", "-")
    inner = _optional(hint)
    if "type" in extra:  # a str field whose values an enum lists
        inner, hint = extra["type"], extra["type"] | None if inner is not hint else extra["type"]
        del extra["type"]
    item = typing.get_args(inner)[0] if typing.get_origin(inner) is tuple else None
    if parse is None and item is not None:
        parse = csv_choices(item, flag)
    if parse is None and callable(getattr(inner, "from_text", None)):
        parse = _from_text(inner)
    if parse is None and f.name in FRAME_ID_FIELDS and inner is str:
        parse = check_frame_id
    enum_type = item if _is_enum(item) else inner if _is_enum(inner) else None
    choices = tuple(str(m.value) for m in enum_type) if enum_type else ()
    # in the help text too: a narrow terminal cuts the metavar, not the help
    if choices and enum_type:
        help_ = with_choices(help_, enum_type, many=item is not None)
    if parse is not None:  # read as text, converted by the parser, None: not given
        shown = "none" if f.default is None else _text(f.default)
        kwargs = {"help": help_, "callback": parsed(parse), "show_default": shown, **extra}
        info = typer.Option(*(decls or (flag,)), **kwargs)
        record = GeneratedOption(name, cls, f.name, parsed=True, choices=choices)
        return Annotated[str | None, info], None, record
    if inner is bool and not decls:  # a switch both ways: --x / --no-x
        decls = (f"{flag}/--no-{flag[2:]}",)
    info = typer.Option(*(decls or (flag,)), **{"help": help_, **extra})
    record = GeneratedOption(name, cls, f.name, parsed=False, choices=choices)
    default = ... if f.default is dataclasses.MISSING else f.default
    if enum_type is not None and default is not None and default is not ...:
        default = enum_type(default)
    return Annotated[hint, info], default, record


def config_options(
    param: str,
    cls: type,
    *,
    only: Iterable[str] | None = None,
    skip: Iterable[str] = (),
    names: Mapping[str, str] | None = None,
    parse: Mapping[str, Callable[[str], Any]] | None = None,
    extra: Mapping[str, Mapping[str, Any]] | None = None,
) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Replace the command's parameter ``param`` by one option per field of ``cls``.

    Args:
        param: the command's parameter that receives the :class:`Options`.
        cls: the frozen config dataclass (help: its field docstrings; defaults: its fields').
        only: the fields made options, in this order (default: every field but ``skip``).
        skip: fields left out.
        names: field -> option name where the CLI's differs (``unknown_classes`` ->
            ``gt_unknown_classes``).
        parse: field -> parser of the option's text (``tuple`` fields default to a
            comma-separated parser, enums checked).
        extra: field -> more ``typer.Option`` arguments (``min``, ``rich_help_panel``), and
            ``flags`` (its option names, e.g. ``("--out", "-o")``) or ``type`` (an enum
            whose values a ``str`` field takes).
    """
    hints = typing.get_type_hints(cls)
    by_name = {f.name: f for f in dataclasses.fields(cls)}
    skipped = set(skip)
    wanted = list(only) if only is not None else [n for n in by_name if n not in skipped]

    def decorate(fn: Callable[..., Any]) -> Callable[..., Any]:
        sig = inspect.signature(fn, eval_str=True)
        records: list[GeneratedOption] = list(getattr(fn, "__care_options__", ()))
        before = list(sig.parameters).index(param)  # the options stand where ``param`` stood
        params = [p for p in sig.parameters.values() if p.name != param]
        generated: list[inspect.Parameter] = []
        made: dict[str, str] = {}  # click parameter -> field
        for fname in wanted:
            opt = (names or {}).get(fname, fname)
            annotation, default, record = _option(
                cls, by_name[fname], hints[fname], opt, (parse or {}).get(fname),
                dict((extra or {}).get(fname, {})),
            )  # fmt: skip
            generated.append(inspect.Parameter(opt, inspect.Parameter.KEYWORD_ONLY,
                                               default=default, annotation=annotation))  # fmt: skip
            records.append(record)
            made[opt] = fname
        params[before:before] = generated
        if not any(p.name == _CTX for p in params):
            params.append(
                inspect.Parameter(_CTX, inspect.Parameter.KEYWORD_ONLY, annotation=typer.Context)
            )
        ordered = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in params]

        @functools.wraps(fn)
        def command(*args: Any, **kwargs: Any) -> Any:
            ctx: typer.Context = kwargs[_CTX]
            if _CTX not in sig.parameters:
                kwargs.pop(_CTX)
            values = {made[o]: kwargs.pop(o) for o in made}
            given = frozenset(made[o] for o in made if _given(ctx, o, values[made[o]]))
            values = {k: (by_name[k].default if v is None and k not in given else v)
                      for k, v in values.items()}  # fmt: skip
            kwargs[param] = Options(cls, values, given)
            return fn(*args, **kwargs)

        command.__signature__ = sig.replace(parameters=ordered)  # type: ignore[attr-defined]
        command.__annotations__ = {p.name: p.annotation for p in ordered}
        command.__care_options__ = tuple(records)  # type: ignore[attr-defined]
        return command

    return decorate


def _given(ctx: typer.Context, name: str, value: Any) -> bool:
    """Whether the user set the option (on the command line or in its environment variable).

    By the source's name: typer vendors its own click, whose ``ParameterSource`` is not
    ``click.core``'s."""
    source = ctx.get_parameter_source(name)
    return getattr(source, "name", "") in ("COMMANDLINE", "ENVIRONMENT") and value is not None


def generated_options(command: Callable[..., Any]) -> tuple[GeneratedOption, ...]:
    """The options :func:`config_options` made for a command (its callback, or typer's)."""
    return tuple(getattr(command, "__care_options__", ()))


def finite_numbers(command: Any) -> None:
    """Make every numeric option of ``command`` and of its subcommands refuse NaN and
    infinities as a usage error (exit 2), before the command runs.

    The one place this is checked for every command: a config's ``__post_init__`` checks
    ranges, but some options belong to no config, and a NaN passes comparisons in neither
    direction, so a check written as ``x > 0`` elsewhere would let it through to a file.
    Wraps each parameter's ``process_value`` (conversion and parser callbacks included), so
    parsed tuples of numbers are covered too.
    """
    for param in command.params:
        _refuse_non_finite(param)
    for sub in getattr(command, "commands", {}).values():
        finite_numbers(sub)


def _numbers(value: Any) -> list[float]:
    if isinstance(value, bool):
        return []
    if isinstance(value, float):
        return [value]
    if isinstance(value, tuple | list):
        return [n for v in value for n in _numbers(v)]
    return []


def _refuse_non_finite(param: Any) -> None:
    convert = param.process_value

    def process_value(ctx: Any, value: Any) -> Any:
        value = convert(ctx, value)
        bad = [v for v in _numbers(value) if not math.isfinite(v)]
        if bad:
            msg = f"{bad[0]!r} is not a finite number"
            raise typer.BadParameter(msg, ctx=ctx, param=param)
        return value

    param.process_value = process_value
