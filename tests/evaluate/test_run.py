"""`care run` on the bundled sample: the whole chain, the printed table and the .rrd files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from care.viz import rrd_entity_counts
from evaluate.pipeline import SAMPLE


@pytest.mark.slow
def test_care_run_on_the_bundled_sample(tmp_path: Path) -> None:
    if not (SAMPLE / "index.json").is_file():
        pytest.skip("the bundled sample is not present")
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-m",
        "care_cli.main",
        "run",
        "--out",
        str(out),
        "--seeds",
        "3",
        "--workers",
        "1",
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "| Min stderr | confidence |" in done.stdout
    assert "protocol `instance` (29 queries)" in done.stdout  # one query per GT instance
    assert "rerun " in done.stdout
    assert (out / "eval" / "results.md").is_file()
    counts = rrd_entity_counts(out / "scene_000.eval.rrd")
    assert counts[("/eval/log", "TextLog:text")] >= 20
    assert any(path.startswith("/world/eval/instances/first") for path, _ in counts)
    scalars = [p for p, c in counts if p.startswith("/eval/success/grid/class/min_stderr")]
    assert scalars
    assert sum(rrd_entity_counts(out / "scene_000.grid.rrd").values()) > 0
