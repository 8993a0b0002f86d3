"""`care run` on a user's own recordings: one recording with a CLIP checkpoint directory and
no ground truth, and a plain folder of three recordings in three formats. Both exit 0 with
maps and Rerun files, and say that nothing was evaluated."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from care_maps.core.frames import Frame
from care_maps.ingest.write import write_recording
from tests.support.frames import load_livingroom

pytestmark = pytest.mark.slow

OFFLINE = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}


def _frames(livingroom_root: Path, start: int) -> list[Frame]:
    """Eight living-room frames at a quarter resolution (160 x 120)."""
    out = []
    for f in load_livingroom(livingroom_root, start + 40)[start::5]:
        K = f.K.copy()
        K[:2] /= 4
        K[:2, 2] = (f.K[:2, 2] - 1.5) / 4
        out.append(
            Frame(f.stamp_ns, f.rgb[::4, ::4].copy(), f.depth_m[::4, ::4].copy(), K, f.cam_to_world)
        )
    return out


def _care(*args) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "care_maps.cli.main", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, env=OFFLINE, timeout=900)


@pytest.mark.slow
def test_run_on_own_recordings_without_ground_truth(
    tmp_path: Path, livingroom_root: Path, save_tiny_clip
) -> None:
    weights = save_tiny_clip(tmp_path / "weights" / "tiny-clip", layers=2)
    folder = tmp_path / "recordings"
    folder.mkdir()
    write_recording(folder / "kitchen.mcap", _frames(livingroom_root, 0), fmt="mcap")
    write_recording(folder / "hall.bag", _frames(livingroom_root, 40), fmt="ros1")
    write_recording(folder / "lab", _frames(livingroom_root, 80), fmt="ros2")
    clip = ["--encoder", "clip", "--weights", weights, "--vocabulary", "chair,sofa,table"]

    one = _care("run", folder / "kitchen.mcap", "--out", tmp_path / "one", *clip)
    assert one.returncode == 0, one.stderr[-2000:]
    assert "no ground truth for kitchen" in one.stdout
    assert (tmp_path / "one" / "stores" / "kitchen" / "map.yaml").is_file()
    assert (tmp_path / "one" / "kitchen.grid.rrd").is_file()

    many = _care("run", folder, "--out", tmp_path / "many", *clip)
    assert many.returncode == 0, many.stderr[-2000:]
    assert "no ground truth for hall, kitchen, lab" in many.stdout
    for name in ("hall", "kitchen", "lab"):
        store = tmp_path / "many" / "stores" / name
        assert (store / "cells.parquet").is_file()
        assert (store / "instances.parquet").is_file()
        assert (store / "map_frame.json").is_file()  # the y-down trajectory, aligned
        assert (tmp_path / "many" / f"{name}.instances.rrd").is_file()
    assert not (tmp_path / "many" / "eval").exists()
