"""Encoders are found by name through the ``care_maps.core.encoders`` entry points of the installed
packages: the built-ins and a user's own package alike, imported only when built."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

from care_maps.core.encoders import ENCODERS, ENTRY_POINT_GROUP, EncoderOptions, make_encoder
from care_maps.core.errors import EncoderError

PLUGIN = "care_test_user_vlm"
"""Module of the user's encoder package written by :func:`user_package`."""

_MODULE = """
import numpy as np

from care_maps.core.encoders import Encoder


class UserEncoder(Encoder):
    name = "user-vlm"
    dim = 4

    def __init__(self, options):
        self.options = options

    def encode_views(self, frames):
        return np.zeros((len(frames), 1, 1, self.dim), np.float32)

    def encode_text(self, names):
        return np.eye(len(names), self.dim, dtype=np.float32)


NOT_AN_ENCODER = object
"""


@pytest.fixture
def user_package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """An installed distribution (``.dist-info`` on ``sys.path``) that declares two
    ``care_maps.core.encoders`` entry points: a real encoder and something that is not one."""
    (tmp_path / f"{PLUGIN}.py").write_text(_MODULE)
    dist = tmp_path / "care_test_user_vlm-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: care-test-user-vlm\nVersion: 0.1\n"
    )
    (dist / "entry_points.txt").write_text(
        textwrap.dedent(f"""\
            [{ENTRY_POINT_GROUP}]
            user-vlm = {PLUGIN}:UserEncoder
            broken = {PLUGIN}:NOT_AN_ENCODER
            """)
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    ENCODERS.refresh()
    yield tmp_path
    monkeypatch.undo()
    sys.modules.pop(PLUGIN, None)
    ENCODERS.refresh()


def test_builtins_are_entry_points() -> None:
    assert ENCODERS["clip"] == "care_maps.core.encoders.clip:ClipEncoder"
    assert ENCODERS["precomputed"] == "care_maps.core.encoders.precomputed:PrecomputedEncoder"
    assert ENCODERS["labels"] == "care_maps.world.perception.encoder:LabelsEncoder"
    assert list(ENCODERS) == sorted(ENCODERS)


def test_a_user_package_registers_an_encoder_by_name(user_package: Path) -> None:
    assert "user-vlm" in ENCODERS
    enc = make_encoder("user-vlm", EncoderOptions(seed=3))
    assert type(enc).__module__ == PLUGIN
    assert enc.options.seed == 3
    assert enc.encode_text(["a", "b"]).shape == (2, 4)


def test_an_entry_point_that_is_not_an_encoder_is_one_line(user_package: Path) -> None:
    with pytest.raises(EncoderError, match=r"encoder 'broken' .*not a subclass") as err:
        make_encoder("broken")
    assert "\n" not in str(err.value)


def test_unknown_name_lists_the_installed_ones(user_package: Path) -> None:
    with pytest.raises(EncoderError) as err:
        make_encoder("nope")
    assert str(err.value) == f"unknown encoder 'nope'; choose one of {', '.join(ENCODERS)}"
    assert "user-vlm" in str(err.value)
    assert "labels" in str(err.value)


def test_the_registry_imports_no_encoder() -> None:
    """Listing the encoders reads metadata only: neither torch (clip) nor the sample world
    (labels) is imported."""
    code = (
        "import sys; from care_maps.core.encoders import ENCODERS; names = list(ENCODERS); "
        "heavy = [m for m in sys.modules if m.split('.')[0] in ('torch', 'transformers', 'world')"
        " or m in ('care_maps.core.encoders.clip', 'care_maps.core.encoders.precomputed')]; "
        "print(names, heavy)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == "['clip', 'labels', 'precomputed'] []"
