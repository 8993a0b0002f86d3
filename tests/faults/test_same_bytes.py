"""The same input gives the same bytes in every output file: no time, date, host or pid
is written (timings go to the terminal). Two runs of ``care sample make`` (its likeness
measurement included) and of ``care ingest``, into two folders, compared file by file."""

from __future__ import annotations

from pathlib import Path

TINY = ("--scenes", "1", "--seed", "11", "--rooms", "1", "--width", "32", "--height", "24",
        "--frames", "2", "--workers", "1")  # fmt: skip


def _files(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def _same(a: Path, b: Path) -> None:
    first, second = _files(a), _files(b)
    assert first.keys() == second.keys()
    assert [k for k in first if first[k] != second[k]] == []


def test_sample_make_twice_same_bytes(care, tmp_path: Path) -> None:
    for run in ("a", "b"):
        code, out, err = care("sample", "make", *TINY, "--out", tmp_path / run / "ds")
        assert code == 0, err
        assert "CLIP likeness" in out  # the measurement ran (its time printed, not written)
    _same(tmp_path / "a" / "ds", tmp_path / "b" / "ds")


def test_ingest_twice_same_bytes(care, recording: Path, tmp_path: Path) -> None:
    for run in ("a", "b"):
        code, _, err = care("ingest", recording, "--out", tmp_path / run / "store")
        assert code == 0, err
    _same(tmp_path / "a" / "store", tmp_path / "b" / "store")
