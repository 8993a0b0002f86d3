"""``care sample make`` leaves a dataset whole or absent: under a full disk (a file-size
limit) and Ctrl-C, no recording without its ground truth or ``index.json``, the earlier
dataset byte for byte as it was, and the message that says so is true."""

from __future__ import annotations

import json
import signal
from pathlib import Path

import pytest

from tests.support.cli import care_popen, care_process
from tests.support.faults import assert_fault, leftovers, snapshot
from tests.support.processes import appears, loading, wait_for

TINY = ("sample", "make", "--scenes", "1", "--rooms", "1", "--width", "32", "--height", "24",
        "--frames", "2", "--workers", "1", "--no-likeness")  # fmt: skip
LIMIT = 100_000
"""Bytes: room for the recording (~11 KB), not for its ground truth (~0.5 MB)."""


def _whole(dataset: Path) -> None:
    """Every recording the index lists is there with its ground truth."""
    index = json.loads((dataset / "index.json").read_text())
    for entry in index["recordings"]:
        name = entry["name"]
        assert (dataset / entry["recording"]).exists()
        assert (dataset / f"{name}.gt.parquet").is_file(), name
        assert (dataset / f"{name}.gt.json").is_file(), name


def test_full_disk_leaves_no_dataset(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    done = care_process(*TINY, "--out", out, fsize=LIMIT)
    assert_fault(done.returncode, done.stderr, r"file-size limit reached.*nothing half-written",
                 clean=(tmp_path,))  # fmt: skip
    assert not out.exists()
    assert care_process(*TINY, "--out", out).returncode == 0
    _whole(out)


def test_full_disk_keeps_the_earlier_dataset(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    assert care_process(*TINY, "--out", out).returncode == 0
    before = snapshot(out)
    done = care_process(*TINY, "--seed", "5", "--out", out, fsize=LIMIT)
    assert_fault(done.returncode, done.stderr, r"file-size limit", intact=before,
                 clean=(tmp_path,))  # fmt: skip


def _staged(tmp_path: Path, pattern: str):
    """A file matching ``pattern`` inside the dataset's staging temporary."""
    return lambda: any(p for d in tmp_path.glob(".ds.*-*") for p in d.glob(pattern))


# the moments of a run a Ctrl-C lands in, each waited for (never a fixed delay): modules
# loading, the dataset staged, a recording written into it, its ground truth written
MOMENTS = {
    "loading": lambda proc, tmp_path: loading(proc),
    "staged": lambda proc, tmp_path: appears(tmp_path, ".ds.*-*"),
    "recording written": lambda proc, tmp_path: _staged(tmp_path, "*.mcap"),
    "ground truth written": lambda proc, tmp_path: _staged(tmp_path, "*.gt.parquet"),
}


@pytest.mark.parametrize("moment", list(MOMENTS))
def test_ctrl_c_leaves_a_whole_dataset_or_none(tmp_path: Path, moment: str) -> None:
    out = tmp_path / "ds"
    proc = care_popen(*TINY[:-1], "--out", out)  # with the likeness step: a longer run
    if wait_for(proc, MOMENTS[moment](proc, tmp_path)):
        proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    if proc.returncode != 0:
        assert_fault(proc.returncode, err, r"^error: interrupted", exit_code=130)
    if out.exists():
        _whole(out)
    assert care_process(*TINY, "--out", out).returncode == 0
    _whole(out)
    assert not leftovers(tmp_path)
