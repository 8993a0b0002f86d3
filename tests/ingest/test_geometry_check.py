"""The consistency check of every ingest, end to end: the third-party living-room frames
written by the real writers with one convention wrong each (another camera's focal length in
the camera info, a body-axes camera frame named as optical, depth in TUM's 5000 per metre
read as millimetres) are refused in one line naming the option, and that option gives the
map of the right recording; right recordings pass and record their figures; a camera that
stands still is not judged and proceeds; ``--accept-geometry`` keeps what it is given."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from care_maps.core.errors import IngestError
from care_maps.core.store import read_table
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.geometry.transforms import BODY_FROM_OPTICAL
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.source import ReadOptions
from care_maps.ingest.write import write_recording
from care_maps.runtime.execution import Execution
from tests.support.encoders import TinyEncoder
from tests.support.frames import load_livingroom

CELL = 0.05
QUIET = Execution(progress=False)


@pytest.fixture(scope="module")
def frames(livingroom_root) -> list:
    return load_livingroom(livingroom_root, 120)[::3]


def _cells(store: Path) -> set[tuple[int, int]]:
    table = read_table(store / "cells.parquet", ["ix", "iy"])
    return set(zip(table.column("ix").to_pylist(), table.column("iy").to_pylist(), strict=True))


def _ingest_and_grid(source: Path, out: Path, **read: object) -> str | None:
    """The store and its grid from ``source`` read with ``read`` options; the one-line error
    instead where ingest refuses (and then nothing is written at ``out``)."""
    config = IngestConfig(read=ReadOptions(**read), vocabulary="red,green,blue")
    try:
        run_ingest(source, out, config, run=QUIET, encoder=TinyEncoder())
    except IngestError as err:
        assert not out.exists()  # nothing half-written
        return str(err)
    build_grid(out, GridConfig(cell_size=CELL, stride=2), run=QUIET)
    return None


@pytest.fixture(scope="module")
def reference(tmp_path_factory, frames) -> tuple[Path, set]:
    """The right recording's store and grid (built once)."""
    root = tmp_path_factory.mktemp("reference")
    bag = write_recording(root / "right.mcap", frames, fmt="mcap")
    assert _ingest_and_grid(bag, root / "store") is None
    return root / "store", _cells(root / "store")


def _same_map(store: Path, reference: set) -> None:
    cells = _cells(store)
    assert len(cells ^ reference) <= 0.01 * len(reference), (len(cells ^ reference), len(reference))


def test_a_right_recording_passes_and_records_its_figures(reference) -> None:
    store, _ = reference
    geometry = json.loads((store / "meta.json").read_text())["geometry"]
    assert geometry["status"] == "agree"
    assert geometry["agree"] >= 0.9
    assert geometry["pairs_judged"] >= 8
    assert 1.0 < geometry["median_range_m"] < 3.0


@pytest.mark.slow
def test_another_cameras_focal_length_is_refused_and_intrinsics_fix_it(
    tmp_path, frames, reference
) -> None:
    wrong = []
    for f in frames:
        K = f.K.copy()
        K[0, 0] *= 2.0
        K[1, 1] *= 2.0
        wrong.append(replace(f, K=K))
    bag = write_recording(tmp_path / "focal.mcap", wrong, fmt="mcap")
    line = _ingest_and_grid(bag, tmp_path / "bad")
    assert line is not None
    assert "\n" not in line
    assert "focal length" in line
    fix = line.split("--intrinsics ")[1].split()[0]
    fx, _, cx, cy = (float(v) for v in fix.split(","))
    assert fx == pytest.approx(525.0, rel=0.03)  # within the search's resolution
    assert (cx, cy) == (319.5, 239.5)
    # the camera as it really is gives the right map
    assert _ingest_and_grid(bag, tmp_path / "fixed", intrinsics="525,525,319.5,239.5") is None
    _same_map(tmp_path / "fixed", reference[1])


@pytest.mark.slow
def test_a_body_frame_named_as_optical_is_refused_and_camera_convention_fixes_it(
    tmp_path, frames, reference
) -> None:
    # the camera frame's poses are a body's (x forward, y left, z up) under an optical name
    body = [
        replace(f, cam_to_world=f.cam_to_world @ np.linalg.inv(BODY_FROM_OPTICAL)) for f in frames
    ]
    bag = write_recording(tmp_path / "body.mcap", body, fmt="mcap")
    line = _ingest_and_grid(bag, tmp_path / "bad")
    assert line is not None
    assert "--camera-convention body" in line
    assert _ingest_and_grid(bag, tmp_path / "fixed", camera_convention="body") is None
    _same_map(tmp_path / "fixed", reference[1])


@pytest.mark.slow
def test_depth_in_other_units_is_refused_as_such_not_as_a_floor_problem(
    tmp_path, frames, reference
) -> None:
    # 16-bit depth at TUM's 5000 per metre, read as the ROS millimetres: five times too far
    tum_units = [replace(f, depth_m=f.depth_m * 5.0) for f in frames]
    bag = write_recording(tmp_path / "depth.mcap", tum_units, fmt="mcap")
    line = _ingest_and_grid(bag, tmp_path / "bad")
    assert line is not None
    assert "depth reads 5 times too large" in line
    assert "--depth-scale with the depth value of one metre (5000 for 16-bit images" in line
    assert _ingest_and_grid(bag, tmp_path / "fixed", depth_scale=5000.0) is None
    _same_map(tmp_path / "fixed", reference[1])


@pytest.mark.slow
def test_accept_geometry_keeps_it_and_says_so(tmp_path, frames, run_cli) -> None:
    body = [
        replace(f, cam_to_world=f.cam_to_world @ np.linalg.inv(BODY_FROM_OPTICAL)) for f in frames
    ]
    bag = write_recording(tmp_path / "body.mcap", body, fmt="mcap")
    code, out, err = run_cli("ingest", bag, "--out", tmp_path / "kept", "--accept-geometry")
    assert code == 0, err
    geometry = json.loads((tmp_path / "kept" / "meta.json").read_text())["geometry"]
    assert geometry["status"] == "mistake"
    assert geometry["accepted"] is True
    assert "kept as given" in out
    code, out, _ = run_cli("check", tmp_path / "kept")
    assert code == 0
    assert "geometry inconsistent as read" in out
    # care topics judges the first views before any encoding, and says what ingest would do
    code, out, _ = run_cli("topics", bag)
    assert code == 0
    assert "ingest would refuse" in out
    assert "--camera-convention body" in out


def test_a_camera_that_stands_still_is_not_judged_and_proceeds(tmp_path, frames, run_cli) -> None:
    still = [replace(f, cam_to_world=frames[0].cam_to_world) for f in frames[:8]]
    bag = write_recording(tmp_path / "still.mcap", still, fmt="mcap")
    code, out, err = run_cli("ingest", bag, "--out", tmp_path / "still")
    assert code == 0, err
    assert "geometry not judged" in out
    geometry = json.loads((tmp_path / "still" / "meta.json").read_text())["geometry"]
    assert geometry["status"] == "unjudged"
