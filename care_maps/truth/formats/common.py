"""What the format readers share: safe PLY and JSON reading, atomic writing, instance rows
from labelled points, and rooms from plain dicts. Every failure is one
:class:`care_maps.core.errors.GroundTruthError` naming the file and what is wrong."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.errors import GroundTruthError
from care_maps.core.outputs import write_atomic
from care_maps.truth.model import GroundTruth, Room, instances_table

__all__ = [
    "face_array",
    "from_labelled_points",
    "read_json",
    "read_ply",
    "room_of_dict",
    "room_to_dict",
    "vertices_xyz",
    "write_ply",
]


def read_ply(path: Path) -> Any:
    """The parsed PLY (``plyfile.PlyData``); a missing, truncated or corrupt file is one line."""
    from plyfile import PlyData, PlyParseError

    path = Path(path)
    if not path.is_file():
        msg = f"{path}: no such PLY file"
        raise GroundTruthError(msg)
    try:
        return PlyData.read(str(path))
    except (PlyParseError, ValueError, EOFError, IndexError, TypeError, KeyError) as err:
        msg = f"{path}: not a readable PLY file ({type(err).__name__}: {err}); re-export it"
        raise GroundTruthError(msg) from err


def _element(ply: Any, path: Path, name: str) -> Any:
    try:
        return ply[name]
    except KeyError as err:
        have = [e.name for e in ply.elements]
        msg = f"{path}: no '{name}' element (has {have})"
        raise GroundTruthError(msg) from err


def _property(element: Any, path: Path, names: tuple[str, ...]) -> np.ndarray:
    present = [p.name for p in element.properties]
    for name in names:
        if name in present:
            return element[name]
    msg = (
        f"{path}: {element.name} has no property {' or '.join(repr(n) for n in names)} "
        f"(has {present})"
    )
    raise GroundTruthError(msg)


def vertex_property(ply: Any, path: Path, *names: str) -> np.ndarray:
    """A per-vertex property, under the first of ``names`` present."""
    return np.asarray(_property(_element(ply, path, "vertex"), path, names))


def face_property(ply: Any, path: Path, *names: str) -> np.ndarray:
    """A per-face property, under the first of ``names`` present."""
    return np.asarray(_property(_element(ply, path, "face"), path, names))


def vertices_xyz(ply: Any, path: Path) -> np.ndarray:
    """(V, 3) float32 vertex positions (x, y, z keep their bits when stored as float32)."""
    xyz = [vertex_property(ply, path, axis) for axis in "xyz"]
    return np.stack(xyz, axis=1).astype(np.float32)


def face_array(ply: Any, path: Path) -> list[np.ndarray]:
    """Vertex indices of each face (triangles, quads or any polygon)."""
    faces = _property(_element(ply, path, "face"), path, ("vertex_indices", "vertex_index"))
    return [np.asarray(f, np.int64) for f in faces]


def vertex_labels_from_faces(
    n_vertices: int, faces: list[np.ndarray], face_label: np.ndarray, path: Path
) -> np.ndarray:
    """(V,) label of each vertex from the faces that use it (a vertex shared by faces of two
    labels takes the later face's, as the datasets' own export scripts do); 0 if unused."""
    out = np.zeros(n_vertices, np.int64)
    if not faces:
        return out
    lengths = np.fromiter((len(f) for f in faces), np.int64, len(faces))
    flat = np.concatenate(faces) if len(faces) else np.zeros(0, np.int64)
    if len(flat) and (flat.min() < 0 or flat.max() >= n_vertices):
        msg = f"{path}: a face refers to vertex {int(flat.max())}, but there are {n_vertices}"
        raise GroundTruthError(msg)
    out[flat] = np.repeat(np.asarray(face_label, np.int64), lengths)
    return out


def read_json(path: Path, what: str) -> Any:
    """A JSON file's content; missing or invalid is one line saying which ``what`` it is."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as err:
        msg = f"{path}: missing ({what})"
        raise GroundTruthError(msg) from err
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        msg = f"{path}: not valid JSON ({err}); it should be the {what}"
        raise GroundTruthError(msg) from err


def field(doc: Any, key: str, path: Path, kind: type | tuple[type, ...] = object) -> Any:
    """``doc[key]``, or one line naming the file and the missing or mistyped field."""
    if not isinstance(doc, dict) or key not in doc:
        msg = f"{path}: missing field '{key}'"
        raise GroundTruthError(msg)
    value = doc[key]
    if not isinstance(value, kind):
        msg = f"{path}: field '{key}' should be {getattr(kind, '__name__', kind)}, got {type(value).__name__}"
        raise GroundTruthError(msg)
    return value


def write_text(path: Path, text: str) -> None:
    write_atomic(path, lambda tmp: tmp.write_text(text))


