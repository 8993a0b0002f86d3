"""The checks of the fault-injection suite (``tests/faults``).

Each fault asserts the five properties of :func:`assert_fault`: the exit code, a single line
on stderr, no traceback, nothing half-written (no temporary left) and earlier good output
intact.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

if TYPE_CHECKING:
    from care_maps.evaluate.job import EvalConfig

PROGRESS: Final = re.compile(r"\d+%\|.*\| *[\d?]+/[\d?]+ \[|^[\w ]+: \d+it \[\d\d:\d\d, ")
"""A tqdm bar's frame: with a total (``40%|####  | 2/5 [``), or without (``scenes: 0it [00:00, ``)."""
BAR_FRAME: Final = re.compile(r"^.*?\d+%\|[^|]*\| *[\d?]+/[\d?]+ \[[^\]]*\]")
"""A whole tqdm frame at the start of a line: a worker's bar, left unfinished when the run
was stopped, and the program's line written after it."""
CURSOR: Final = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
"""A terminal control sequence (tqdm moves the cursor up over nested bars): not text."""
TMP_NAME: Final = re.compile(r"^\..+\.(tmp|old|building)-\d+")


def snapshot(*roots: Path) -> dict[str, str]:
    """Every file (hidden ones too) under ``roots``: relative path -> content hash."""
    files: dict[str, str] = {}
    for root in roots:
        root = Path(root)
        if root.is_file():
            files[str(root)] = hashlib.sha256(root.read_bytes()).hexdigest()
            continue
        for p in sorted(root.rglob("*")):
            if p.is_file() and not p.name.endswith(".lock"):
                files[str(p)] = hashlib.sha256(p.read_bytes()).hexdigest()
    return files


def leftovers(*dirs: Path) -> list[Path]:
    """Temporaries (``.<name>.tmp-<pid>`` etc.) and lock files in and below ``dirs``."""
    return [
        p
        for d in map(Path, dirs)
        if d.is_dir()
        for p in d.rglob(".*")
        if TMP_NAME.match(p.name) or p.name.endswith(".lock")
    ]


def assert_fault(
    code: int,
    err: str,
    pattern: str,
    *,
    exit_code: int = 1,
    clean: tuple[Path, ...] = (),
    intact: dict[str, str] | None = None,
) -> str:
    """The five properties: exit code, one line on stderr (matching ``pattern``), no traceback,
    no temporary left in ``clean``, and the files of ``intact`` unchanged."""
    assert code == exit_code, (code, err)
    assert "Traceback" not in err, err
    # what a terminal shows: a progress bar redraws with \r, a finished one clears itself
    # (in a pipe, tqdm may leave a bar's last frame: a bar, not a line of text)
    lines = [
        seen
        for line in err.split("\n")
        if (seen := BAR_FRAME.sub("", CURSOR.sub("", line.rsplit("\r", 1)[-1])).strip())
        and not PROGRESS.search(seen)
    ]
    assert len(lines) == 1, err
    assert lines[0].startswith("error: "), lines[0]
    assert re.search(pattern, lines[0]), lines[0]
    assert not leftovers(*clean), leftovers(*clean)
    if intact is not None:
        roots = {Path(p) for p in intact}
        now = {k: v for k, v in snapshot(*roots).items() if k in intact}
        assert now == intact
    return lines[0]


def tables(store: Path) -> dict[str, bytes]:
    """The bytes of each parquet table of ``store``, by file name."""
    return {p.name: p.read_bytes() for p in sorted(Path(store).glob("*.parquet"))}


@contextlib.contextmanager
def chmod(path: Path, mode: int) -> Iterator[None]:
    """``path`` at ``mode`` inside the block, at its old mode after."""
    old = Path(path).stat().st_mode & 0o7777
    Path(path).chmod(mode)
    try:
        yield
    finally:
        Path(path).chmod(old)


def read_meta(store: Path) -> dict[str, Any]:
    """The store's ``meta.json``."""
    loaded: dict[str, Any] = json.loads((Path(store) / "meta.json").read_text())
    return loaded


EVAL_FLAGS: Final = ("--seeds", "2", "--bootstrap", "10", "--workers", "1", "--k-grid", "4,8",
                     "--k-instances", "2,4")  # fmt: skip
"""``care eval``'s options of a small evaluation: :func:`eval_config` on the command line."""


def eval_config() -> EvalConfig:
    """The small evaluation the suite's good outputs hold (:data:`EVAL_FLAGS`)."""
    from care_maps.evaluate.job import EvalConfig

    return EvalConfig(seeds=2, bootstrap=10, k_grid=(4, 8), k_instances=(2, 4))
