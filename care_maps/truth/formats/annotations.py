"""Light annotation files: a list of object boxes a person writes by hand or exports from a
labelling tool, as JSON, YAML or CSV.

JSON / YAML::

    frame: map                      # optional: the frame the numbers are in
    rooms:                          # optional: floor polygons (counter-clockwise) in metres
      - {name: kitchen, polygon: [[0, 0], [4, 0], [4, 3], [0, 3]], z_min: 0.0, z_max: 2.6}
    objects:                        # required (a bare list of objects works too)
      - {class: chair, center: [1.2, 0.5, 0.45], size: [0.5, 0.5, 0.9], yaw: 0.3, room: kitchen}

``center``/``size`` may also be given as ``cx, cy, cz, sx, sy, sz``; ``yaw`` (radians,
counter-clockwise about +z, default 0), ``room`` (a room's name) and ``id`` (default: row
number from 1) are optional.

CSV: one object per row, ``class, cx, cy, cz, sx, sy, sz[, yaw][, room]``, with or without
that header line (with a header, columns may come in any order and ``id`` may be added).
Rooms for a CSV come from ``<name>.rooms.json`` / ``.yaml`` beside it (``rooms:`` as above).

Objects are boxes only: evaluation judges a retrieved mask by its IoU with the map's points
inside the box (docs/evaluation.md, *Success criteria*).
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.errors import GroundTruthError
from care_maps.truth.formats.common import read_json, room_of_dict, room_to_dict, write_text
from care_maps.truth.model import GroundTruth, Room, instances_table

__all__ = ["ANNOTATION_SUFFIXES", "read_annotations", "write_annotations"]

ANNOTATION_SUFFIXES = (".json", ".yaml", ".yml", ".csv")
CSV_COLUMNS = ("class", "cx", "cy", "cz", "sx", "sy", "sz", "yaw", "room")


def _read_yaml(path: Path) -> Any:
    import yaml

    try:
        return yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        msg = f"{path}: not valid YAML ({str(err).splitlines()[0]})"
        raise GroundTruthError(msg) from err


def _read_doc(path: Path) -> Any:
    if not path.is_file():
        msg = f"{path}: no such annotation file"
        raise GroundTruthError(msg)
    if path.suffix == ".json":
        return read_json(path, "annotation file")
    return _read_yaml(path)


def _number(value: Any, path: Path, where: str, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError) as err:
        msg = f"{path}: {where}: '{name}' should be a number, got {value!r}"
        raise GroundTruthError(msg) from err
    if not math.isfinite(out):
        msg = f"{path}: {where}: '{name}' is {value!r}"
        raise GroundTruthError(msg)
    return out


def _vector(obj: dict, key: str, flat: tuple[str, str, str], path: Path, where: str) -> np.ndarray:
    if key in obj:
        value = obj[key]
        if not isinstance(value, list | tuple) or len(value) != 3:
            msg = f"{path}: {where}: '{key}' should be 3 numbers, got {value!r}"
            raise GroundTruthError(msg)
        return np.array([_number(v, path, where, key) for v in value])
    missing = [k for k in flat if k not in obj or obj[k] in (None, "")]
    if missing:
        msg = f"{path}: {where}: missing field '{key}' (or {', '.join(flat)}): no {', '.join(missing)}"
        raise GroundTruthError(msg)
    return np.array([_number(obj[k], path, where, k) for k in flat])


def _objects_from_csv(path: Path) -> list[dict[str, Any]]:
    try:
        rows = [
            r for r in csv.reader(path.read_text().splitlines()) if r and not r[0].startswith("#")
        ]
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        msg = f"{path}: not a readable CSV file ({err})"
        raise GroundTruthError(msg) from err
    if not rows:
        return []
    header = [c.strip().lower() for c in rows[0]]
    try:
        float(header[1])
        named = False
    except (IndexError, ValueError):
        named = True
    out = []
    if named:
        if "class" not in header:
            msg = f"{path}: header has no 'class' column (expected {', '.join(CSV_COLUMNS)})"
            raise GroundTruthError(msg)
        for n, row in enumerate(rows[1:], start=2):
            obj: dict[str, Any] = {k: v.strip() for k, v in zip(header, row, strict=False)}
            obj["_where"] = f"line {n}"
            out.append(obj)
        return out
    for n, row in enumerate(rows, start=1):
        cells = [c.strip() for c in row]
        if len(cells) < 7:
            msg = f"{path}: line {n}: expected class, cx, cy, cz, sx, sy, sz[, yaw][, room], got {len(cells)} field(s)"
            raise GroundTruthError(msg)
        obj = dict(zip(CSV_COLUMNS[:7], cells[:7], strict=True))
        rest = cells[7:]
        if rest:
            try:
                float(rest[0])
                obj["yaw"] = rest.pop(0)
            except ValueError:
                pass
        if rest:
            obj["room"] = rest[0]
        obj["_where"] = f"line {n}"
        out.append(obj)
    return out


def _rooms_beside(path: Path) -> list[Room]:
    for ext in (".json", ".yaml", ".yml"):
        side = path.with_name(f"{path.stem.removesuffix('.annotations')}.rooms{ext}")
        if side.is_file():
            doc = _read_doc(side)
            rooms = doc.get("rooms") if isinstance(doc, dict) else doc
            return [room_of_dict(r, n, side) for n, r in enumerate(rooms or [])]
    return []


def read_annotations(path: Path) -> GroundTruth:
    """Box-only ground truth from a JSON, YAML or CSV annotation file."""
    path = Path(path)
    frame = "annotations"
    if path.suffix.lower() == ".csv":
        if not path.is_file():
            msg = f"{path}: no such annotation file"
            raise GroundTruthError(msg)
        objects, rooms = _objects_from_csv(path), _rooms_beside(path)
    else:
        doc = _read_doc(path)
        if isinstance(doc, dict):
            if "objects" not in doc:
                msg = f"{path}: missing field 'objects' (a list of {{class, center, size}})"
                raise GroundTruthError(msg)
            objects = doc["objects"]
            rooms = [room_of_dict(r, n, path) for n, r in enumerate(doc.get("rooms") or [])]
            frame = str(doc.get("frame", frame))
        else:
            objects, rooms = doc, []
        if not isinstance(objects, list):
            msg = f"{path}: 'objects' should be a list of {{class, center, size}}"
            raise GroundTruthError(msg)
    if not objects:
        msg = f"{path}: no objects annotated"
        raise GroundTruthError(msg)
    by_name = {r.name: r.room_id for r in rooms}
    probe = GroundTruth(("void",), instances_table([]), rooms, np.zeros((0, 3)), np.zeros(0))
    rows, names, seen = [], [], set()
    for n, obj in enumerate(objects):
        where = obj.pop("_where", f"objects[{n}]") if isinstance(obj, dict) else f"objects[{n}]"
        if not isinstance(obj, dict):
            msg = f"{path}: {where} should be a mapping with class, center and size"
            raise GroundTruthError(msg)
        name = str(obj.get("class", obj.get("class_name", "")) or "").strip()
        if not name:
            msg = f"{path}: {where}: missing field 'class'"
            raise GroundTruthError(msg)
        center = _vector(obj, "center", ("cx", "cy", "cz"), path, where)
        size = _vector(obj, "size", ("sx", "sy", "sz"), path, where)
        if (size <= 0).any():
            msg = f"{path}: {where} ('{name}'): size {size.tolist()} has a side <= 0: an empty box"
            raise GroundTruthError(msg)
        yaw = obj.get("yaw")
        yaw = 0.0 if yaw in (None, "") else _number(yaw, path, where, "yaw")
        iid = (
            int(_number(obj["id"], path, where, "id")) if obj.get("id") not in (None, "") else n + 1
        )
        if iid < 1 or iid in seen:
            msg = f"{path}: {where}: id {iid} is {'used twice' if iid in seen else '< 1'}"
            raise GroundTruthError(msg)
        seen.add(iid)
        room = obj.get("room")
        if room not in (None, "") and rooms:
            if str(room) not in by_name:
                msg = (
                    f"{path}: {where}: room '{room}' is not one of the rooms ({', '.join(by_name)})"
                )
                raise GroundTruthError(msg)
            room_id = by_name[str(room)]
        else:
            room_id = int(probe.room_of(center[None])[0]) if rooms else -1
        rows.append({"instance_id": iid, "class_name": name, "room_id": room_id,
                     "box_center": center.tolist(), "box_size": size.tolist(), "yaw": yaw})  # fmt: skip
        names.append(name)
    class_names = ("void", *sorted(set(names)))
    for r in rows:
        r["class_id"] = class_names.index(r["class_name"])
    return GroundTruth(
        class_names=class_names, instances=instances_table(rows), rooms=rooms,
        points=np.zeros((0, 3), np.float32), point_instance=np.zeros(0, np.int32),
        info={"format": "annotations", "files": [path.name]}, frame=frame,
    )  # fmt: skip


def _yaw_of(rotation: np.ndarray) -> float:
    r = np.asarray(rotation, np.float64).reshape(3, 3)
    if not np.allclose(r[2], [0, 0, 1], atol=1e-9):
        msg = "an annotation file holds upright boxes (yaw only); this box is tilted"
        raise GroundTruthError(msg)
    return float(math.atan2(r[1, 0], r[0, 0]))


def write_annotations(gt: GroundTruth, path: Path) -> list[Path]:
    """Write ``gt``'s instances as boxes (JSON, YAML or CSV by the suffix; a CSV gets its rooms
    in ``<name>.rooms.json`` beside it)."""
    path = Path(path)
    center, size, rotation = gt.boxes()
    room_name = {r.room_id: r.name for r in gt.rooms}
    objects = []
    for i, (iid, name, room) in enumerate(
        zip(gt.instance_ids.tolist(), gt.instances.column("class_name").to_pylist(),
            gt.instances.column("room_id").to_pylist(), strict=True)
    ):  # fmt: skip
        obj: dict[str, Any] = {
            "id": int(iid),
            "class": name,
            "center": center[i].tolist(),
            "size": size[i].tolist(),
        }
        yaw = _yaw_of(rotation[i])
        if yaw:
            obj["yaw"] = yaw
        if room in room_name:
            obj["room"] = room_name[room]
        objects.append(obj)
    rooms = [room_to_dict(r) for r in gt.rooms]
    if path.suffix.lower() == ".csv":
        lines = ["id,class,cx,cy,cz,sx,sy,sz,yaw,room"]
        for o in objects:
            nums = [*o["center"], *o["size"], o.get("yaw", 0.0)]
            lines.append(
                ",".join(
                    [str(o["id"]), o["class"], *(repr(float(v)) for v in nums), o.get("room", "")]
                )
            )
        write_text(path, "\n".join(lines) + "\n")
        if not rooms:
            return [path]
        side = path.with_name(f"{path.stem.removesuffix('.annotations')}.rooms.json")
        write_text(side, json.dumps({"rooms": rooms}, indent=1))
        return [path, side]
    doc = {"frame": gt.frame, "rooms": rooms, "objects": objects}
    if path.suffix.lower() == ".json":
        write_text(path, json.dumps(doc, indent=1))
    else:
        import yaml

        write_text(path, yaml.safe_dump(doc, sort_keys=False))
    return [path]
