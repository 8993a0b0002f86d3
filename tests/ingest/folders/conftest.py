"""Fixtures of the folder tests: the living-room frames they lay out.

The layouts' writers (each public dataset's own conventions) are in
:mod:`tests.support.layouts`.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from care_maps.core.frames import Frame
from tests.support.frames import load_livingroom


@pytest.fixture(scope="session")
def livingroom40(livingroom_root: Path) -> list[Frame]:
    """40 living-room frames, every other one of the first 80 (2.6 s of the orbit)."""
    return load_livingroom(livingroom_root, 80)[::2]
