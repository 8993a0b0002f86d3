"""A re-run of an ingest with nothing to do returns before any model is built: torch is never
imported (it alone takes seconds), and a changed weights directory is noticed without it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
PROBE = """
import sys
from care_maps.cli.main import main
sys.argv = ["care", "ingest", sys.argv[1], "--out", sys.argv[2], "--encoder", "labels"]
try:
    main()
except SystemExit as exc:
    assert not exc.code, exc.code
print("torch imported" if "torch" in sys.modules else "no torch")
"""


def test_up_to_date_ingest_loads_no_model(tmp_path: Path) -> None:
    rec = ROOT / "care_maps" / "data" / "sample" / "scene_000.mcap"
    store = tmp_path / "store"
    first = subprocess.run(
        [sys.executable, "-c", PROBE, rec, store], capture_output=True, text=True
    )
    assert first.returncode == 0, first.stderr[-2000:]
    assert "torch imported" in first.stdout  # the first run encodes
    again = subprocess.run(
        [sys.executable, "-c", PROBE, rec, store], capture_output=True, text=True
    )
    assert again.returncode == 0, again.stderr[-2000:]
    assert "no torch" in again.stdout
    assert "80 views" in again.stdout
