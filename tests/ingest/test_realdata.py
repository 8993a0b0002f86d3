"""Real RGB-D data through every container format: poses, intrinsics and geometry survive."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from care_maps.core.store import Store
from care_maps.geometry.transforms import backproject, transform_points
from care_maps.ingest.pipeline import run_ingest
from care_maps.ingest.write import write_recording
from care_maps.runtime.execution import Execution
from tests.support.frames import load_livingroom, load_slambook

FORMATS = [
    ("mcap", "rec.mcap", "sqlite3"),
    ("ros2", "rec_sqlite3", "sqlite3"),
    ("ros2", "rec_mcap", "mcap"),
    ("ros1", "rec.bag", "sqlite3"),
]
LIVINGROOM_FRAMES = 20


@pytest.fixture(scope="module")
def livingroom(livingroom_root: Path) -> list:
    return load_livingroom(livingroom_root, LIVINGROOM_FRAMES)


def _ingest(tmp_path: Path, frames: list, fmt: str, name: str, storage: str) -> Store:
    rec = write_recording(tmp_path / name, frames, fmt=fmt, ros2_storage=storage)
    return Store(run_ingest(rec, tmp_path / "store", run=Execution(progress=False)))


def _world_points(frame_depth: np.ndarray, K: np.ndarray, pose: np.ndarray) -> np.ndarray:
    points, _ = backproject(frame_depth, K, stride=4)
    return transform_points(pose, points)


@pytest.mark.parametrize(("fmt", "name", "storage"), FORMATS)
def test_livingroom_round_trip(
    tmp_path: Path, livingroom: list, fmt: str, name: str, storage: str
) -> None:
    store = _ingest(tmp_path, livingroom, fmt, name, storage)
    assert store.num_views == LIVINGROOM_FRAMES
    np.testing.assert_allclose(
        store.poses(), np.stack([f.cam_to_world for f in livingroom]), atol=1e-6
    )
    K = np.array(
        [[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]]
    )  # camera_intrinsic.json
    np.testing.assert_allclose(
        store.intrinsics(), np.broadcast_to(K, (LIVINGROOM_FRAMES, 3, 3)), atol=1e-6
    )
    views = dict(store.iter_frames(extras=False))
    for k in (0, LIVINGROOM_FRAMES - 1):
        np.testing.assert_allclose(views[k].depth_m, livingroom[k].depth_m, atol=1e-6)  # mm exact


def test_livingroom_depth_lands_on_the_same_surface(tmp_path: Path, livingroom: list) -> None:
    """Frames 0 and 15 back-projected with the recovered poses overlap within 2 cm (median)."""
    store = _ingest(tmp_path, livingroom, "ros1", "rec.bag", "sqlite3")
    views = dict(store.iter_frames(extras=False))
    a = _world_points(views[0].depth_m, views[0].K, views[0].cam_to_world)
    b = _world_points(views[15].depth_m, views[15].K, views[15].cam_to_world)
    dist, _ = cKDTree(a).query(b)
    assert np.median(dist) < 0.02
    # The same check with a wrong convention (world-to-camera) fails: the test has teeth.
    wrong = _world_points(views[15].depth_m, views[15].K, np.linalg.inv(views[15].cam_to_world))
    assert np.median(cKDTree(a).query(wrong)[0]) > 0.02


@pytest.mark.parametrize(("fmt", "name", "storage"), FORMATS)
def test_slambook_round_trip(
    tmp_path: Path, slambook_root: Path, fmt: str, name: str, storage: str
) -> None:
    frames = load_slambook(slambook_root)
    store = _ingest(tmp_path, frames, fmt, name, storage)
    assert store.num_views == 5
    np.testing.assert_allclose(store.poses(), np.stack([f.cam_to_world for f in frames]), atol=1e-6)
    K = np.array([[518.0, 0.0, 325.5], [0.0, 519.0, 253.5], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(store.intrinsics(), np.broadcast_to(K, (5, 3, 3)), atol=1e-6)
