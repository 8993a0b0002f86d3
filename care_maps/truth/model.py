"""The one ground-truth model every reader produces and evaluation consumes.

A :class:`GroundTruth` is

- **instances**: one row per object (``instance_id >= 1``, ``class_name``, ``class_id``,
  ``room_id`` (-1: none), axis-aligned ``bbox_min``/``bbox_max`` and a ``box_center``,
  ``box_size``, ``box_rotation`` (row-major 3x3) that may be oriented);
- **points**: labelled surface points (``points`` (P, 3) with ``point_instance`` (P,), 0 =
  structure or unlabelled). An instance with points is judged on them; an instance with none
  is *box-only* and is judged on its box (see :meth:`GroundTruth.label_points`);
- **rooms**: floor polygons with an optional height band (multi-storey houses);
- **frame**: the name of the frame everything is expressed in (``world`` for the sample
  world, the dataset's name for a scan read as it is, ``map`` after ``--gt-transform``).

The file formats live in their own modules (:mod:`care_maps.truth.formats`, the sample world's native
files in :mod:`care_maps.truth.formats.native`), which import this model and not the other way; the
geometry in :mod:`care_maps.truth.geometry`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np
import pyarrow as pa

from care_maps.core.errors import GroundTruthError
from care_maps.truth.geometry import (
    aabb_of_boxes,
    apply_transform,
    box_floor_distance,
    boxes_of_aabb,
    label_points_by_boxes,
    points_in_polygon,
    transform_boxes,
    yaw_rotation,
)

__all__ = ["INSTANCE_COLUMNS", "LABEL_DISTANCE", "GroundTruth", "Room", "instances_table"]

INSTANCE_COLUMNS = ("instance_id", "class_name", "class_id", "room_id", "bbox_min", "bbox_max")
"""The columns every instance has (the box columns are derived from the bounds if absent)."""

BOX_COLUMNS = ("box_center", "box_size", "box_rotation")

LABEL_DISTANCE = 0.05
"""Metres: a scene point farther than this from every ground-truth point gets no label."""


@dataclass(frozen=True, eq=False)
class Room:
    """One room of the floor plan: a floor polygon and, optionally, the height band it spans."""

    room_id: int
    name: str
    floor_polygon: np.ndarray
    """(P, 2) float64 polygon of the room's floor, metres, counter-clockwise."""
    z_min: float = -np.inf
    """Lowest height (m) of the room: rooms of different storeys share a floor plan."""
    z_max: float = np.inf


def instances_table(rows: list[dict[str, Any]]) -> pa.Table:
    """The instances table from row dicts with :data:`INSTANCE_COLUMNS` or a box.

    A row may give its box as ``box_center``/``box_size`` with ``box_rotation`` (9 numbers)
    or ``yaw`` (radians about z); without one the box is its axis-aligned bounds, and without
    bounds the bounds are those of the box. ``room_id`` defaults to -1 (no room).
    """
    centers, sizes, rots, los, his = [], [], [], [], []
    for r in rows:
        if "box_center" in r and r["box_center"] is not None:
            c = np.asarray(r["box_center"], np.float64)
            s = np.asarray(r["box_size"], np.float64)
            if r.get("box_rotation") is not None:
                rot = np.asarray(r["box_rotation"], np.float64).reshape(3, 3)
            else:
                rot = yaw_rotation(float(r.get("yaw") or 0.0))
            lo, hi = aabb_of_boxes(c[None], s[None], rot[None])
            lo, hi = (
                (r["bbox_min"], r["bbox_max"]) if r.get("bbox_min") is not None else (lo[0], hi[0])
            )
        else:
            lo, hi = r["bbox_min"], r["bbox_max"]
            c, s, rot = (a[0] for a in boxes_of_aabb(np.asarray(lo), np.asarray(hi)))
        centers.append(c.tolist())
        sizes.append(s.tolist())
        rots.append(rot.reshape(9).tolist())
        los.append([float(v) for v in lo])
        his.append([float(v) for v in hi])
    return pa.table(
        {
            "instance_id": pa.array([r["instance_id"] for r in rows], pa.int32()),
            "class_name": pa.array([r["class_name"] for r in rows], pa.string()),
            "class_id": pa.array([r.get("class_id", 0) for r in rows], pa.int32()),
            "room_id": pa.array([r.get("room_id", -1) for r in rows], pa.int32()),
            "bbox_min": pa.array(los, pa.list_(pa.float32(), 3)),
            "bbox_max": pa.array(his, pa.list_(pa.float32(), 3)),
            "box_center": pa.array(centers, pa.list_(pa.float64(), 3)),
            "box_size": pa.array(sizes, pa.list_(pa.float64(), 3)),
            "box_rotation": pa.array(rots, pa.list_(pa.float64(), 9)),
        }
    )


