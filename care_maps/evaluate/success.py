"""Success of a chosen candidate against ground truth, as ``docs/method.md`` defines it.

- Instances: point IoU between the retrieved mask and a ground-truth mask, both over the map's
  scene points (ground-truth labels of scene points come from
  :meth:`care_maps.truth.model.GroundTruth.label_points`), success when IoU > 0.25.
- Box-only ground truth (annotation files): the GT mask of an instance is the scene points
  inside its box (:meth:`care_maps.truth.model.GroundTruth.label_points`), so the same point IoU applies.
- Grid: floor-plane distance from the chosen cell centre to the nearest ground-truth surface
  point (or box footprint, for box-only instances) of an object of the target class, success
  when <= 1 m.

Both produce a (Q, N) success matrix per map unit (a room, or the whole scene) for the
queries of one protocol, so strategies can be scored as array operations.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from care_maps.core.errors import EvalError
from care_maps.evaluate.config import IOU_THRESHOLD, QueryProtocol
from care_maps.evaluate.groundtruth import scene_points
from care_maps.query.map import CandidateMap
from care_maps.truth.model import LABEL_DISTANCE, GroundTruth

__all__ = [
    "PROTOCOLS",
    "QuerySet",
    "grid_queries",
    "grid_success",
    "instance_iou",
    "instance_queries",
    "scene_point_labels",
]

PROTOCOLS = tuple(QueryProtocol)
"""The query protocols (:class:`care_maps.evaluate.config.QueryProtocol` documents each)."""


@dataclass(frozen=True, eq=False)
class QuerySet:
    """Q queries over the candidates of one map unit, with their success matrix."""

    unit: str
    """Room name (room-by-room evaluation) or ``scene``."""
    cmap: CandidateMap
    """The unit's candidates (a subset of the scene's map, renumbered)."""
    candidate_ids: np.ndarray
    """(N,) ids of the unit's candidates in the scene's map."""
    queries: tuple[str, ...]
    """Query label: ``class#instance_id`` (instance protocol) or the class name."""
    targets: tuple[str, ...]
    """Target class name of each query (the query text)."""
    class_ids: np.ndarray
    """(Q,) vocabulary id of each target."""
    success: np.ndarray
    """(Q, N) bool: choosing candidate c succeeds for query q."""


def scene_point_labels(
    store: Path, gt: GroundTruth, max_dist: float = LABEL_DISTANCE
) -> np.ndarray:
    """(P,) ground-truth instance id of each point of the store's ``scene_points.parquet``
    (0 = structure or nothing within ``max_dist``)."""
    return gt.label_points(scene_points(Path(store)), max_dist=max_dist)


