"""``care check PATH``: verify a store and its maps, an evaluation folder, or a ``care run``
output (sizes, checksums, Parquet footers)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

__all__ = ["register"]


def _store_problems(path: Path) -> list[str]:
    """Every damaged file of the store ``path`` and every map file of another store or
    build (:func:`care_maps.fuse.provenance.map_problems`): a file copied from another store is named
    as that, not as damaged, and an intact file is not named for it."""
    from care_maps.core.errors import CareError
    from care_maps.core.store import Store
    from care_maps.fuse.provenance import map_problems

    try:
        store = Store(path)
        foreign = map_problems(store)
        named = {line.split(": ")[0] for line in foreign}
        return foreign + [line for line in store.verify() if line.split(": ")[0] not in named]
    except CareError as err:  # Store raises StoreError
        return [str(err)]


def _eval_problems(path: Path, command: str) -> list[str]:
    """One line naming the evaluation's missing or changed files (none: it is whole)."""
    from care_maps.core.outputs import damaged

    bad = damaged(path)
    if not bad:
        return []
    more = f" (and {len(bad) - 1} more: {', '.join(bad[1:])})" if len(bad) > 1 else ""
    return [
        f"{path / bad[0]}: missing, truncated or altered since it was written{more}; "
        f"re-run `{command}` with --out {path} to write it again"
    ]


def _verify(path: Path) -> tuple[list[str], str]:
    """The problems of ``path`` (a store, evaluation or run output) and its ok line."""
    from care_maps.core.outputs import OutputKind, read_marker

    kind = (read_marker(path) or {}).get("kind")
    if kind == OutputKind.EVAL:
        files = len((read_marker(path) or {}).get("tables") or {})
        return _eval_problems(path, "care eval"), f"{path}: ok ({files} files verified)"
    if kind == OutputKind.RUN:
        stores = sorted(p.parent for p in path.glob("stores/*/meta.json"))
        problems = [line for store in stores for line in _store_problems(store)]
        if (path / "eval").is_dir():
            problems += _eval_problems(path / "eval", "care run")
        evaluated = " and its evaluation" if (path / "eval").is_dir() else ""
        return problems, f"{path}: ok ({len(stores)} stores{evaluated} verified)"
    tables = sorted(p.name for p in Path(path).glob("*.parquet"))
    problems = _store_problems(path)
    ok = f"{path}: ok ({len(tables)} tables verified)"
    if not problems:
        from care_maps.cli.summary import geometry_line, runs_lines

        geometry = geometry_line(path)
        ok += "" if geometry is None else "\n" + geometry
        ok += "".join("\n" + line for line in runs_lines(path))
    return problems, ok


def check(
    paths: Annotated[
        list[Path],
        typer.Argument(
            help="Store directories (`care ingest`), evaluation folders (`care eval`) or "
            "`care run` outputs."
        ),
    ],
) -> None:
    """Verify stores and their maps, evaluations and `care run` outputs: every file whole,
    as it was written; exit 1 if not.

    An output whose previous version a killed process had moved aside (and not yet put
    back) is restored first."""
    from care_maps.core.outputs import restore_stale

    bad = 0
    for path in paths:
        restore_stale(path)
        problems, ok = _verify(path)
        if problems:
            bad += 1
            for line in problems:
                typer.echo(f"error: {line}", err=True)
        else:
            typer.echo(ok)
    if bad:
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    """Add ``care check`` to ``app``."""
    app.command("check")(check)
