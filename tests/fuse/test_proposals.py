"""Geometric proposals on a sampled room, and the proposal IoU against a hand count."""

from __future__ import annotations

import numpy as np

from care_maps.fuse.evaluate_proposals import best_iou, proposal_iou
from care_maps.fuse.instances import InstanceConfig
from care_maps.fuse.pointcloud import SceneCloud
from care_maps.fuse.proposals import PROPOSERS, geometric_proposals, remove_structure

STEP = 0.03


def _face_grid(lo: np.ndarray, hi: np.ndarray, axis: int, value: float) -> np.ndarray:
    """Points every STEP on the axis-aligned rectangle [lo, hi] with coordinate ``axis`` = value."""
    others = [a for a in range(3) if a != axis]
    g = [np.arange(lo[a], hi[a] + 1e-9, STEP) for a in others]
    a, b = np.meshgrid(*g, indexing="ij")
    pts = np.zeros((a.size, 3))
    pts[:, others[0]], pts[:, others[1]], pts[:, axis] = a.ravel(), b.ravel(), value
    return pts


def _box_surface(lo: tuple[float, ...], hi: tuple[float, ...]) -> np.ndarray:
    """The visible faces of a box standing on the floor (no bottom face)."""
    lo_a, hi_a = np.array(lo), np.array(hi)
    faces = [_face_grid(lo_a, hi_a, 2, hi_a[2])]
    for axis in (0, 1):
        faces += [
            _face_grid(lo_a, hi_a, axis, lo_a[axis]),
            _face_grid(lo_a, hi_a, axis, hi_a[axis]),
        ]
    return np.concatenate(faces)


BOXES = [
    ((0.3, 0.3, 0.0), (0.8, 0.9, 0.6)),
    ((-1.0, 0.2, 0.0), (-0.4, 0.7, 0.9)),
    ((0.1, -1.1, 0.0), (1.4, -0.5, 0.75)),  # a table-height top: horizontal, must stay
    ((-1.45, -1.2, 0.0), (-1.1, -0.6, 1.0)),  # against a wall
]


def _room(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.array([-1.5, -1.5, 0.0]), np.array([1.5, 1.5, 2.4])
    parts = [_face_grid(lo, hi, 2, 0.0), _face_grid(lo, hi, 2, 2.4)]
    for axis in (0, 1):
        parts += [_face_grid(lo, hi, axis, lo[axis]), _face_grid(lo, hi, axis, hi[axis])]
    labels = [np.zeros(sum(len(p) for p in parts), np.int64)]
    for i, (blo, bhi) in enumerate(BOXES):
        surf = _box_surface(blo, bhi)
        parts.append(surf)
        labels.append(np.full(len(surf), i + 1))
    pts = np.concatenate(parts) + rng.normal(0, 0.003, (sum(len(p) for p in parts), 3))
    return pts.astype(np.float32), np.concatenate(labels)


class _Labeller:
    def __init__(self, labels: np.ndarray) -> None:
        self.labels = labels

    def label_points(self, points: np.ndarray, max_dist: float = 0.05) -> np.ndarray:
        return self.labels


CONFIG = InstanceConfig(voxel_size=STEP, plane_min_points=200)


def test_structure_removal_keeps_objects_and_table_tops() -> None:
    pts, labels = _room(np.random.default_rng(0))
    removed = remove_structure(pts.astype(np.float64), CONFIG)
    assert removed[labels == 0].mean() > 0.9  # floor, ceiling, walls
    assert removed[labels > 0].mean() < 0.05  # objects, including the table top at 0.75 m


def test_geometric_proposals_match_the_boxes() -> None:
    pts, labels = _room(np.random.default_rng(1))
    cloud = SceneCloud(pts, np.zeros_like(pts, dtype=np.uint8))
    props = geometric_proposals(cloud, None, CONFIG)
    assert PROPOSERS["geometric"] is geometric_proposals
    ids, iou = proposal_iou(pts, props.masks, _Labeller(labels))
    assert ids.tolist() == [1, 2, 3, 4]
    assert iou.min() > 0.5, iou
    assert iou.mean() > 0.8, iou
    assert (props.source_ids == -1).all()


def test_best_iou_hand_count() -> None:
    labels = np.array([0, 1, 1, 1, 2, 2, 0, 0])
    masks = [np.array([1, 2]), np.array([2, 3, 4, 5]), np.array([6])]
    ids, iou, best = best_iou(masks, labels)
    # GT 1 = {1,2,3}: mask 0 -> 2/3, mask 1 -> 2/5; GT 2 = {4,5}: mask 1 -> 2/4
    assert ids.tolist() == [1, 2]
    np.testing.assert_allclose(iou, [2 / 3, 0.5])
    assert best.tolist() == [0, 1]
    ids, iou, best = best_iou([], labels)
    assert iou.tolist() == [0.0, 0.0]
    assert best.tolist() == [-1, -1]


def test_clusters_longer_than_the_extent_limit_are_dropped() -> None:
    """Box extents by hand: 0.6, 0.9, 1.3 and 1.0 m; a 0.95 m limit keeps the first two."""
    import dataclasses

    pts, labels = _room(np.random.default_rng(2))
    cloud = SceneCloud(pts, np.zeros_like(pts, dtype=np.uint8))
    props = geometric_proposals(cloud, None, dataclasses.replace(CONFIG, max_instance_extent=0.95))
    kept = sorted(int(np.bincount(labels[m]).argmax()) for m in props.masks)
    assert kept == [1, 2]