def _gt_column(gt_ids: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Column of each label in ``gt_ids`` (-1 where the label is not one of them)."""
    if len(gt_ids) == 0:
        return np.full(len(labels), -1, np.int64)
    order = np.argsort(gt_ids, kind="stable")
    pos = np.clip(np.searchsorted(gt_ids[order], labels), 0, len(gt_ids) - 1)
    return np.where(gt_ids[order][pos] == labels, order[pos], -1)


def instance_iou(cmap: CandidateMap, labels: np.ndarray, gt_ids: np.ndarray) -> np.ndarray:
    """(N, G) point IoU of each retrieved mask with each GT instance mask.

    ``labels`` (P,) gives the GT instance of every scene point; the GT mask of instance g is
    the scene points labelled g. One bincount over (candidate, instance) pairs.
    """
    gt_ids = np.asarray(gt_ids, dtype=np.int64)
    labels = np.asarray(labels, dtype=np.int64)
    n_cand, n_gt = cmap.num_candidates, len(gt_ids)
    lengths = np.diff(cmap.point_offsets)
    owner = np.repeat(np.arange(n_cand), lengths)
    col = _gt_column(gt_ids, labels[cmap.point_indices])
    hit = col >= 0
    inter = np.bincount(owner[hit] * n_gt + col[hit], minlength=n_cand * n_gt)
    inter = inter.reshape(n_cand, n_gt)
    scene_col = _gt_column(gt_ids, labels)
    gt_size = np.bincount(scene_col[scene_col >= 0], minlength=n_gt)
    union = lengths[:, None] + gt_size[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1), 0.0)


def grid_success(cell_xy: np.ndarray, object_xy: np.ndarray, radius: float) -> np.ndarray:
    """(N,) bool: each cell centre lies within ``radius`` (floor plane) of an object point."""
    if len(object_xy) == 0 or len(cell_xy) == 0:
        return np.zeros(len(cell_xy), bool)
    dist, _ = cKDTree(np.asarray(object_xy, np.float64)).query(
        np.asarray(cell_xy, np.float64), k=1, distance_upper_bound=radius * (1 + 1e-9)
    )
    return dist <= radius


def _units(
    cmap: CandidateMap, gt: GroundTruth, rooms: bool
) -> list[tuple[str, int | None, np.ndarray]]:
    """(name, room id or None, candidate mask) of each map unit."""
    if not rooms or not gt.rooms:
        return [("scene", None, np.ones(cmap.num_candidates, bool))]
    room_of = gt.room_of(cmap.positions) if cmap.num_candidates else np.zeros(0, int)
    return [
        (name, r.room_id, room_of == r.room_id)
        for name, r in zip(_unit_names(gt), gt.rooms, strict=True)
    ]


def _unit_names(gt: GroundTruth) -> list[str]:
    """A unique name per room: its type, with its id where two rooms share a type (a scene
    with two kitchens), since results are grouped by (scene, unit, query)."""
    names = [r.name or f"room{r.room_id}" for r in gt.rooms]
    return [
        f"{n} #{r.room_id}" if names.count(n) > 1 else n
        for n, r in zip(names, gt.rooms, strict=True)
    ]


def _gt_instances(
    gt: GroundTruth, cmap: CandidateMap
) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """(instance ids, rooms, class names, vocabulary ids) of GT instances whose class the map
    knows and that the recording saw (``info['unseen_instances']`` are left out)."""
    table = gt.instances
    ids = table.column("instance_id").to_numpy().astype(np.int64)
    room = table.column("room_id").to_numpy().astype(np.int64)
    names = table.column("class_name").to_pylist()
    unseen = set(gt.info.get("unseen_instances", []) or [])
    lookup = {n.strip().lower(): i for i, n in reversed(list(enumerate(cmap.vocabulary)))}
    vocab = np.array([lookup.get(n.strip().lower(), -1) for n in names], dtype=np.int64)
    keep = (vocab >= 0) & ~np.isin(ids, list(unseen))
    return ids[keep], room[keep], [n for n, k in zip(names, keep, strict=True) if k], vocab[keep]


def instance_queries(
    cmap: CandidateMap,
    gt: GroundTruth,
    labels: np.ndarray,
    *,
    protocol: QueryProtocol = QueryProtocol.INSTANCE,
    rooms: bool = True,
    iou_threshold: float = IOU_THRESHOLD,
) -> list[QuerySet]:
    """Query sets of the instance map, per room where the GT has rooms (and ``rooms``)."""
    if protocol not in PROTOCOLS:
        msg = f"unknown query protocol {protocol!r}; choose one of {', '.join(PROTOCOLS)}"
        raise EvalError(msg)
    ids, room, names, vocab = _gt_instances(gt, cmap)
    visible = np.isin(ids, labels[labels > 0])  # a GT mask with no scene point cannot match
    ids, room, vocab = ids[visible], room[visible], vocab[visible]
    names = [n for n, v in zip(names, visible, strict=True) if v]
    ok = instance_iou(cmap, labels, ids) > iou_threshold  # (N_all, G)
    out = []
    for unit, room_id, keep in _units(cmap, gt, rooms):
        sub, cand_ids = cmap.subset(keep)
        here = np.ones(len(ids), bool) if room_id is None else room == room_id
        if protocol == "instance":
            cols = np.flatnonzero(here)
            queries = tuple(f"{names[g]}#{ids[g]}" for g in cols)
            targets = tuple(names[g] for g in cols)
            class_ids = vocab[cols]
            success = ok[cand_ids][:, cols].T
        else:
            class_ids = np.unique(vocab[here])
            targets = tuple(cmap.vocabulary[y] for y in class_ids)
            queries = targets
            success = (
                np.stack([ok[cand_ids][:, here & (vocab == y)].any(axis=1) for y in class_ids])
                if len(class_ids)
                else np.zeros((0, len(cand_ids)), bool)
            )
        if len(queries):
            out.append(QuerySet(unit, sub, cand_ids, queries, targets, class_ids, success))
    return out


def grid_queries(
    cmap: CandidateMap,
    gt: GroundTruth,
    *,
    rooms: bool = True,
    radius: float = 1.0,
) -> list[QuerySet]:
    """Query sets of the grid map: one query per class present (per room where rooms exist)."""
    ids, room, _names, vocab = _gt_instances(gt, cmap)
    out = []
    for unit, room_id, keep in _units(cmap, gt, rooms):
        sub, cand_ids = cmap.subset(keep)
        here = np.ones(len(ids), bool) if room_id is None else room == room_id
        class_ids = np.unique(vocab[here])
        rows = []
        for y in class_ids:
            objects = ids[here & (vocab == y)]
            rows.append(gt.floor_distance(sub.positions[:, :2], objects) <= radius)
        if len(class_ids):
            targets = tuple(cmap.vocabulary[y] for y in class_ids)
            out.append(QuerySet(unit, sub, cand_ids, targets, targets, class_ids, np.stack(rows)))
    return out
