"""``care check STORE``: verify a store and its maps (sizes, checksums, Parquet footers)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

__all__ = ["register"]


def check(
    stores: Annotated[
        list[Path], typer.Argument(help="Store directories written by `care ingest`.")
    ],
) -> None:
    """Verify stores and their maps: every table whole, as it was written; exit 1 if not."""
    from care.errors import CareError, StoreError
    from care.store import Store

    bad = 0
    for path in stores:
        try:
            problems = Store(path).verify()
        except StoreError as err:
            problems = [str(err)]
        except CareError as err:  # pragma: no cover - Store raises StoreError
            problems = [str(err)]
        if problems:
            bad += 1
            for line in problems:
                typer.echo(f"error: {line}", err=True)
        else:
            tables = sorted(p.name for p in Path(path).glob("*.parquet"))
            typer.echo(f"{path}: ok ({len(tables)} tables verified)")
    if bad:
        raise typer.Exit(1)


def register(app: typer.Typer) -> None:
    """Add ``care check`` to ``app``."""
    app.command("check")(check)