def write_ply(path: Path, elements: list[Any], *, text: bool = False) -> None:
    """Write ``plyfile`` elements atomically (binary little-endian unless ``text``)."""
    from plyfile import PlyData

    write_atomic(path, lambda tmp: PlyData(elements, text=text, byte_order="<").write(str(tmp)))


def from_labelled_points(
    points: np.ndarray,
    point_instance: np.ndarray,
    class_of: dict[int, str],
    *,
    path: Path,
    rooms: list[Room] | None = None,
    room_of_instance: dict[int, int] | None = None,
    info: dict[str, Any] | None = None,
    frame: str,
) -> GroundTruth:
    """A :class:`GroundTruth` from labelled points and each instance's class name.

    Instances are the ids present in ``class_of``; their bounds come from their points, their
    room from ``room_of_instance`` or else the room of their points' centre. Points of ids
    without a class become structure (0). An instance without a point is refused: a mask
    with nothing in it can never be found.
    """
    point_instance = np.asarray(point_instance, np.int64)
    ids = sorted(int(i) for i in class_of if int(i) > 0)
    known = np.isin(point_instance, ids)
    point_instance = np.where(known, point_instance, 0).astype(np.int32)
    if not ids:
        msg = f"{path}: no labelled instances (every point is unlabelled or structure)"
        raise GroundTruthError(msg)
    order = np.argsort(point_instance, kind="stable")
    sorted_ids = point_instance[order]
    starts = np.searchsorted(sorted_ids, ids, side="left")
    ends = np.searchsorted(sorted_ids, ids, side="right")
    empty = [i for i, s, e in zip(ids, starts, ends, strict=True) if s == e]
    if empty:
        msg = (
            f"{path}: instance(s) {empty[:10]} ({class_of[empty[0]]!r}, ...) have no points; "
            "fix or drop them"
        )
        raise GroundTruthError(msg)
    names = sorted({class_of[i] for i in ids})
    class_names = ("void", *names)
    probe = GroundTruth(
        class_names, instances_table([]), rooms or [], np.zeros((0, 3)), np.zeros(0)
    )
    rows = []
    for i, s, e in zip(ids, starts, ends, strict=True):
        pts = np.asarray(points, np.float64)[order[s:e]]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if room_of_instance is not None and i in room_of_instance:
            room = room_of_instance[i]
        else:
            room = int(probe.room_of(((lo + hi) / 2)[None])[0]) if rooms else -1
        rows.append(
            {
                "instance_id": i, "class_name": class_of[i],
                "class_id": class_names.index(class_of[i]), "room_id": room,
                "bbox_min": lo.tolist(), "bbox_max": hi.tolist(),
            }
        )  # fmt: skip
    return GroundTruth(
        class_names=class_names,
        instances=instances_table(rows),
        rooms=rooms or [],
        points=np.asarray(points, np.float32).reshape(-1, 3),
        point_instance=point_instance,
        info=info or {},
        frame=frame,
    )


def room_of_dict(doc: Any, index: int, path: Path) -> Room:
    """A room from ``{"name", "polygon" (or "floor_polygon"), "id"?, "z_min"?, "z_max"?}``."""
    if not isinstance(doc, dict):
        msg = f"{path}: room {index} should be a mapping with 'name' and 'polygon'"
        raise GroundTruthError(msg)
    poly = doc.get("polygon", doc.get("floor_polygon"))
    try:
        polygon = np.asarray(poly, np.float64)
    except (TypeError, ValueError) as err:
        msg = f"{path}: room {index} ('{doc.get('name')}'): polygon is not a list of [x, y]"
        raise GroundTruthError(msg) from err
    if polygon.ndim != 2 or polygon.shape[1] != 2 or len(polygon) < 3:
        msg = f"{path}: room {index} ('{doc.get('name')}'): needs a 'polygon' of at least 3 [x, y] points"
        raise GroundTruthError(msg)
    z_min, z_max = doc.get("z_min"), doc.get("z_max")
    room_id: Any = doc.get("room_id", index)  # as read (a number, or text of one)
    return Room(
        int(doc.get("id", room_id)),
        str(doc.get("name", f"room{index}")),
        polygon,
        -np.inf if z_min is None else float(z_min),
        np.inf if z_max is None else float(z_max),
    )


def room_to_dict(room: Room) -> dict[str, Any]:
    out: dict[str, Any] = {
        "id": int(room.room_id),
        "name": room.name,
        "polygon": np.asarray(room.floor_polygon, np.float64).tolist(),
    }
    if np.isfinite(room.z_min):
        out["z_min"] = float(room.z_min)
    if np.isfinite(room.z_max):
        out["z_max"] = float(room.z_max)
    return out
