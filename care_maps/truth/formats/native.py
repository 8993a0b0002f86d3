"""The sample world's native ground truth: ``<stem>.gt.parquet`` + ``<stem>.gt.json``.

- ``.gt.parquet``: labelled surface points, columns ``x, y, z`` float32 (metres, z up) and
  ``instance_id`` int32 (0 = structure: walls, floor, ceiling);
- ``.gt.json``: ``gt_schema_version``, ``class_names`` (index = class id of the recording's
  ``class`` image, 0 = ``void``), ``instances`` (rows of :func:`care_maps.truth.model.instances_table`;
  the ``box_*`` fields only where some box is not the axis-aligned bounds of points),
  ``rooms`` (``room_id``, ``name``, ``floor_polygon``, optional ``z_min``/``z_max``),
  ``frame`` (default ``world``) and ``info`` (how the scene was made).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pyarrow as pa

from care_maps.core.errors import GroundTruthError
from care_maps.core.outputs import atomic_write_text
from care_maps.core.store import read_table, write_table_atomic
from care_maps.truth.model import BOX_COLUMNS, INSTANCE_COLUMNS, GroundTruth, Room, instances_table

__all__ = ["GT_SCHEMA_VERSION", "gt_paths", "read_native", "write_native"]

GT_SCHEMA_VERSION = 1
"""Version of the ``.gt.json`` layout; readers refuse others."""


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


def _needs_boxes(gt: GroundTruth) -> bool:
    center, _size, rot = gt.boxes()
    if not len(center):
        return False
    return bool(gt.box_only.any() or not np.allclose(rot, np.eye(3)))


def write_native(gt: GroundTruth, recording_path: Path) -> None:
    """Write ``<stem>.gt.parquet`` and ``<stem>.gt.json`` beside ``recording_path``.

    Both go through temporary files renamed into place; the output bytes depend only on
    the contents (no timestamps), so the same scene gives the same files.
    """
    pq_path, json_path = gt_paths(recording_path)
    pts = np.asarray(gt.points, np.float32).reshape(-1, 3)
    table = pa.table(
        {
            "x": pa.array(pts[:, 0]),
            "y": pa.array(pts[:, 1]),
            "z": pa.array(pts[:, 2]),
            "instance_id": pa.array(np.asarray(gt.point_instance, np.int32)),
        }
    )
    write_table_atomic(table, pq_path)
    columns = list(INSTANCE_COLUMNS) + (list(BOX_COLUMNS) if _needs_boxes(gt) else [])
    rooms = []
    for r in gt.rooms:
        room = {
            "room_id": r.room_id,
            "name": r.name,
            "floor_polygon": np.round(np.asarray(r.floor_polygon), 6).tolist(),
        }
        if math.isfinite(r.z_min) or math.isfinite(r.z_max):
            room.update(z_min=_finite(r.z_min), z_max=_finite(r.z_max))
        rooms.append(room)
    doc = {
        "gt_schema_version": GT_SCHEMA_VERSION,
        "class_names": list(gt.class_names),
        "instances": gt.instances.select(columns).to_pylist(),
        "rooms": rooms,
        "info": gt.info,
    }
    if gt.frame != "world":
        doc["frame"] = gt.frame
    atomic_write_text(json_path, json.dumps(doc, indent=1, sort_keys=True))


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def read_native(path: Path) -> GroundTruth:
    """Ground truth of the recording at ``path`` (or of the ``.gt.json`` given directly)."""
    path = Path(path)
    if path.name.endswith(".gt.json"):
        path = path.with_name(path.name[: -len(".gt.json")])
    pq_path, json_path = gt_paths(path)
    if not json_path.is_file() or not pq_path.is_file():
        msg = (
            f"{path}: no ground truth beside it (expected {json_path.name} and "
            f"{pq_path.name}); sample-world recordings come with one (`care sample make`), "
            "others take --gt FILE (see `care eval --help`)."
        )
        raise GroundTruthError(msg)
    try:
        doc = json.loads(json_path.read_text())
    except json.JSONDecodeError as err:
        msg = f"{json_path}: not valid JSON ({err}); regenerate it with `care sample make`."
        raise GroundTruthError(msg) from err
    if doc.get("gt_schema_version") != GT_SCHEMA_VERSION:
        msg = (
            f"{json_path}: ground-truth version {doc.get('gt_schema_version')}, this "
            f"program reads {GT_SCHEMA_VERSION}; regenerate it with `care sample make`."
        )
        raise GroundTruthError(msg)
    try:
        table = read_table(pq_path)
        points = np.stack([table.column(c).to_numpy() for c in "xyz"], axis=1)
        point_instance = table.column("instance_id").to_numpy().astype(np.int32)
        rooms = [
            Room(
                r["room_id"],
                r["name"],
                np.asarray(r["floor_polygon"], np.float64),
                -np.inf if r.get("z_min") is None else float(r["z_min"]),
                np.inf if r.get("z_max") is None else float(r["z_max"]),
            )
            for r in doc["rooms"]
        ]
        instances = instances_table(doc["instances"])
        class_names = tuple(doc["class_names"])
    except (KeyError, TypeError, ValueError) as err:
        msg = f"{json_path}: missing or malformed field ({err!r}); regenerate it with `care sample make`."
        raise GroundTruthError(msg) from err
    return GroundTruth(
        class_names=class_names,
        instances=instances,
        rooms=rooms,
        points=points.astype(np.float32).reshape(-1, 3),
        point_instance=point_instance,
        info=doc.get("info", {}),
        frame=doc.get("frame", "world"),
    )
