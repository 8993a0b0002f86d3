"""The command index of ``care``: a run of one command imports only the module that
registers it, so the index must name exactly what each module registers."""

from __future__ import annotations

import contextlib
import importlib
import io
import pkgutil
import subprocess
import sys

import typer

import care_maps.cli
from care_maps.cli import main as cli
from care_maps.cli.main import COMMAND_MODULES
from tests.support.cli import after_care


def _names(module: str) -> set[str]:
    """The commands and groups ``module`` registers on a fresh app."""
    fresh = typer.Typer()
    importlib.import_module(f"care_maps.cli.{module}").register(fresh)
    commands = {c.name for c in fresh.registered_commands}
    groups = {g.name for g in fresh.registered_groups}
    return {n for n in commands | groups if n is not None}


def test_the_index_names_what_each_module_registers() -> None:
    modules = sorted(
        m.name for m in pkgutil.iter_modules(care_maps.cli.__path__) if m.name.endswith("_cmd")
    )
    assert sorted(set(COMMAND_MODULES.values())) == modules
    for module in modules:
        indexed = {name for name, owner in COMMAND_MODULES.items() if owner == module}
        assert _names(module) == indexed, module


def test_one_command_imports_its_own_module_alone() -> None:
    found = after_care(
        ["query", "--help"],
        "sorted(m for m in sys.modules if m.startswith('care_maps.cli.') and m.endswith('_cmd'))",
    )
    assert found == "['care_maps.cli.query_cmd']"


def test_help_lists_every_command() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "care_maps.cli.main", "--help"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    listed = {line.split()[0] for line in out.split("Commands:")[1].splitlines() if line.strip()}
    assert listed == set(COMMAND_MODULES)


def _help(program: typer.Typer) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        cli.build_command(program)(["--help"], prog_name="care", standalone_mode=False)
    return out.getvalue()


def test_the_listing_is_the_registered_commands_help() -> None:
    """``care --help`` lists the commands from their modules' source, without importing
    them: the same text as the registered commands give."""
    listing = cli._listing()
    assert listing is not None  # every module registers in the form the listing reads
    # a program of every module registered in index order, as `care --help` would have it
    # (cli.app of this process may hold a command registered by an earlier test first)
    registered = cli._program()
    for module in dict.fromkeys(COMMAND_MODULES.values()):
        importlib.import_module(f"care_maps.cli.{module}").register(registered)
    cli._plain_help(registered)
    assert _help(listing) == _help(registered)
    assert "Commands:" in _help(listing)


def test_help_imports_no_command_module() -> None:
    found = after_care(
        ["--help"],
        "sorted(m for m in sys.modules if m.endswith('_cmd') or m.endswith('pipeline'))",
    )
    assert found == "[]"
