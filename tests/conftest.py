"""Fixtures shared by every test package."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Third-party test data handed to the project (read-only), see ../shared/data/README.md."""
    path = SHARED / "data"
    if not path.is_dir():
        pytest.skip(f"{path} not present")
    return path
