"""No ``care`` command deletes or overwrites a path it did not create: a user's directory,
the input rosbag2 directory, a regular file. Each is refused in one line, byte for byte
untouched, before any work."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.faults import assert_fault, snapshot
from tests.support.recordings import grey_bag

pytestmark = pytest.mark.slow

COMMANDS = {
    "ingest --out": lambda rec, store, target: ("ingest", rec, "--out", target),
    "ingest --rrd": lambda rec, store, target: ("ingest", rec, "--out", target.parent / "s", "--rrd", target),
    "fuse grid --rrd": lambda rec, store, target: ("fuse", "grid", store, "--rrd", target),
    "fuse instances --rrd": lambda rec, store, target: ("fuse", "instances", store, "--rrd", target),
    "eval --out": lambda rec, store, target: ("eval", store, "--out", target),
    "run --out": lambda rec, store, target: ("run", rec, "--out", target),
    "sample make --out": lambda rec, store, target: ("sample", "make", "--out", target, "--workers", "1"),
}  # fmt: skip


def _user_directory(tmp_path: Path, recording: Path) -> Path:
    user = tmp_path / "home"
    (user / "photos").mkdir(parents=True)
    (user / "photos" / "cat.jpg").write_bytes(b"\xff\xd8\xff\xe0cat")
    (user / "todo.txt").write_text("buy milk")
    return user


def _regular_file(tmp_path: Path, recording: Path) -> Path:
    path = tmp_path / "paper.tex"
    path.write_text("\\documentclass{article}")
    return path


TARGETS = {"user-directory": _user_directory, "regular-file": _regular_file}


@pytest.mark.parametrize("target_kind", list(TARGETS))
@pytest.mark.parametrize("command", list(COMMANDS))
def test_never_replaces_what_it_did_not_create(
    care, good: Path, recording: Path, tmp_path: Path, command: str, target_kind: str
) -> None:
    if command.endswith("--rrd") and target_kind == "user-directory":
        pytest.skip("an --rrd is a file; a directory there is refused (test_rrd_is_a_directory)")
    target = TARGETS[target_kind](tmp_path, recording)
    before = snapshot(target)
    names = sorted(p.name for p in tmp_path.iterdir())
    code, _, err = care(*COMMANDS[command](recording, good / "store", target))
    assert_fault(
        code,
        err,
        r"not replaced|not overwritten|not a file care wrote",
        clean=(tmp_path,),
        intact=before,
    )
    assert snapshot(target) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == names  # nothing made beside it


@pytest.mark.parametrize("where", ["itself", "inside", "ancestor"])
def test_the_input_rosbag2_directory_is_never_an_output(care, tmp_path: Path, where: str) -> None:
    bag = grey_bag(tmp_path / "rec" / "bag")
    before = snapshot(tmp_path / "rec")
    out = {"itself": bag, "inside": bag / "store", "ancestor": tmp_path / "rec"}[where]
    for args in (
        ("ingest", bag, "--out", out),
        ("ingest", bag, "--out", tmp_path / "s", "--rrd", bag / "x.rrd"),
    ):
        code, _, err = care(*args)
        assert_fault(code, err, r"input", clean=(tmp_path,), intact=before)
    assert snapshot(tmp_path / "rec") == before
    assert not (tmp_path / "s").exists()
    code, _, err = care("ingest", bag, "--out", tmp_path / "store")  # and it is still readable
    assert code == 0, err


def test_sweeping_spares_the_users_files(care, recording: Path, tmp_path: Path) -> None:
    """Stale temporaries are swept only for the output at hand: a user's file of a similar
    name beside it, from a 'process' long gone, stays."""
    mine = tmp_path / ".notes.old-999999"
    mine.write_text("keep me")
    stale = tmp_path / ".store.tmp-999999"  # a killed ingest's, of this very output
    stale.mkdir()
    (stale / "views.parquet").write_bytes(b"PAR1")
    assert care("ingest", recording, "--out", tmp_path / "store")[0] == 0
    assert mine.read_text() == "keep me"
    assert not stale.exists()
