"""What the program's unraisable hook does with an error from a finaliser: Python's own
report normally; nothing once the run is interrupted (the finaliser of an object the
interruption left half-built, e.g. tqdm's ``__del__`` without ``pos``)."""

from __future__ import annotations

import signal
import sys

import pytest

from care_maps.cli import main as cli


class _HalfBuilt:
    def __del__(self) -> None:
        raise AttributeError("'tqdm' object has no attribute 'pos'")


def _unraisable() -> object:
    """A real ``UnraisableHookArgs``, caught from a finaliser that raises."""
    caught: list[object] = []
    before = sys.unraisablehook
    sys.unraisablehook = caught.append
    try:
        _HalfBuilt()  # collected at once: its __del__ raises
    finally:
        sys.unraisablehook = before
    return caught[0]


def test_reported_as_python_does_while_running(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(cli, "_stopped_by", None)
    cli._raise_again(_unraisable())
    assert "AttributeError" in capsys.readouterr().err


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_dropped_once_interrupted(
    signum: int, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(cli, "_stopped_by", signum)
    cli._raise_again(_unraisable())
    assert capsys.readouterr().err == ""
