"""Put a benchmark's latest figures into its section of ``docs/benchmarks.md``.

Each script's table lies between two markers on the page::

    <!-- bench:fuse -->
    ...the table the script wrote last...
    <!-- /bench:fuse -->

:func:`write_section` replaces what lies between a section's markers, and nothing else, so
the page always shows the latest run of every script and the prose around the tables stays
as written. A script calls it at the end of its run::

    from bench.docs_section import write_section

    write_section("fuse", table_markdown)
"""

from __future__ import annotations

import os
import re
from pathlib import Path

__all__ = ["PAGE", "markers", "read_section", "write_section"]

PAGE = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"
"""The page holding every benchmark's section."""

_NAME = re.compile(r"[a-z0-9][a-z0-9_-]*")


def markers(name: str) -> tuple[str, str]:
    """The opening and closing markers of section ``name``."""
    if not _NAME.fullmatch(name):
        msg = f"benchmark section name {name!r}: use lower-case letters, digits, '-' and '_'"
        raise ValueError(msg)
    return f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"


def _span(text: str, name: str, page: Path) -> tuple[int, int]:
    """Where the body of section ``name`` starts and ends in ``text``."""
    start, end = markers(name)
    if text.count(start) != 1 or text.count(end) != 1:
        msg = (
            f"{page}: needs exactly one {start} and one {end} "
            f"(found {text.count(start)} and {text.count(end)}); add the section by hand first"
        )
        raise ValueError(msg)
    begin = text.index(start) + len(start)
    finish = text.index(end)
    if finish < begin:
        msg = f"{page}: {end} comes before {start}"
        raise ValueError(msg)
    return begin, finish


def read_section(name: str, page: Path = PAGE) -> str:
    """The markdown between section ``name``'s markers, without the surrounding newlines."""
    text = Path(page).read_text()
    begin, finish = _span(text, name, Path(page))
    return text[begin:finish].strip("\n")


def write_section(name: str, markdown: str, page: Path = PAGE) -> None:
    """Replace the text between ``<!-- bench:NAME -->`` and ``<!-- /bench:NAME -->`` on
    ``page`` with ``markdown``; the rest of the page is kept byte for byte.

    The page is replaced as a whole (written beside it, then renamed over it), so a run
    killed halfway leaves the page as it was. Missing or doubled markers are a
    :class:`ValueError` naming the page and the markers.
    """
    page = Path(page)
    text = page.read_text()
    begin, finish = _span(text, name, page)
    updated = f"{text[:begin]}\n{markdown.strip(chr(10))}\n{text[finish:]}"
    staged = page.with_name(f".{page.name}.tmp-{os.getpid()}")
    try:
        staged.write_text(updated)
        staged.replace(page)
    finally:
        staged.unlink(missing_ok=True)
