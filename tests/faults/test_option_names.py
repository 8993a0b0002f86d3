"""Every option's refusal names the option as typed (``--from``, not the field ``start``),
and every frame-id option refuses what tf2 would reject, before any work, in one line."""

from __future__ import annotations

import typing
from pathlib import Path

import pytest

from tests.support.faults import assert_fault

BAD_FRAME_IDS = ("", "/map", "camera link")
"""Empty and leading-slash ids (tf2's ``validateFrameId`` refuses both), whitespace."""


def _frame_id_options() -> list[tuple[tuple[str, ...], str]]:
    """``(command path, --flag)`` of every frame-id option, from the CLI itself."""
    import typer

    from care_maps.cli.main import _register, app

    _register()
    found: list[tuple[tuple[str, ...], str]] = []

    def walk(command, path: tuple[str, ...]) -> None:
        found.extend(
            (path, p.opts[0])
            for p in command.params
            if set(p.opts) & {"--frame-id", "--world-frame", "--camera-frame"}
        )
        for name, sub in getattr(command, "commands", {}).items():
            walk(sub, (*path, name))

    walk(typer.main.get_command(app), ())
    return found


FRAME_OPTIONS = _frame_id_options()


def test_every_frame_id_option_is_found() -> None:
    found = {(p[0], f) for p, f in FRAME_OPTIONS}
    assert {("frame", "--frame-id"), ("query", "--frame-id"), ("replan", "--frame-id"),
            ("ingest", "--world-frame"), ("ingest", "--camera-frame")} <= found  # fmt: skip


@pytest.mark.parametrize("value", BAD_FRAME_IDS)
@pytest.mark.parametrize(
    ("path", "flag"), FRAME_OPTIONS, ids=[" ".join(p) + f" {f}" for p, f in FRAME_OPTIONS]
)
def test_frame_ids_tf2_rejects_are_refused(
    care, tmp_path: Path, path: tuple[str, ...], flag: str, value: str
) -> None:
    code, out, err = care(*path, tmp_path / "x", f"{flag}={value}")
    assert_fault(code, err, rf"'{flag}'.* is not a TF frame id", exit_code=2)
    assert out == ""  # no command printed for tf2 to reject
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("args", "flag", "exit_code"),
    [
        (("query", "{s}", "chair", "--from", "abc"), "'--from'", 2),
        (("query", "{s}", "chair", "--from", "1,2,3"), "'--from'", 2),
        (("replan", "{s}", "chair", "--from", "1,inf"), "'--from'", 2),
        (("replan", "{s}", "chair", "--visited", "1,2,3"), "--visited '1,2,3'", 1),
    ],
)
def test_option_errors_name_the_option(
    care, good: Path, args: tuple[str, ...], flag: str, exit_code: int
) -> None:
    code, _, err = care(*(a.format(s=good / "store") for a in args))
    assert_fault(code, err, flag, exit_code=exit_code)


def test_the_library_refuses_them_too() -> None:
    """The one check, also where the plan of a frame is made (``care frame``, goals)."""
    import numpy as np

    from care_maps.core.frames import FrameIdError, check_frame_id
    from care_maps.core.mapframe import MapFrame
    from care_maps.query.publish import frame_plan

    assert check_frame_id("base_link") == "base_link"
    frame = typing.cast(MapFrame, type("F", (), {"is_gravity_aligned": True,
                                                 "map_from_world": np.eye(4)})())  # fmt: skip
    for name in BAD_FRAME_IDS:
        with pytest.raises(FrameIdError, match="not a TF frame id"):
            frame_plan(frame, "map", name)
