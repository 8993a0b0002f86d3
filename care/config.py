"""What every stage's frozen config dataclass shares: its field docs, its JSON form, and
the values a map recorded with it.

A config's defaults and help exist once, in the dataclass: the default is the field's, the
help is the docstring written under the field (the habit of nerfstudio's and tyro's
configs). The CLI (:mod:`care_cli.options`) builds its options from both, and a map table
stores the config it was built with as JSON (:func:`config_json`) so that a later command
given no options reuses it (:func:`recorded_fields`).
"""

from __future__ import annotations

import ast
import dataclasses
import enum
import functools
import inspect
import json
import textwrap
from collections.abc import Iterable, Mapping
from typing import Any

__all__ = ["config_json", "field_docs", "member", "recorded_fields"]


def member(kind: type[enum.Enum], value: object, error: type[Exception], what: str) -> Any:
    """``value`` as a member of the enum ``kind`` (configs accept its values as text), or
    ``error`` in one line that lists the choices."""
    try:
        return kind(value)
    except ValueError as err:
        choices = ", ".join(str(m.value) for m in kind)
        msg = f"{what} {value!r}; choose one of {choices}"
        raise error(msg) from err


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """Field name -> the first paragraph of the docstring under it, for a dataclass and its
    bases (a field without one maps to '')."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        body = tree.body[0].body  # type: ignore[attr-defined]
        for stmt, after in zip(body, [*body[1:], None], strict=True):
            if not (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)):
                continue
            doc = ""
            if (
                isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)
            ):
                doc = inspect.cleandoc(after.value.value).split("\n\n")[0].replace("\n", " ")
            docs[stmt.target.id] = doc
    return {f.name: docs.get(f.name, "") for f in dataclasses.fields(cls)}


def _plain(value: Any) -> Any:
    """A JSON-able form of a config value: enums by value, tuples as lists, nested configs
    as dicts, paths as text."""
    if isinstance(value, enum.Enum):
        return value.value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, int | float | str | bool) or value is None:
        return value
    return str(value)


def config_json(config: object, *, leave_out: Iterable[str] = ()) -> str:
    """The config as sorted JSON (every field but ``leave_out``): what a map records."""
    skip = set(leave_out)
    fields = {
        f.name: _plain(getattr(config, f.name))
        for f in dataclasses.fields(config)  # type: ignore[arg-type]
        if f.name not in skip
    }
    return json.dumps(fields, sort_keys=True)


def recorded_fields(cls: type, text: bytes | str | None) -> dict[str, Any]:
    """The fields of ``cls`` a recorded :func:`config_json` holds (lists back to tuples);
    an absent or unreadable record gives ``{}`` (then the defaults apply)."""
    if not text:
        return {}
    try:
        values = json.loads(text)
    except ValueError:
        return {}
    if not isinstance(values, dict):
        return {}
    names = {f.name for f in dataclasses.fields(cls)}
    return {k: tuple(v) if isinstance(v, list) else v for k, v in values.items() if k in names}
