"""The product code type-checks: mypy over ``care_maps`` (the ``[tool.mypy]`` section of
``pyproject.toml``: non-strict, every annotation the code states is checked) reports no
error. It runs in CI with the rest of the suite, so an annotation that lies fails there."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_mypy_reports_no_error(tmp_path: Path) -> None:
    pytest.importorskip("mypy", reason="mypy comes with the dev extra (scripts/install.sh)")
    done = subprocess.run(
        [sys.executable, "-m", "mypy", "--cache-dir", str(tmp_path / "cache")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-6000:] + done.stderr[-2000:]
    assert "Success: no issues found" in done.stdout
