"""Frame selection on a hand-made stream: time range, every Nth, and the motion filter."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame
from care_maps.ingest.select import FrameSelection, FrameSelector


def _frame(i: int, x: float, yaw_deg: float) -> Frame:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    pose[0, 3] = x
    empty = np.zeros((2, 2), np.float32)
    return Frame(5 * 10**9 + i * 500_000_000, np.zeros((2, 2, 3), np.uint8), empty, np.eye(3), pose)


def _kept(selection: FrameSelection, frames: list[Frame]) -> tuple[list[int], dict]:
    sel = FrameSelector(selection)
    kept = []
    for i, f in enumerate(frames):
        if sel.keep(f):
            kept.append(i)
        elif sel.done:
            break
    return kept, dict(sel.skipped)


def test_time_range_and_every() -> None:
    frames = [_frame(i, float(i), 0.0) for i in range(10)]  # one every 0.5 s
    kept, skipped = _kept(FrameSelection(start=1.0, end=3.0, every=2), frames)
    # in range: t = 1.0 .. 3.0 -> frames 2..6; every 2nd of those: 2, 4, 6
    assert kept == [2, 4, 6]
    assert skipped == {"before start": 2, "every": 2}


def test_motion_filter_needs_both_small() -> None:
    path = [(0.0, 0), (0.05, 2), (0.3, 2), (0.32, 30), (0.33, 31)]
    frames = [_frame(i, x, yaw) for i, (x, yaw) in enumerate(path)]
    kept, skipped = _kept(FrameSelection(min_motion=0.2, min_rotation=10), frames)
    assert kept == [0, 2, 3]  # 1: 5 cm, 2 deg; 4: 1 cm, 1 deg after 3
    assert skipped == {"little motion": 2}


@pytest.mark.parametrize(
    "kwargs",
    [{"every": 0}, {"start": -1.0}, {"min_motion": float("nan")}, {"start": 5.0, "end": 1.0}],
)
def test_bad_selection_is_one_clear_error(kwargs) -> None:
    with pytest.raises(IngestError, match="--"):
        FrameSelection(**kwargs)
