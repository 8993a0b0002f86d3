"""Fixtures of the ingest tests: where the real RGB-D data lies.

Synthetic frames, message builders, hand-built bags and the frames' loaders are in
``tests/support`` (:mod:`tests.support.frames`, :mod:`tests.support.messages`,
:mod:`tests.support.recordings`).
"""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def slambook_root(shared_data: Path) -> Path:
    return shared_data / "rgbd" / "slambook_kinect5"
