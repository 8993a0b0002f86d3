"""How well proposals match ground-truth instances: best IoU over scene points per GT instance."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Protocol

import numpy as np

from care_maps.core.errors import FuseError
from care_maps.core.store import Store, read_table, source_recording
from care_maps.truth.model import LABEL_DISTANCE

__all__ = ["PointLabeller", "best_iou", "instance_map_iou", "proposal_iou"]


class PointLabeller(Protocol):
    """Anything that labels points with ground-truth instance ids (``care_maps.truth.model.GroundTruth``)."""

    def label_points(self, points: np.ndarray, max_dist: float = LABEL_DISTANCE) -> np.ndarray: ...


def best_iou(
    masks: Sequence[np.ndarray], point_labels: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per ground-truth instance, the best IoU of any mask and that mask's index.

    Args:
        masks: M arrays of point indices.
        point_labels: (N,) ground-truth instance id of each scene point, 0 = none.

    Returns:
        ``(gt_ids (G,), iou (G,), best_mask (G,))`` over the ids > 0 present in
        ``point_labels``; best_mask is -1 where no mask overlaps.
    """
    labels = np.asarray(point_labels, np.int64)
    gt_ids, gt_index = np.unique(labels, return_inverse=True)
    gt_sizes = np.bincount(gt_index, minlength=len(gt_ids))
    M, G = len(masks), len(gt_ids)
    lengths = np.array([len(m) for m in masks], np.int64)
    flat = np.concatenate([np.asarray(m, np.int64) for m in masks]) if M else np.zeros(0, np.int64)
    owner = np.repeat(np.arange(M), lengths)
    inter = np.bincount(owner * G + gt_index[flat], minlength=M * G).reshape(M, G)
    union = lengths[:, None] + gt_sizes[None, :] - inter
    iou = np.where(union > 0, inter / np.maximum(union, 1), 0.0)
    real = gt_ids > 0
    if M == 0:
        return gt_ids[real], np.zeros(int(real.sum())), np.full(int(real.sum()), -1)
    best = iou.argmax(axis=0)
    best_val = iou[best, np.arange(G)]
    best = np.where(best_val > 0, best, -1)
    return gt_ids[real], best_val[real], best[real]


def proposal_iou(
    points: np.ndarray,
    masks: Sequence[np.ndarray],
    gt: PointLabeller,
    *,
    max_dist: float = LABEL_DISTANCE,
) -> tuple[np.ndarray, np.ndarray]:
    """``(gt_ids, best IoU)`` of each ground-truth instance against the masks.

    Scene points are labelled by ``gt.label_points`` (nearest ground-truth surface point
    within ``max_dist``), so a ground-truth instance is measured only where the scene cloud
    has points; its mean over instances is the proposals' quality figure.
    """
    ids, iou, _ = best_iou(masks, gt.label_points(np.asarray(points), max_dist))
    return ids, iou


def instance_map_iou(
    store_path: Path, recording: Path | None = None, *, max_dist: float = LABEL_DISTANCE
) -> tuple[np.ndarray, np.ndarray]:
    """``(gt_ids, best IoU)`` of the store's instance map against the recording's ground truth.

    ``recording`` defaults to the source path ingest recorded in the store's meta; its
    ground truth (``<stem>.gt.parquet``/``.json``, sample-world recordings only) is loaded
    with :func:`care_maps.truth.formats.native.read_native`.
    """
    from care_maps.fuse.instances import INSTANCES_TABLE, SCENE_POINTS_TABLE
    from care_maps.fuse.pointcloud import read_scene_points
    from care_maps.truth.formats.native import read_native

    store = Store(store_path)
    if recording is None:
        source = source_recording(store.path, store.meta)
        if source is None:
            msg = f"{store.path}: meta.json names no source recording; pass the recording path"
            raise FuseError(msg)
        recording = Path(source)
    cloud = read_scene_points(store.table_path(SCENE_POINTS_TABLE))
    table = read_table(store.table_path(INSTANCES_TABLE), ["point_indices"])
    masks = [np.asarray(m, np.int64) for m in table.column("point_indices").to_pylist()]
    return proposal_iou(cloud.points, masks, read_native(recording), max_dist=max_dist)
