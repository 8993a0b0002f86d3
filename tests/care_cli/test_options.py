"""The CLI's options are generated from the configs: each default and help exists once.

Checked against the dataclasses themselves (``dataclasses.fields``), not against values
copied here: every generated option's click default is its field's default, every enum
option lists its choices in ``--help`` and refuses anything else with a usage error
(exit 2), and a map records its settings so that a later command given no options neither
rebuilds it nor resets its logit scale.
"""

from __future__ import annotations

import dataclasses
import enum
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest
import typer.main

from care_maps.cli.options import Options, generated_options


def _commands() -> Iterator[tuple[str, Any]]:
    """``(path, command)`` of every ``care`` command (typer's own click objects)."""
    from care_maps.cli.main import _register, app

    _register()

    def walk(cmd: Any, path: str) -> Iterator[tuple[str, Any]]:
        if hasattr(cmd, "commands"):
            for name, sub in cmd.commands.items():
                yield from walk(sub, f"{path} {name}".strip())
        else:
            yield path, cmd

    yield from walk(typer.main.get_command(app), "")


def _value(v: object) -> object:
    return v.value if isinstance(v, enum.Enum) else v


@pytest.mark.slow
def test_every_generated_default_is_the_configs() -> None:
    seen = 0
    for path, cmd in _commands():
        params = {p.name: p for p in cmd.params}
        for opt in generated_options(cmd.callback):
            field = {f.name: f for f in dataclasses.fields(opt.cls)}[opt.field]
            param = params[opt.param]
            seen += 1
            if field.default is dataclasses.MISSING:
                assert param.required, (path, opt)
            elif opt.parsed:  # text read by a parser: None (not given), the help shows the default
                assert param.default is None, (path, opt)
                shown = ",".join(map(str, map(_value, field.default))) if isinstance(
                    field.default, tuple
                ) else str(_value(field.default)).replace("None", "none")  # fmt: skip
                assert param.show_default == shown, (path, opt)
            else:
                assert _value(param.default) == _value(field.default), (path, opt)
    assert seen > 60  # grid, instances, query, replan, eval, run, ingest, topics


@pytest.mark.slow
def test_help_lists_every_enum_choice(run_cli) -> None:
    for path, cmd in _commands():
        code, out, _ = run_cli(*path.split(), "--help")
        assert code == 0, path
        text = " ".join(out.replace("│", " ").split())
        for param in cmd.params:
            kind = getattr(getattr(param, "type_descriptor", None), "annotation", None)
            if isinstance(kind, type) and issubclass(kind, enum.Enum):
                for choice in kind:
                    assert str(choice.value) in text, (path, param.name, choice)
        for opt in generated_options(cmd.callback):
            for choice in opt.choices:
                assert choice in text, (path, opt.param, choice)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["replan", "store", "chair", "--strategy", "min_stderrr"], "--strategy"),
        (["replan", "store", "chair", "--criterion", "nearest"], "--criterion"),
        (["fuse", "instances", "store", "--proposals", "sam"], "--proposals"),
        (["eval", "store", "--strategies", "min_stderr,best"], "--strategies"),
        (["eval", "store", "--maps", "voxels"], "--maps"),
    ],
)
def test_an_unknown_choice_is_a_usage_error(run_cli, args: list[str], option: str) -> None:
    code, _, err = run_cli(*args)
    assert code == 2, err
    assert option in err
    assert "Traceback" not in err


def test_given_then_recorded_then_default() -> None:
    from care_maps.fuse.config import GridConfig

    recorded = GridConfig(stride=3, logit_scale=30.0).settings()
    given = Options(GridConfig, {"cell_size": 0.2, "stride": 2}, frozenset({"cell_size"}))
    config = given.config(recorded)
    assert (config.cell_size, config.stride, config.logit_scale) == (0.2, 3, 30.0)
    # a recorded name that is no field of the config (how a build ran) is not reused
    extra = json.dumps({**json.loads(recorded), "memory_budget": 1 << 30})
    assert given.config(extra) == config
    assert given.config(None).stride == GridConfig().stride


@pytest.mark.slow
def test_a_later_grid_command_reuses_the_maps_settings(tmp_path: Path, run_cli) -> None:
    """Built at scale 30 and stride 3: `--recompute` alone keeps scale 30 (it reset it to
    100), and `care fuse grid` with no options neither rebuilds it nor changes a byte."""
    from tests.support.stores import grid_store

    store = grid_store(tmp_path / "s", n=2)
    cells = store / "cells.parquet"
    args = ["fuse", "grid", str(store), "--cell-size", "0.1", "--stride", "3"]
    assert run_cli(*args, "--logit-scale", "30")[0] == 0
    built = pq.read_schema(cells).metadata
    assert float(built[b"care.logit_scale"]) == 30.0

    code, _, err = run_cli("fuse", "grid", str(store), "--recompute", "--vocabulary", "bed,sofa")
    assert code == 0, err
    md = pq.read_schema(cells).metadata
    assert float(md[b"care.logit_scale"]) == 30.0
    assert md[b"care.vocabulary"] == b'["bed", "sofa"]'

    before = cells.read_bytes(), cells.stat().st_mtime_ns
    code, _, err = run_cli("fuse", "grid", str(store))
    assert code == 0, err
    assert (cells.read_bytes(), cells.stat().st_mtime_ns) == before
