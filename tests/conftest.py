"""Fixtures shared by every test package."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.cli import InProcessCli

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Third-party test data handed to the project (read-only), see ../shared/data/README.md."""
    path = SHARED / "data"
    if not path.is_dir():
        pytest.skip(f"{path} not present")
    return path


@pytest.fixture(scope="session")
def livingroom_root(shared_data: Path) -> Path:
    """The third-party living-room RGB-D frames (ICL-NUIM), the recordings' usual source."""
    return shared_data / "rgbd" / "livingroom1_clean_micro"


def _save_tiny_clip(out: Path, layers: int) -> Path:
    """A real CLIP (random weights, seed 0) written with ``save_pretrained``: model, a real
    byte-level BPE tokenizer over a small vocabulary, and an image processor."""
    from care_maps.core.encoders.random_clip import save_random_clip

    return save_random_clip(out, layers=layers)


@pytest.fixture(scope="session")
def save_tiny_clip():
    """``save_tiny_clip(out_dir, layers)``: write a tiny real CLIP checkpoint, return its path."""
    return _save_tiny_clip


@pytest.fixture
def run_cli(capsys: pytest.CaptureFixture[str]) -> InProcessCli:
    """Run ``care ARGS`` in-process through ``care_maps.cli.main.main``: (exit code, stdout, stderr)."""
    return InProcessCli(capsys)
