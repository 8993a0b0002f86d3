"""A symbolic link the user made is never replaced, followed or deleted: every output path
that is itself a link (to an empty directory, to a directory of ours, to a file, or
dangling) is refused in one line that names where it points, before any work, and the link
and what it points to stay as they were."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.faults import assert_fault

pytestmark = pytest.mark.slow

COMMANDS = {
    "ingest --out": lambda rec, store, link: ("ingest", rec, "--out", link),
    "ingest --rrd": lambda rec, store, link: ("ingest", rec, "--out", link.parent / "s", "--rrd", link),
    "fuse grid --rrd": lambda rec, store, link: ("fuse", "grid", store, "--rrd", link),
    "eval --out": lambda rec, store, link: ("eval", store, "--out", link),
    "run --out": lambda rec, store, link: ("run", rec, "--out", link),
    "sample make --out": lambda rec, store, link: ("sample", "make", "--out", link, "--workers", "1"),
    "sample make --rrd": lambda rec, store, link: ("sample", "make", "--out", link.parent / "d", "--rrd", link),
}  # fmt: skip
"""Each command whose output is ``link``."""

FILE_OUTPUTS = {"ingest --rrd", "fuse grid --rrd", "sample make --rrd"}


def _empty_directory(tmp_path: Path) -> Path:
    target = tmp_path / "emptydir"
    target.mkdir()
    return target


def _user_file(tmp_path: Path) -> Path:
    target = tmp_path / "notes.txt"
    target.write_text("mine")
    return target


def _nowhere(tmp_path: Path) -> Path:
    return tmp_path / "nowhere"


TARGETS = {"empty-directory": _empty_directory, "user-file": _user_file, "dangling": _nowhere}


def _state(tmp_path: Path) -> dict[str, str]:
    """Every entry under ``tmp_path``: links by their target, files by content."""
    out: dict[str, str] = {}
    for p in sorted(tmp_path.rglob("*")):
        key = str(p.relative_to(tmp_path))
        if p.is_symlink():
            out[key] = "-> " + str(p.readlink())
        elif p.is_file():
            out[key] = p.read_text(errors="replace")
        else:
            out[key] = "dir"
    return out


@pytest.mark.parametrize("target", list(TARGETS))
@pytest.mark.parametrize("command", list(COMMANDS))
def test_an_output_that_is_a_link_is_refused(
    care, good: Path, recording: Path, tmp_path: Path, command: str, target: str
) -> None:
    work = tmp_path / "work"
    work.mkdir()
    store = good / "store"
    link = work / "link"
    pointed = TARGETS[target](work)
    link.symlink_to(pointed)
    before = _state(work)
    code, _, err = care(*COMMANDS[command](recording, store, link))
    line = assert_fault(code, err, r"link: is a symbolic link; not replaced or followed")
    assert str(pointed) in line  # names where it points
    assert _state(work) == before
    assert link.is_symlink()


def test_the_way_out_it_names_works(care, recording: Path, tmp_path: Path) -> None:
    """Given the directory the link points to, the ingest writes there; the link stays."""
    target = tmp_path / "emptydir"
    target.mkdir()
    link = tmp_path / "link"
    link.symlink_to(target)
    code, _, err = care("ingest", recording, "--out", link)
    assert code == 1
    code, _, err = care("ingest", recording, "--out", target)
    assert code == 0, err
    assert link.is_symlink()
    assert (link / "views.parquet").is_file()  # seen through the user's link


def test_links_among_the_parents_are_followed(care, recording: Path, tmp_path: Path) -> None:
    """Only the output itself must not be a link: a linked data folder holds outputs."""
    (tmp_path / "disk").mkdir()
    (tmp_path / "data").symlink_to(tmp_path / "disk")
    code, _, err = care("ingest", recording, "--out", tmp_path / "data" / "store")
    assert code == 0, err
    assert (tmp_path / "disk" / "store" / "views.parquet").is_file()
    assert (tmp_path / "data").is_symlink()


def test_batch_answers_out_is_a_link(care, good: Path, tmp_path: Path) -> None:
    queries = tmp_path / "q.txt"
    queries.write_text("chair\n")
    user = tmp_path / "mine.parquet"
    user.write_bytes(b"PAR1 not ours")
    link = tmp_path / "answers.parquet"
    link.symlink_to(user)
    before = _state(tmp_path)
    code, _, err = care("query", good / "store", "--batch", queries, "--out", link)
    assert_fault(code, err, r"answers\.parquet: is a symbolic link", clean=(tmp_path,))
    assert _state(tmp_path) == before
