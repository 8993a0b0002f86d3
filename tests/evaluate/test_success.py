"""Success criteria against brute force: point IoU with Python sets, distances by hand."""

from __future__ import annotations

import dataclasses

import numpy as np

from care_maps.evaluate.success import grid_queries, grid_success, instance_iou, instance_queries
from care_maps.query import load_map
from care_maps.truth.formats.native import read_native
from care_maps.truth.model import GroundTruth


def test_instance_iou_matches_set_arithmetic(dataset) -> None:
    gt = read_native(dataset / "scene_0.mcap")
    cmap = load_map(dataset / "stores" / "scene_0", "instances")
    labels = gt.label_points(gt.points)
    np.testing.assert_array_equal(labels, gt.point_instance)
    ids = np.array([6, 1, 4, 2])
    iou = instance_iou(cmap, labels, ids)
    for c in range(cmap.num_candidates):
        pred = set(cmap.mask(c).tolist())
        for j, g in enumerate(ids):
            truth = set(np.flatnonzero(labels == g).tolist())
            assert np.isclose(iou[c, j], len(pred & truth) / len(pred | truth))
    assert np.isclose(iou[6, 1], 0.2)  # the half mask misses object 1
    assert np.isclose(iou[7, 2], 0.5)  # the mixed mask matches objects 4 and 6


def test_grid_success_is_floor_distance() -> None:
    rng = np.random.default_rng(0)
    cells, objects = rng.uniform(0, 5, (50, 2)), rng.uniform(0, 5, (7, 2))
    brute = np.linalg.norm(cells[:, None] - objects[None], axis=-1).min(1) <= 1.0
    np.testing.assert_array_equal(grid_success(cells, objects, 1.0), brute)
    assert not grid_success(cells, np.zeros((0, 2)), 1.0).any()


def test_query_sets_room_by_room_and_protocols(dataset) -> None:
    gt = read_native(dataset / "scene_0.mcap")
    cmap = load_map(dataset / "stores" / "scene_0", "instances")
    labels = gt.label_points(gt.points)
    sets = instance_queries(cmap, gt, labels, protocol="instance")
    assert [s.unit for s in sets] == ["living", "bedroom"]
    living = sets[0]
    assert living.queries == ("chair#1", "chair#2", "table#3")
    np.testing.assert_array_equal(living.candidate_ids, [0, 1, 2, 6])  # centres with x < 5
    # chair#1 succeeds only on its own mask (the half mask has IoU 0.2)
    np.testing.assert_array_equal(living.success[0], [True, False, False, False])
    by_class = instance_queries(cmap, gt, labels, protocol="class", rooms=False)
    assert len(by_class) == 1
    scene = by_class[0]
    assert scene.queries == ("chair", "table", "sofa", "lamp")
    np.testing.assert_array_equal(np.flatnonzero(scene.success[0]), [0, 1, 4])
    np.testing.assert_array_equal(np.flatnonzero(scene.success[2]), [3, 7])
    grid = load_map(dataset / "stores" / "scene_0", "grid")
    gsets = grid_queries(grid, gt, radius=1.0)
    bedroom = gsets[1]
    assert bedroom.queries == ("chair", "sofa", "lamp")
    xy = bedroom.cmap.positions[:, :2]
    obj = gt.points[gt.point_instance == 5, :2]
    expected = np.linalg.norm(xy[:, None] - obj[None], axis=-1).min(1) <= 1.0
    np.testing.assert_array_equal(bedroom.success[0], expected)


def test_rooms_of_one_type_are_separate_units(dataset) -> None:
    """Two kitchens in one scene are two units: grouped by name they would merge their
    queries (and a failure in one would be hidden by a success in the other)."""
    gt = read_native(dataset / "scene_0.mcap")
    twins = GroundTruth(
        gt.class_names, gt.instances,
        [dataclasses.replace(r, name="kitchen") for r in gt.rooms], gt.points, gt.point_instance,
    )  # fmt: skip
    cmap = load_map(dataset / "stores" / "scene_0", "instances")
    sets = instance_queries(cmap, twins, gt.label_points(gt.points), protocol="class")
    assert [s.unit for s in sets] == ["kitchen #0", "kitchen #1"]
    grid = load_map(dataset / "stores" / "scene_0", "grid")
    assert [s.unit for s in grid_queries(grid, twins, radius=1.0)] == ["kitchen #0", "kitchen #1"]
