"""Put a benchmark's latest figures into its section of ``docs/benchmarks.md``.

Each script's table lies between two markers on the page::

    <!-- bench:fuse -->
    ...the table the script wrote last...
    <!-- /bench:fuse -->

:func:`write_section` replaces what lies between a section's markers, and nothing else, so
the page always shows the latest run of every script and the prose around the tables stays
as written. A script adds ``--no-docs`` to its command line and runs its work inside
:func:`recorded`, which keeps what the run prints and, when the run ends without an error,
writes it (with the command line that made it) into the script's section::

    add_docs_flag(parser)
    args = parser.parse_args()
    with recorded("fuse", write=not args.no_docs):
        run(args)
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import shlex
import sys
from collections.abc import Iterator
from pathlib import Path

__all__ = [
    "PAGE",
    "add_docs_flag",
    "as_markdown",
    "markers",
    "read_section",
    "recorded",
    "write_section",
]

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


def add_docs_flag(parser: argparse.ArgumentParser) -> None:
    """Add ``--no-docs`` (a trial run that must not replace the page's figures)."""
    parser.add_argument(
        "--no-docs",
        action="store_true",
        help=f"Do not write this run's figures into {PAGE.relative_to(PAGE.parents[1])}.",
    )


class _Tee(io.TextIOBase):
    """Writes to the terminal and keeps a copy."""

    def __init__(self, stream: io.TextIOBase) -> None:
        self.stream, self.kept = stream, io.StringIO()

    def write(self, text: str) -> int:
        self.kept.write(text)
        return self.stream.write(text)

    def flush(self) -> None:
        self.stream.flush()


@contextlib.contextmanager
def recorded(name: str, *, write: bool = True, page: Path = PAGE) -> Iterator[None]:
    """Print as usual; after a run that ends without an error, put what it printed into
    section ``name`` of ``page``, under the command line that made it (a run that fails
    leaves the page as it was)."""
    tee = _Tee(sys.stdout)
    with contextlib.redirect_stdout(tee):
        yield
    if write:
        command = shlex.join(["python3", f"bench/{Path(sys.argv[0]).name}", *sys.argv[1:]])
        cores = os.cpu_count()
        body = f"`{command}` ({cores} cores):\n\n{as_markdown(tee.kept.getvalue())}"
        write_section(name, body, page)


def as_markdown(printed: str) -> str:
    """A run's printed text as markdown: its markdown tables stay tables, a ``#`` heading
    line becomes a bold line (the page's own headings stay the outline), and every other
    run of lines is a ``text`` block, as the terminal showed it."""
    out: list[str] = []
    plain: list[str] = []

    def close_plain() -> None:
        while plain and not plain[-1].strip():
            plain.pop()
        if plain:
            out.append("```text\n" + "\n".join(plain) + "\n```")
        plain.clear()

    for line in printed.strip("\n").splitlines():
        if line.startswith("|"):
            close_plain()
            if out and out[-1].startswith("|"):
                out[-1] += "\n" + line
            else:
                out.append(line)
        elif line.startswith("#"):
            close_plain()
            out.append(f"**{line.lstrip('#').strip()}**")
        elif line.strip() or plain:
            plain.append(line)
    close_plain()
    return "\n\n".join(out)
