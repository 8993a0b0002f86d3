"""A config's field docs are read from its own lines: the same class statement as its whole
module's parse gives, for every dataclass of the modules whose configs the CLI builds
options from."""

from __future__ import annotations

import ast
import dataclasses
import importlib

from care_maps.core.config import _class, _classes

_MODULES = (
    "care_maps.core.encoders.base",
    "care_maps.evaluate.config",
    "care_maps.fuse.config",
    "care_maps.ingest.pipeline",
    "care_maps.ingest.select",
    "care_maps.ingest.source",
    "care_maps.query.explore",
    "care_maps.query.goals",
    "care_maps.query.paths",
    "care_maps.replan.attempts",
    "care_maps.replan.batch",
    "care_maps.runtime.execution",
    "care_maps.world.record",
)


def _body(node: ast.ClassDef) -> list[str]:
    return [ast.dump(stmt, include_attributes=False) for stmt in node.body]


def test_own_lines_give_the_modules_class_statement() -> None:
    checked = 0
    for name in _MODULES:
        module = importlib.import_module(name)
        for cls in vars(module).values():
            if isinstance(cls, type) and dataclasses.is_dataclass(cls):
                if cls.__module__ != name:
                    continue
                assert _body(_class(cls)) == _body(_classes(name)[cls.__qualname__]), cls
                checked += 1
    assert checked >= 30
