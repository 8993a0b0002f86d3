"""A map config holds only what shapes the map: every one of its fields is in the map's key.

How a build runs (read-ahead, memory, batch sizes, rebuilding, progress bars) is the run's
:class:`care_maps.runtime.execution.Execution`; a how-to field that strayed into a map config would
either change the key of a map whose bytes it does not change, or hide from it. So each
field of :class:`care_maps.fuse.config.GridConfig` and :class:`care_maps.fuse.config.InstanceConfig`, changed
to another valid value, changes the fingerprint, and no field of ``Execution`` is one.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import typing

import pytest

from care_maps.fuse.config import GridConfig, InstanceConfig
from care_maps.runtime.execution import Execution

MAP_CONFIGS = (GridConfig, InstanceConfig)


def _other(value: object, hint: object) -> object:
    """A valid value of the field other than ``value``."""
    if isinstance(value, enum.Enum):
        return next(m for m in type(value) if m is not value)
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return value * 1.5 if value else 0.5
    if value is None and typing.get_origin(hint) in (typing.Union, type(int | None)):
        return ("chair", "table")  # the vocabulary: names instead of the store's
    raise AssertionError(f"no other value for {value!r} ({hint})")


@pytest.mark.parametrize("cls", MAP_CONFIGS, ids=lambda c: c.__name__)
def test_every_field_changes_the_fingerprint(cls: type) -> None:
    base = cls()
    hints = typing.get_type_hints(cls)
    for field in dataclasses.fields(cls):
        changed = dataclasses.replace(
            base, **{field.name: _other(getattr(base, field.name), hints[field.name])}
        )
        assert changed.fingerprint() != base.fingerprint(), field.name
        assert changed.settings() != base.settings(), field.name


@pytest.mark.parametrize("cls", MAP_CONFIGS, ids=lambda c: c.__name__)
def test_the_recorded_settings_are_every_field(cls: type) -> None:
    names = {f.name for f in dataclasses.fields(cls)}
    assert set(json.loads(cls().settings())) == names
    assert not hasattr(cls, "HOW")


@pytest.mark.parametrize("cls", MAP_CONFIGS, ids=lambda c: c.__name__)
def test_no_execution_field_is_in_a_map_config(cls: type) -> None:
    how = {f.name for f in dataclasses.fields(Execution)}
    assert not how & {f.name for f in dataclasses.fields(cls)}
