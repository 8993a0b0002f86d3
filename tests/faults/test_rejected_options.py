"""A rejected option changes nothing: every numeric option of every command refuses NaN
and infinities as a usage error before any work, and a command that fails after changing
the store's map frame puts the old one back, so the store keeps working."""

from __future__ import annotations

import json
import math
import typing
from pathlib import Path

import pytest

from tests.support.faults import assert_fault, snapshot


def _numeric_options() -> list[tuple[tuple[str, ...], str]]:
    """``(command path, --flag)`` of every option taking a float, from the CLI itself."""
    import typer

    from care_maps.cli.main import _register, app

    _register()
    found: list[tuple[tuple[str, ...], str]] = []

    def walk(command, path: tuple[str, ...]) -> None:
        for param in command.params:
            hint = getattr(getattr(param, "type_descriptor", None), "annotation", None)
            args = [a for a in typing.get_args(hint) if a is not type(None)] or [hint]
            if float in args and param.opts:
                found.append((path, param.opts[0]))
        for name, sub in getattr(command, "commands", {}).items():
            walk(sub, (*path, name))

    walk(typer.main.get_command(app), ())
    return found


NUMERIC = _numeric_options()


def test_every_float_option_is_found() -> None:
    flags = {f for _, f in NUMERIC}
    assert {"--cell-size", "--floor-z", "--iou-threshold", "--max-dt", "--voxel-size"} <= flags


@pytest.mark.slow
@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
@pytest.mark.parametrize(("path", "flag"), NUMERIC, ids=[" ".join(p) + f" {f}" for p, f in NUMERIC])
def test_non_finite_numbers_are_usage_errors(
    care, tmp_path: Path, path: tuple[str, ...], flag: str, value: str
) -> None:
    """Refused while the command line is read: nothing is made, whatever the command."""
    positional = {"sample": (), "check": ()}.get(path[0], (tmp_path / "x",))
    code, _, err = care(*path, *positional, f"{flag}={value}")
    assert_fault(code, err, rf"'{flag}'.*{value} is not a finite number", exit_code=2)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@pytest.mark.parametrize(
    ("command", "floor", "expected"),
    [("grid", "nan", 2), ("instances", "nan", 2), ("grid", "5", 1)],
)
def test_a_rejected_floor_leaves_the_store_as_it_was(
    care, copy_good, command: str, floor: str, expected: int
) -> None:
    """``nan`` is refused on the command line; a finite floor far from the depth makes the
    build fail, and the map frame it wrote is put back: the store is byte for byte the same,
    and the next commands work."""
    store = copy_good("store")
    before = snapshot(store)
    code, _, err = care("fuse", command, store, "--overwrite", "--floor-z", floor)
    assert_fault(code, err, r"floor|finite", exit_code=expected, clean=(store.parent,))
    assert snapshot(store) == before
    if expected == 2:  # refused before any work: nothing ran that could have changed it
        return
    assert care("fuse", "grid", store)[0] == 0
    code, _, err = care("query", store, "chair")
    assert code == 0, err
    assert care("check", store)[0] == 0


@pytest.mark.slow
def test_a_damaged_map_frame_is_found_by_check(care, copy_good) -> None:
    store = copy_good("store")
    path = store / "map_frame.json"
    doc = json.loads(path.read_text())
    doc["frame"]["floor"] = math.nan
    doc["frame"]["map_from_world"][11] = math.nan
    path.write_text(json.dumps(doc))
    code, _, err = care("check", store)
    assert_fault(code, err, r"map_frame\.json: the map frame holds non-finite numbers")
    code, _, err = care("query", store, "chair")
    assert_fault(code, err, r"map_frame\.json: the map frame holds non-finite numbers")
