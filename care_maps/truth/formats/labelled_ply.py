"""A labelled point cloud or mesh: a PLY with per-vertex instance and class ids, and a class
table beside it.

- ``<name>.ply``: vertices ``x, y, z`` plus ``instance`` (also read: ``instance_id``,
  ``objectId``; 0 or negative = structure/unlabelled) and ``label`` (also ``class``,
  ``label_id``, ``semantic``): the class id, an index into the class table. Faces, colours
  and normals may be there and are ignored.
- the class table, first found of ``<name>.classes.json`` (a list of names, index = id, or
  ``{"classes": [...] or {"id": "name"}, "rooms": [...], "instance_rooms": {"id": room}}``),
  ``<name>.classes.tsv`` / ``.csv`` / ``.txt`` (``id<TAB or ,>name`` per line).

An instance's class is the most common label of its vertices.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.errors import GroundTruthError
from care_maps.truth.formats.common import (
    from_labelled_points,
    read_json,
    read_ply,
    room_of_dict,
    room_to_dict,
    vertex_property,
    vertices_xyz,
    write_ply,
    write_text,
)
from care_maps.truth.model import GroundTruth

__all__ = ["class_table_paths", "read_labelled_ply", "write_labelled_ply"]

INSTANCE_NAMES = ("instance", "instance_id", "objectId")
LABEL_NAMES = ("label", "class", "label_id", "semantic")


def class_table_paths(ply_path: Path) -> list[Path]:
    stem = Path(ply_path).with_suffix("")
    return [
        stem.with_name(f"{stem.name}.classes{ext}") for ext in (".json", ".tsv", ".csv", ".txt")
    ]


def _class_table(ply_path: Path) -> tuple[dict[int, str], dict[str, Any], Path]:
    for path in class_table_paths(ply_path):
        if not path.is_file():
            continue
        if path.suffix == ".json":
            doc = read_json(path, "class table of a labelled PLY")
            extra = doc if isinstance(doc, dict) else {}
            classes = doc.get("classes") if isinstance(doc, dict) else doc
            if isinstance(classes, list):
                return {i: str(n) for i, n in enumerate(classes)}, extra, path
            if isinstance(classes, dict):
                try:
                    return {int(k): str(v) for k, v in classes.items()}, extra, path
                except ValueError as err:
                    msg = f"{path}: class ids must be integers ({err})"
                    raise GroundTruthError(msg) from err
            msg = f"{path}: expected a list of class names or {{'classes': ...}}"
            raise GroundTruthError(msg)
        table = {}
        with path.open(newline="") as fh:
            dialect = "excel-tab" if "\t" in fh.read(4096) else "excel"
            fh.seek(0)
            for n, row in enumerate(csv.reader(fh, dialect), start=1):
                if not row or row[0].startswith("#"):
                    continue
                try:
                    table[int(row[0])] = row[1].strip()
                except (ValueError, IndexError) as err:
                    if n == 1:
                        continue  # a header line
                    msg = f"{path}:{n}: expected 'id, name', got {row!r}"
                    raise GroundTruthError(msg) from err
        return table, {}, path
    names = ", ".join(p.name for p in class_table_paths(ply_path))
    msg = f"{ply_path}: no class table beside it (one of {names})"
    raise GroundTruthError(msg)


def read_labelled_ply(path: Path) -> GroundTruth:
    """Ground truth of a labelled PLY and its class table (see the module docstring)."""
    path = Path(path)
    ply = read_ply(path)
    xyz = vertices_xyz(ply, path)
    inst = vertex_property(ply, path, *INSTANCE_NAMES).astype(np.int64)
    label = vertex_property(ply, path, *LABEL_NAMES).astype(np.int64)
    table, extra, table_path = _class_table(path)
    class_of: dict[int, str] = {}
    for i in np.unique(inst[inst > 0]):
        values, counts = np.unique(label[inst == i], return_counts=True)
        cid = int(values[np.argmax(counts)])
        if cid not in table:
            msg = f"{table_path}: class id {cid} (of instance {int(i)} in {path.name}) is not in the table"
            raise GroundTruthError(msg)
        class_of[int(i)] = table[cid]
    rooms = [room_of_dict(r, n, table_path) for n, r in enumerate(extra.get("rooms") or [])]
    inst_rooms = {int(k): int(v) for k, v in (extra.get("instance_rooms") or {}).items()}
    return from_labelled_points(
        xyz, np.where(inst > 0, inst, 0), class_of, path=path, rooms=rooms,
        room_of_instance=inst_rooms or None,
        info={"format": "ply", "files": [path.name, table_path.name]}, frame=str(extra.get("frame", "ply")),
    )  # fmt: skip


def write_labelled_ply(gt: GroundTruth, path: Path) -> list[Path]:
    """Write ``gt``'s labelled points as a binary PLY and its class table (with rooms)."""
    from plyfile import PlyElement

    path = Path(path)
    pts = np.asarray(gt.points, np.float32).reshape(-1, 3)
    class_of = dict(zip(gt.instance_ids.tolist(), gt.instance_class_ids.tolist(), strict=True))
    label = np.array([class_of.get(int(i), 0) for i in gt.point_instance], np.int32)
    vertex = np.zeros(
        len(pts), [("x", "f4"), ("y", "f4"), ("z", "f4"), ("instance", "i4"), ("label", "i4")]
    )
    vertex["x"], vertex["y"], vertex["z"] = pts.T
    vertex["instance"] = gt.point_instance
    vertex["label"] = label
    write_ply(path, [PlyElement.describe(vertex, "vertex")])
    table_path = class_table_paths(path)[0]
    doc = {
        "classes": list(gt.class_names),
        "rooms": [room_to_dict(r) for r in gt.rooms],
        "instance_rooms": {
            str(i): int(r)
            for i, r in zip(
                gt.instance_ids.tolist(), gt.instances.column("room_id").to_pylist(), strict=True
            )
        },
        "frame": gt.frame,
    }
    write_text(table_path, json.dumps(doc, indent=1))
    return [path, table_path]
