"""What every stage's frozen config dataclass shares: its field docs, its JSON form, and
the values a map recorded with it.

A config's defaults and help exist once, in the dataclass: the default is the field's, the
help is the docstring written under the field (the habit of nerfstudio's and tyro's
configs). The CLI (:mod:`care_maps.cli.options`) builds its options from both, and a map table
stores the config it was built with as JSON (:func:`care_maps.core.fingerprint.config_json`) so that a later command
given no options reuses it (:func:`recorded_fields`).
"""

from __future__ import annotations

import ast
import dataclasses
import enum
import functools
import inspect
import json
import re
import sys
import textwrap
from typing import Any

__all__ = ["field_docs", "member", "recorded_fields"]


def member(kind: type[enum.Enum], value: object, error: type[Exception], what: str) -> Any:
    """``value`` as a member of the enum ``kind`` (configs accept its values as text), or
    ``error`` in one line that lists the choices."""
    try:
        return kind(value)
    except ValueError as err:
        choices = ", ".join(str(m.value) for m in kind)
        msg = f"{what} {value!r}; choose one of {choices}"
        raise error(msg) from err


def _class(klass: type) -> ast.ClassDef:
    """The class statement of ``klass``: its own lines parsed where they can be told apart
    (the CLI's start reads the field docs of a dozen configs; parsing their whole modules
    took 0.04 s of it), else its module's."""
    own = _block(_lines(klass.__module__), klass.__qualname__.split("."))
    if own is not None:
        try:
            node = ast.parse(textwrap.dedent("".join(own))).body[0]
        except (SyntaxError, IndexError):
            node = None
        named = {
            s.target.id
            for s in getattr(node, "body", ())
            if isinstance(s, ast.AnnAssign) and isinstance(s.target, ast.Name)
        }
        if isinstance(node, ast.ClassDef) and set(inspect.get_annotations(klass)) <= named:
            return node
    return _classes(klass.__module__)[klass.__qualname__]


@functools.cache
def _lines(module: str) -> list[str]:
    return inspect.getsource(sys.modules[module]).splitlines(keepends=True)


def _block(lines: list[str], names: list[str]) -> list[str] | None:
    """The lines of the class ``names`` (its qualified name, split) in a module's ``lines``:
    from its ``class`` line to the next line indented no deeper (comments and blank lines
    aside); None unless each name's ``class`` line is the only one in its block."""
    lo, hi = 0, len(lines)
    for name in names:
        line = re.compile(rf"\s*class {re.escape(name)}\b")
        starts = [i for i in range(lo, hi) if line.match(lines[i])]
        if len(starts) != 1:
            return None
        lo = starts[0]
        indent = len(lines[lo]) - len(lines[lo].lstrip())
        end = lo + 1
        while end < hi:
            text = lines[end].lstrip()
            if text and not text.startswith("#") and len(lines[end]) - len(text) <= indent:
                break
            end += 1
        hi = end
    return lines[lo:hi]


@functools.cache
def _classes(module: str) -> dict[str, ast.ClassDef]:
    """Qualified name -> class statement of every class a module defines, its source
    parsed once (``inspect.getsource`` of a class parses its whole module each time)."""
    source = inspect.getsource(sys.modules[module])
    found: dict[str, ast.ClassDef] = {}
    todo: list[tuple[str, ast.AST]] = [("", ast.parse(source))]
    while todo:
        prefix, node = todo.pop()
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef):
                found[prefix + child.name] = child
                todo.append((f"{prefix}{child.name}.", child))
    return found


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """Field name -> the first paragraph of the docstring under it, for a dataclass and its
    bases (a field without one maps to '')."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        body = _class(klass).body
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


def recorded_fields(cls: type, text: bytes | str | None) -> dict[str, Any]:
    """The fields of ``cls`` a recorded :func:`care_maps.core.fingerprint.config_json` holds (lists back to tuples);
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