def _fixed(table: pa.Table, name: str, width: int) -> np.ndarray:
    column = table.column(name).combine_chunks()
    if len(column) == 0:
        return np.zeros((0, width))
    return column.flatten().to_numpy().reshape(-1, width).astype(np.float64)


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Everything a recording's evaluation needs to know about the scene it shows."""

    class_names: tuple[str, ...]
    """Class table; ``class_id`` of an instance indexes it (0 = ``void`` by convention)."""
    instances: pa.Table
    """One row per object, see :func:`instances_table`."""
    rooms: list[Room]
    points: np.ndarray
    """(P, 3) float32 labelled surface points (may be empty: box-only ground truth)."""
    point_instance: np.ndarray
    """(P,) int32 instance id of each point, 0 = structure or unlabelled."""
    info: dict[str, Any] = field(default_factory=dict)
    """Where it came from (format, files) and, for the sample world, how it was made
    (``unseen_instances`` are left out of the evaluation)."""
    frame: str = "world"
    """Name of the frame the points, boxes and rooms are expressed in."""

    def __post_init__(self) -> None:
        if not isinstance(self.instances, pa.Table) or any(
            c not in self.instances.column_names for c in BOX_COLUMNS
        ):
            rows = self.instances.to_pylist() if isinstance(self.instances, pa.Table) else []
            object.__setattr__(self, "instances", instances_table(rows))

    # -- instances -----------------------------------------------------------------------

    @property
    def instance_ids(self) -> np.ndarray:
        return self.instances.column("instance_id").to_numpy()

    @property
    def instance_class_ids(self) -> np.ndarray:
        return self.instances.column("class_id").to_numpy()

    def instance_class_names(self) -> dict[int, str]:
        """``instance_id -> class name``."""
        return dict(
            zip(
                self.instances.column("instance_id").to_pylist(),
                self.instances.column("class_name").to_pylist(),
                strict=True,
            )
        )

    def boxes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(center (B, 3), size (B, 3), rotation (B, 3, 3))`` of every instance's box."""
        return (
            _fixed(self.instances, "box_center", 3),
            _fixed(self.instances, "box_size", 3),
            _fixed(self.instances, "box_rotation", 9).reshape(-1, 3, 3),
        )

    @cached_property
    def box_only(self) -> np.ndarray:
        """(B,) bool: instances with no labelled point, judged on their box."""
        return ~np.isin(self.instance_ids, np.unique(self.point_instance))

    # -- labelling -----------------------------------------------------------------------

    @cached_property
    def _tree(self) -> Any:
        from scipy.spatial import cKDTree

        return cKDTree(np.asarray(self.points, dtype=np.float64).reshape(-1, 3))

    def label_points(self, points: np.ndarray, max_dist: float = LABEL_DISTANCE) -> np.ndarray:
        """(N,) int32 ground-truth instance of each point, 0 for structure or nothing.

        A point takes the instance of the nearest ground-truth point within ``max_dist``
        metres; a point that none labels takes the box-only instance whose box contains it
        (the smallest such box). So point-labelled ground truth is judged on its surface and
        box-only ground truth on the scene points inside its boxes.
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(len(points), np.int32)
        if len(points) == 0:
            return out
        if len(self.points):
            dist, idx = self._tree.query(points, k=1, distance_upper_bound=max_dist)
            hit = np.isfinite(dist)
            out[hit] = self.point_instance[idx[hit]]
        boxed = self.box_only
        if boxed.any():
            free = out == 0
            center, size, rot = (a[boxed] for a in self.boxes())
            ids = self.instance_ids[boxed]
            out[free] = label_points_by_boxes(points[free], ids, center, size, rot)
        return out

    def floor_distance(self, xy: np.ndarray, instance_ids: np.ndarray) -> np.ndarray:
        """(N,) floor-plane distance from each point to the nearest surface point or, for
        box-only instances, box footprint of any of ``instance_ids`` (inf if none)."""
        from scipy.spatial import cKDTree

        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        out = np.full(len(xy), np.inf)
        if len(xy) == 0:
            return out
        chosen = np.isin(self.point_instance, instance_ids)
        if chosen.any():
            tree = cKDTree(np.asarray(self.points, np.float64)[chosen, :2])
            out = np.minimum(out, tree.query(xy, k=1)[0])
        boxed = self.box_only & np.isin(self.instance_ids, instance_ids)
        if boxed.any():
            center, size, rot = (a[boxed] for a in self.boxes())
            out = np.minimum(out, box_floor_distance(xy, center, size, rot).min(axis=1))
        return out

    def room_of(self, xy: np.ndarray) -> np.ndarray:
        """(N,) int32 room id of each point by point-in-polygon, -1 outside all.

        Points are (N, 2) floor positions or (N, 3) positions; with heights, a room's height
        band must contain the point too. A point on a shared wall line goes to the first room
        that contains it.
        """
        pts = np.asarray(xy, dtype=np.float64)
        pts = pts.reshape(-1, pts.shape[-1] if pts.ndim > 1 else 2)
        out = np.full(len(pts), -1, np.int32)
        for room in self.rooms:
            free = out < 0
            if pts.shape[1] >= 3:
                free &= (pts[:, 2] >= room.z_min) & (pts[:, 2] <= room.z_max)
            if not free.any():
                continue
            inside = points_in_polygon(pts[free, :2], np.asarray(room.floor_polygon, np.float64))
            out[np.flatnonzero(free)[inside]] = room.room_id
        return out

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (lo, hi) of every labelled point and instance box."""
        lo = self.instances.column("bbox_min").combine_chunks()
        hi = self.instances.column("bbox_max").combine_chunks()
        parts_lo = [np.asarray(self.points, np.float64).reshape(-1, 3)]
        parts_hi = [parts_lo[0]]
        if len(lo):
            parts_lo.append(lo.flatten().to_numpy().reshape(-1, 3))
            parts_hi.append(hi.flatten().to_numpy().reshape(-1, 3))
        lo_all, hi_all = np.concatenate(parts_lo), np.concatenate(parts_hi)
        if len(lo_all) == 0:
            return np.full(3, np.nan), np.full(3, np.nan)
        return lo_all.min(axis=0), hi_all.max(axis=0)

    # -- changes ---------------------------------------------------------------------------

    def transformed(self, transform: np.ndarray, frame: str = "map") -> GroundTruth:
        """The same ground truth in another frame: points, boxes and rooms mapped by a 4x4
        rigid transform. Rooms keep their height band only under a rotation about z."""
        t = np.asarray(transform, np.float64).reshape(4, 4)
        rot = t[:3, :3]
        if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-5) or not np.allclose(
            t[3], [0, 0, 0, 1]
        ):
            msg = f"--gt-transform is not a rigid transform (rotation + translation): {t.tolist()}"
            raise GroundTruthError(msg)
        center, size, rotation = transform_boxes(t, *self.boxes())
        lo, hi = aabb_of_boxes(center, size, rotation)
        rows = self.instances.to_pylist()
        for i, r in enumerate(rows):
            r.update(
                box_center=center[i].tolist(), box_size=size[i].tolist(),
                box_rotation=rotation[i].reshape(9).tolist(),
                bbox_min=lo[i].tolist(), bbox_max=hi[i].tolist(),
            )  # fmt: skip
        upright = np.allclose(rot[2], [0, 0, 1], atol=1e-6)
        rooms = []
        for room in self.rooms:
            poly = np.c_[room.floor_polygon, np.zeros(len(room.floor_polygon))]
            moved = apply_transform(t, poly)[:, :2]
            band = (room.z_min + t[2, 3], room.z_max + t[2, 3]) if upright else (-np.inf, np.inf)
            rooms.append(Room(room.room_id, room.name, moved, *band))
        points = (
            apply_transform(t, self.points).astype(np.float32)
            if len(self.points)
            else (np.asarray(self.points, np.float32).reshape(-1, 3))
        )
        info = {**self.info, "transform": t.tolist(), "source_frame": self.frame}
        return replace(
            self, instances=instances_table(rows), rooms=rooms, points=points, info=info,
            frame=frame,
        )  # fmt: skip

    def without_instances(self, ids: list[int] | np.ndarray) -> GroundTruth:
        """The same ground truth less some instances (their points become structure)."""
        ids = np.asarray(list(ids), np.int64)
        if not len(ids):
            return self
        keep = ~np.isin(self.instance_ids, ids)
        point_instance = np.where(np.isin(self.point_instance, ids), 0, self.point_instance)
        return replace(
            self,
            instances=self.instances.filter(keep),
            point_instance=point_instance.astype(np.int32),
        )

    def renamed(self, mapping: dict[str, str]) -> GroundTruth:
        """Classes renamed by ``mapping`` (a name mapped to ``""`` drops its instances: their
        points become structure). Names the mapping lacks are kept."""
        rows, dropped = [], []
        for r in self.instances.to_pylist():
            name = mapping.get(r["class_name"], r["class_name"])
            if not name:
                dropped.append(r["instance_id"])
                continue
            rows.append({**r, "class_name": name})
        names = sorted({r["class_name"] for r in rows})
        class_names = ("void", *names)
        for r in rows:
            r["class_id"] = class_names.index(r["class_name"])
        point_instance = np.where(
            np.isin(self.point_instance, dropped), 0, self.point_instance
        ).astype(np.int32)
        return replace(
            self,
            class_names=class_names,
            instances=instances_table(rows),
            point_instance=point_instance,
        )
