"""Each default and each choice list is written once.

A default spelled in two signatures (a config's field and the function it feeds, a command's
option and the dataclass behind it) drifts the day one of them changes; a list of choices
spelled twice accepts in one place what the other refuses. This reads the product's source
(not the tests, benches or scripts) and finds both kinds of copy:

- a keyword default (a parameter's or a dataclass field's) with the same name and the same
  literal value in two places, where the value says something (not None, a bool, 0, 1 or "");
- a literal tuple, list or set of three or more strings (a list of choices, of columns, of
  names) spelled out twice;
- a table-metadata key (``b"care...."``) spelled out twice.

One of the two places should import the other's constant, enum or dataclass default.
"""

from __future__ import annotations

import ast
import subprocess
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = "care_maps"
"""The product's one package (its subpackages are the layers)."""
TRIVIAL = (None, True, False, 0, 1, "", 0.0, 1.0)


def _sources() -> list[Path]:
    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "*.py"],
        cwd=ROOT, capture_output=True, text=True, check=True,
    ).stdout.split()  # fmt: skip
    return [ROOT / f for f in listed if f.split("/")[0] == PRODUCT and (ROOT / f).is_file()]


def _says_something(node: ast.expr | None) -> bool:
    if not isinstance(node, ast.Constant):
        return False
    value = node.value
    return not (
        isinstance(value, bool) or any(value == t and type(value) is type(t) for t in TRIVIAL)
    )


def _keyword_defaults(tree: ast.AST):
    """(name, value, line, owner) of each parameter default and dataclass field default."""
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            args = node.args
            positional = args.posonlyargs + args.args
            pairs = [
                *zip(positional[len(positional) - len(args.defaults):], args.defaults, strict=True),
                *zip(args.kwonlyargs, args.kw_defaults, strict=True),
            ]  # fmt: skip
            for arg, default in pairs:
                if _says_something(default):
                    yield arg.arg, default.value, node.lineno, node.name
        elif isinstance(node, ast.ClassDef):
            for item in node.body:
                if (
                    isinstance(item, ast.AnnAssign)
                    and isinstance(item.target, ast.Name)
                    and _says_something(item.value)
                ):
                    yield item.target.id, item.value.value, item.lineno, node.name


def _string_lists(tree: ast.AST):
    for node in ast.walk(tree):
        if isinstance(node, ast.Tuple | ast.List | ast.Set) and len(node.elts) >= 3:
            values = [e.value for e in node.elts if isinstance(e, ast.Constant)]
            if len(values) == len(node.elts) and all(isinstance(v, str) for v in values):
                yield frozenset(values), node.lineno


def _copies() -> tuple[dict, dict]:
    defaults: dict[tuple[str, str], list[str]] = defaultdict(list)
    lists: dict[frozenset[str], list[str]] = defaultdict(list)
    for path in _sources():
        tree = ast.parse(path.read_text(), str(path))
        where = path.relative_to(ROOT)
        for name, value, line, owner in _keyword_defaults(tree):
            defaults[name, repr(value)].append(f"{where}:{line} ({owner})")
        for values, line in _string_lists(tree):
            lists[values].append(f"{where}:{line}")
    return (
        {k: v for k, v in defaults.items() if len(v) > 1},
        {k: v for k, v in lists.items() if len(v) > 1},
    )


def test_no_default_written_twice() -> None:
    defaults, _ = _copies()
    found = [f"{name}={value}: {', '.join(places)}" for (name, value), places in defaults.items()]
    assert not found, "defaults written twice:\n" + "\n".join(sorted(found))


def test_no_choice_list_written_twice() -> None:
    _, lists = _copies()
    found = [f"{sorted(values)}: {', '.join(places)}" for values, places in lists.items()]
    assert not found, "lists written twice:\n" + "\n".join(sorted(found))


def test_the_finder_finds_a_copy(tmp_path: Path) -> None:
    """A hand-made copy of each kind is found (the checks above can fail)."""
    source = (
        "def a(batch_size=8, flag=True): ...\n"
        "class B:\n    batch_size: int = 8\n"
        "X = ('mcap', 'ros2', 'ros1')\nY = ['ros1', 'mcap', 'ros2']\n"
    )
    tree = ast.parse(source)
    names = [(n, v) for n, v, _, _ in _keyword_defaults(tree)]
    assert sorted(names) == [("batch_size", 8)] * 2
    assert [v for v, _ in _string_lists(tree)] == [frozenset({"mcap", "ros2", "ros1"})] * 2
    keys = ast.parse("A = {b'care.x': 1}\nB = md[b'care.x']\nC = b'other'\n")
    assert [k for k, _ in _metadata_keys(keys)] == [b"care.x"] * 2


def _metadata_keys(tree: ast.AST):
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Constant)
            and isinstance(node.value, bytes)
            and node.value.startswith(b"care.")
        ):
            yield node.value, node.lineno


def test_no_metadata_key_written_twice() -> None:
    """A table-metadata key (``b"care...."``) is spelled once, as a constant its writer and
    its readers import."""
    places: dict[bytes, list[str]] = defaultdict(list)
    for path in _sources():
        for key, line in _metadata_keys(ast.parse(path.read_text(), str(path))):
            places[key].append(f"{path.relative_to(ROOT)}:{line}")
    found = [f"{key!r}: {', '.join(p)}" for key, p in places.items() if len(p) > 1]
    assert not found, "metadata keys written twice:\n" + "\n".join(sorted(found))
