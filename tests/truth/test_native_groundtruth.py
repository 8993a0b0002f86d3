"""GroundTruth: file round trip, nearest-point labelling and rooms, against independent references."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.path import Path as MplPath

from care_maps.core.errors import WorldError
from care_maps.truth.formats.native import gt_paths, read_native, write_native
from care_maps.truth.model import GroundTruth, Room, instances_table


def _gt() -> GroundTruth:
    rng = np.random.default_rng(0)
    points = rng.uniform(0, 4, (500, 3)).astype(np.float32)
    rows = [
        {"instance_id": 1, "class_name": "chair", "class_id": 4, "room_id": 0,
         "bbox_min": [0, 0, 0], "bbox_max": [1, 1, 1]},
        {"instance_id": 2, "class_name": "table", "class_id": 5, "room_id": 1,
         "bbox_min": [2, 0, 0], "bbox_max": [3, 1, 1]},
    ]  # fmt: skip
    rooms = [
        Room(0, "kitchen", np.array([[0, 0], [2, 0], [2, 3], [0, 3]], float)),
        # an L-shaped room, so the test is not only about rectangles
        Room(1, "hall", np.array([[2, 0], [5, 0], [5, 1], [3, 1], [3, 3], [2, 3]], float)),
    ]
    return GroundTruth(
        class_names=("void", "wall", "floor", "ceiling", "chair", "table"),
        instances=instances_table(rows),
        rooms=rooms,
        points=points,
        point_instance=rng.integers(0, 3, 500).astype(np.int32),
        info={"seed": 3},
    )


def test_save_load_round_trip_beside_recording(tmp_path: Path) -> None:
    gt = _gt()
    rec = tmp_path / "scene_000.mcap"
    write_native(gt, rec)
    assert [p.name for p in gt_paths(rec)] == ["scene_000.gt.parquet", "scene_000.gt.json"]
    back = read_native(rec)
    assert back.class_names == gt.class_names
    assert back.instances.equals(gt.instances.cast(back.instances.schema))
    np.testing.assert_array_equal(back.points, gt.points)
    np.testing.assert_array_equal(back.point_instance, gt.point_instance)
    np.testing.assert_allclose(back.rooms[1].floor_polygon, gt.rooms[1].floor_polygon)
    assert back.info == {"seed": 3}
    # a rosbag2 directory takes its own name as the stem
    assert gt_paths(tmp_path / "scene_001")[1].name == "scene_001.gt.json"


def test_load_missing_is_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(WorldError, match=r"no ground truth beside it"):
        read_native(tmp_path / "nothing.mcap")


def test_label_points_matches_brute_force_nearest_neighbour() -> None:
    gt = _gt()
    rng = np.random.default_rng(1)
    queries = rng.uniform(-0.5, 4.5, (300, 3))
    d = np.linalg.norm(queries[:, None, :] - gt.points[None].astype(np.float64), axis=-1)
    nearest = d.argmin(axis=1)
    expected = np.where(d.min(axis=1) <= 0.3, gt.point_instance[nearest], 0)
    np.testing.assert_array_equal(gt.label_points(queries, max_dist=0.3), expected)
    assert gt.label_points(np.zeros((0, 3))).shape == (0,)


def test_room_of_matches_matplotlib_point_in_polygon() -> None:
    gt = _gt()
    rng = np.random.default_rng(2)
    xy = rng.uniform(-1, 6, (2000, 2))
    expected = np.full(len(xy), -1)
    for room in reversed(gt.rooms):
        expected[MplPath(room.floor_polygon).contains_points(xy)] = room.room_id
    got = gt.room_of(xy)
    # points exactly on an edge are a matter of convention; random points never are
    np.testing.assert_array_equal(got, expected)
    assert gt.room_of(np.array([[2.5, 2.5], [4.0, 2.0], [1.0, 1.0]])).tolist() == [1, -1, 0]
