"""Ground truth of a sample-world recording: classes, instances, rooms and labelled surface points.

It lies beside the recording it describes (``scene_000.mcap`` ->
``scene_000.gt.parquet`` + ``scene_000.gt.json``):

- ``.gt.parquet``: the sampled surface point cloud, columns ``x, y, z`` float32 (world frame,
  metres, z up) and ``instance_id`` int32 (0 = structure: walls, floor, ceiling);
- ``.gt.json``: class names (index = the class id of the recording's ``class`` image,
  0 = ``void``), the instance rows and the rooms' floor polygons, plus how the scene was made.

Evaluation labels its own reconstructed points with :meth:`GroundTruth.label_points` and
rooms with :meth:`GroundTruth.room_of`; both are vectorised.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from care.errors import WorldError
from care.store import read_table, write_table_atomic

__all__ = ["GT_SCHEMA_VERSION", "GroundTruth", "Room", "gt_paths", "instances_table"]

GT_SCHEMA_VERSION = 1
"""Version of the ``.gt.json`` layout; readers refuse others."""

INSTANCE_COLUMNS = ("instance_id", "class_name", "class_id", "room_id", "bbox_min", "bbox_max")


@dataclass(frozen=True, eq=False)
class Room:
    """One room of the floor plan."""

    room_id: int
    name: str
    floor_polygon: np.ndarray
    """(P, 2) float64 polygon of the room's floor (wall centre lines), metres, counter-clockwise."""


def gt_paths(recording_path: Path) -> tuple[Path, Path]:
    """``(points parquet, json)`` paths of the ground truth beside ``recording_path``.

    The recording may be a file (``.mcap``, ``.bag``) or a rosbag2 directory; the ground
    truth takes its stem either way.
    """
    recording_path = Path(recording_path)
    stem = recording_path.stem if recording_path.suffix else recording_path.name
    return (
        recording_path.with_name(f"{stem}.gt.parquet"),
        recording_path.with_name(f"{stem}.gt.json"),
    )


