"""Dataset folders written in a convention their reader was not told: the living-room frames
in our generic layout with poses written world-to-camera, quaternions written ``w x y z``,
``depth_scale`` off by a thousand either way, and a TUM folder whose depth is TUM's 5000 per
metre under an ``intrinsics.json`` that says millimetres. Before the consistency check each
gave a wrong map with exit 0; now each is refused in one line naming the option that reads it
right, and that option gives the map of the same frames written as an MCAP by the real
writer (cells within 1%)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from care_maps.core.errors import IngestError
from care_maps.core.store import read_table
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.source import ReadOptions
from care_maps.ingest.write import write_recording
from care_maps.runtime.execution import Execution
from tests.support import layouts
from tests.support.encoders import TinyEncoder

QUIET = Execution(progress=False)
CELL = 0.05


def _cells(store: Path) -> set[tuple[int, int]]:
    table = read_table(store / "cells.parquet", ["ix", "iy"])
    return set(zip(table.column("ix").to_pylist(), table.column("iy").to_pylist(), strict=True))


def _build(source: Path, out: Path, **read: object) -> str | None:
    config = IngestConfig(read=ReadOptions(**read), vocabulary="red,green,blue")
    try:
        run_ingest(source, out, config, run=QUIET, encoder=TinyEncoder())
    except IngestError as err:
        assert not out.exists()
        return str(err)
    build_grid(out, GridConfig(cell_size=CELL, stride=2), run=QUIET)
    return None


@pytest.fixture(scope="module")
def reference(tmp_path_factory, livingroom40) -> set:
    root = tmp_path_factory.mktemp("ref")
    bag = write_recording(root / "rec.mcap", livingroom40, fmt="mcap")
    assert _build(bag, root / "store") is None
    return _cells(root / "store")


def _rewrite_poses(folder: Path, row) -> None:
    """poses.txt written again, each line's pose through ``row`` (stamp kept)."""
    lines = []
    for line in (folder / "poses.txt").read_text().splitlines():
        stamp, *values = line.split()
        v = np.array([float(x) for x in values])
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(v[3:]).as_matrix()
        T[:3, 3] = v[:3]
        lines.append(f"{stamp} {' '.join(f'{x:.9f}' for x in row(T))}\n")
    (folder / "poses.txt").write_text("".join(lines))


def _world_to_camera(T: np.ndarray) -> np.ndarray:
    inv = np.linalg.inv(T)
    return np.r_[inv[:3, 3], Rotation.from_matrix(inv[:3, :3]).as_quat()]


def _wxyz(T: np.ndarray) -> np.ndarray:
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    return np.r_[T[:3, 3], w, x, y, z]


def _set_field(folder: Path, name: str, value: object) -> None:
    path = folder / "intrinsics.json"
    data = json.loads(path.read_text())
    data[name] = value
    path.write_text(json.dumps(data))


CASES = {
    "poses world-to-camera": (
        lambda folder: _rewrite_poses(folder, _world_to_camera),
        "--pose-convention world-to-camera",
        {"pose_convention": "world-to-camera"},
    ),
    "quaternions w x y z": (
        lambda folder: _rewrite_poses(folder, _wxyz),
        "--quaternion-order wxyz",
        {"quaternion_order": "wxyz"},
    ),
    "depth_scale 1 (millimetres read as metres)": (
        lambda folder: _set_field(folder, "depth_scale", 1.0),
        "--depth-scale 1000",
        {"depth_scale": 1000.0},
    ),
    "depth_scale 1e6": (
        lambda folder: _set_field(folder, "depth_scale", 1e6),
        "--depth-scale 1000",
        {"depth_scale": 1000.0},
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_a_generic_folder_in_another_convention_is_refused_and_the_named_option_fixes_it(
    tmp_path, livingroom40, reference, case: str
) -> None:
    make, named, fix = CASES[case]
    folder = layouts.generic(tmp_path / "generic", livingroom40)
    make(folder)
    line = _build(folder, tmp_path / "bad")
    assert line is not None
    assert "\n" not in line
    assert line.startswith(str(folder))
    assert named in line, line
    assert _build(folder, tmp_path / "fixed", **fix) is None
    cells = _cells(tmp_path / "fixed")
    assert len(cells ^ reference) <= 0.01 * len(reference)


@pytest.mark.slow
def test_tum_depth_under_a_millimetre_camera_file_is_a_depth_scale_mistake(
    tmp_path, livingroom40, reference
) -> None:
    folder = layouts.tum(tmp_path / "rgbd_dataset_fr3_livingroom", livingroom40)
    K = livingroom40[0].K
    camera = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "depth_scale": 1000}
    (folder / "intrinsics.json").write_text(json.dumps(camera))
    line = _build(folder, tmp_path / "bad")
    assert line is not None
    assert "depth reads 5 times too large" in line
    assert "--depth-scale 5000" in line
    assert _build(folder, tmp_path / "fixed", depth_scale=5000.0) is None
    assert len(_cells(tmp_path / "fixed") ^ reference) <= 0.01 * len(reference)