def instances_table(rows: list[dict[str, Any]]) -> pa.Table:
    """The instances table (columns :data:`INSTANCE_COLUMNS`) from a list of row dicts."""
    return pa.table(
        {
            "instance_id": pa.array([r["instance_id"] for r in rows], pa.int32()),
            "class_name": pa.array([r["class_name"] for r in rows], pa.string()),
            "class_id": pa.array([r["class_id"] for r in rows], pa.int32()),
            "room_id": pa.array([r["room_id"] for r in rows], pa.int32()),
            "bbox_min": pa.array(
                [[float(v) for v in r["bbox_min"]] for r in rows], pa.list_(pa.float32(), 3)
            ),
            "bbox_max": pa.array(
                [[float(v) for v in r["bbox_max"]] for r in rows], pa.list_(pa.float32(), 3)
            ),
        }
    )


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Everything a recording's evaluation needs to know about the scene it shows."""

    class_names: tuple[str, ...]
    """Index = class id used in the ``class`` label image; 0 = ``void``."""
    instances: pa.Table
    """One row per object: instance_id (>= 1), class_name, class_id, room_id,
    bbox_min[3], bbox_max[3] (world-frame axis-aligned bounds of the object's mesh)."""
    rooms: list[Room]
    points: np.ndarray
    """(P, 3) float32 surface points sampled on every mesh, world frame."""
    point_instance: np.ndarray
    """(P,) int32 instance id of each point, 0 = structure (walls, floor, ceiling)."""
    info: dict[str, Any] = field(default_factory=dict)
    """How the scene was made (generator version, seed, options) and what the render saw
    (``unseen_instances``)."""

    # -- queries -------------------------------------------------------------------------

    @cached_property
    def _tree(self) -> Any:
        from scipy.spatial import cKDTree

        return cKDTree(np.asarray(self.points, dtype=np.float64))

    def label_points(self, points: np.ndarray, max_dist: float = 0.05) -> np.ndarray:
        """(N,) int32 instance id of the nearest ground-truth point within ``max_dist`` metres,
        else 0 (structure or nothing)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(points) == 0 or len(self.points) == 0:
            return np.zeros(len(points), np.int32)
        dist, idx = self._tree.query(points, k=1, distance_upper_bound=max_dist)
        hit = np.isfinite(dist)
        out = np.zeros(len(points), np.int32)
        out[hit] = self.point_instance[idx[hit]]
        return out

    def room_of(self, xy: np.ndarray) -> np.ndarray:
        """(N,) int32 room id of each floor-plane point by point-in-polygon, -1 outside all.

        Even-odd ray crossing, vectorised over points and polygon edges; a point on a shared
        wall line goes to the first room that contains it.
        """
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        out = np.full(len(xy), -1, np.int32)
        for room in self.rooms:
            free = out < 0
            if not free.any():
                break
            inside = _points_in_polygon(xy[free], np.asarray(room.floor_polygon, np.float64))
            idx = np.flatnonzero(free)[inside]
            out[idx] = room.room_id
        return out

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

    # -- files ---------------------------------------------------------------------------

    def save(self, recording_path: Path) -> None:
        """Write ``<stem>.gt.parquet`` and ``<stem>.gt.json`` beside ``recording_path``.

        Both go through temporary files renamed into place; the output bytes depend only
        on the contents (no timestamps), so the same scene gives the same files.
        """
        pq_path, json_path = gt_paths(recording_path)
        pts = np.asarray(self.points, np.float32)
        table = pa.table(
            {
                "x": pa.array(pts[:, 0]),
                "y": pa.array(pts[:, 1]),
                "z": pa.array(pts[:, 2]),
                "instance_id": pa.array(np.asarray(self.point_instance, np.int32)),
            }
        )
        write_table_atomic(table, pq_path)
        doc = {
            "gt_schema_version": GT_SCHEMA_VERSION,
            "class_names": list(self.class_names),
            "instances": self.instances.to_pylist(),
            "rooms": [
                {
                    "room_id": r.room_id,
                    "name": r.name,
                    "floor_polygon": np.round(np.asarray(r.floor_polygon), 6).tolist(),
                }
                for r in self.rooms
            ],
            "info": self.info,
        }
        tmp = json_path.with_name(f".{json_path.name}.tmp-{os.getpid()}")
        try:
            tmp.write_text(json.dumps(doc, indent=1, sort_keys=True))
            tmp.replace(json_path)
        finally:
            tmp.unlink(missing_ok=True)

    @classmethod
    def load(cls, path: Path) -> GroundTruth:
        """Ground truth of the recording at ``path`` (or of the ``.gt.json`` given directly)."""
        path = Path(path)
        if path.name.endswith(".gt.json"):
            path = path.with_name(path.name[: -len(".gt.json")])
        pq_path, json_path = gt_paths(path)
        if not json_path.is_file() or not pq_path.is_file():
            msg = (
                f"{path}: no ground truth beside it (expected {json_path.name} and "
                f"{pq_path.name}); sample-world recordings come with one (`care sample make`)."
            )
            raise WorldError(msg)
        try:
            doc = json.loads(json_path.read_text())
        except json.JSONDecodeError as err:
            msg = f"{json_path}: not valid JSON ({err}); regenerate it with `care sample make`."
            raise WorldError(msg) from err
        if doc.get("gt_schema_version") != GT_SCHEMA_VERSION:
            msg = (
                f"{json_path}: ground-truth version {doc.get('gt_schema_version')}, this "
                f"program reads {GT_SCHEMA_VERSION}; regenerate it with `care sample make`."
            )
            raise WorldError(msg)
        table = read_table(pq_path)
        points = np.stack([table.column(c).to_numpy() for c in "xyz"], axis=1).astype(np.float32)
        rows = doc["instances"]
        return cls(
            class_names=tuple(doc["class_names"]),
            instances=instances_table(rows),
            rooms=[
                Room(r["room_id"], r["name"], np.asarray(r["floor_polygon"], np.float64))
                for r in doc["rooms"]
            ],
            points=points.reshape(-1, 3),
            point_instance=table.column("instance_id").to_numpy().astype(np.int32),
            info=doc.get("info", {}),
        )


def _points_in_polygon(xy: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """(N,) bool: even-odd test of (N, 2) points against one (P, 2) polygon, half-open edges
    so that points on a shared boundary are counted once."""
    a = poly[None, :, :]
    b = np.roll(poly, -1, axis=0)[None, :, :]
    x = xy[:, None, 0]
    y = xy[:, None, 1]
    straddles = (a[..., 1] > y) != (b[..., 1] > y)
    dy = np.where(b[..., 1] == a[..., 1], 1.0, b[..., 1] - a[..., 1])
    x_cross = a[..., 0] + (y - a[..., 1]) * (b[..., 0] - a[..., 0]) / dy
    crossings = straddles & (x < x_cross)
    return (np.count_nonzero(crossings, axis=1) % 2) == 1
