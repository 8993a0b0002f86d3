"""Replica scenes: ``mesh_semantic.ply`` with ``info_semantic.json`` (in the scene's
``habitat/`` folder).

Fields used: PLY vertex ``x, y, z``; face ``vertex_indices`` (Replica's are quads) and
``object_id``; ``info_semantic.json`` ``objects`` (``id``, ``class_name``, or ``class_id``
looked up in ``classes`` (``id``, ``name``)). Objects of class ``undefined`` or without an
entry are unlabelled. Replica scenes have no rooms.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from care_maps.core.errors import GroundTruthError
from care_maps.truth.formats.common import (
    face_array,
    face_property,
    field,
    from_labelled_points,
    read_json,
    read_ply,
    vertex_labels_from_faces,
    vertices_xyz,
    write_ply,
    write_text,
)
from care_maps.truth.model import GroundTruth

__all__ = ["read_replica", "replica_files", "write_replica"]

UNDEFINED = ("undefined", "")


def replica_files(path: Path) -> tuple[Path, Path]:
    """``(mesh_semantic.ply, info_semantic.json)`` of the scene ``path`` names (either file,
    the ``habitat`` folder or the scene folder)."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    if (folder / "habitat" / "mesh_semantic.ply").is_file():
        folder = folder / "habitat"
    return folder / "mesh_semantic.ply", folder / "info_semantic.json"


def read_replica(path: Path) -> GroundTruth:
    """Ground truth of a Replica scene (see the module docstring)."""
    mesh, info_path = replica_files(path)
    info = read_json(info_path, "Replica semantic info")
    objects = field(info, "objects", info_path, list)
    classes = {c.get("id"): c.get("name") for c in info.get("classes") or [] if isinstance(c, dict)}
    class_of: dict[int, str] = {}
    for n, obj in enumerate(objects):
        oid = field(obj, "id", info_path, int)
        name = obj.get("class_name") or classes.get(obj.get("class_id"))
        if name is None:
            msg = (
                f"{info_path}: objects[{n}] (id {oid}) has neither class_name nor a known class_id"
            )
            raise GroundTruthError(msg)
        if str(name) not in UNDEFINED and oid > 0:
            class_of[oid] = str(name)
    ply = read_ply(mesh)
    xyz = vertices_xyz(ply, mesh)
    faces = face_array(ply, mesh)
    object_id = face_property(ply, mesh, "object_id").astype(np.int64)
    inst = vertex_labels_from_faces(len(xyz), faces, object_id, mesh)
    return from_labelled_points(
        xyz, inst, class_of, path=mesh, frame="replica",
        info={"format": "replica", "files": [mesh.name, info_path.name]},
    )  # fmt: skip


def write_replica(gt: GroundTruth, folder: Path) -> list[Path]:
    """Write ``gt`` as a Replica ``habitat`` folder: each point a vertex of its own degenerate
    quad, the quad's ``object_id`` its instance, and the objects and classes in
    ``info_semantic.json``."""
    from plyfile import PlyElement

    mesh, info_path = Path(folder) / "mesh_semantic.ply", Path(folder) / "info_semantic.json"
    pts = np.asarray(gt.points, np.float32).reshape(-1, 3)
    vertex = np.zeros(
        len(pts),
        [
            ("x", "f4"),
            ("y", "f4"),
            ("z", "f4"),
            ("nx", "f4"),
            ("ny", "f4"),
            ("nz", "f4"),
            ("red", "u1"),
            ("green", "u1"),
            ("blue", "u1"),
        ],
    )
    vertex["x"], vertex["y"], vertex["z"] = pts.T
    face = np.zeros(len(pts), [("vertex_indices", "i4", (4,)), ("object_id", "i4")])
    face["vertex_indices"] = np.repeat(np.arange(len(pts))[:, None], 4, axis=1)
    face["object_id"] = gt.point_instance
    write_ply(
        mesh,
        [
            PlyElement.describe(vertex, "vertex"),
            PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"}),
        ],
    )
    names = sorted(set(gt.instances.column("class_name").to_pylist()))
    classes = [{"id": 0, "name": "undefined"}] + [
        {"id": i + 1, "name": n} for i, n in enumerate(names)
    ]
    objects = [
        {"id": int(i), "class_id": names.index(n) + 1, "class_name": n}
        for i, n in zip(
            gt.instance_ids.tolist(), gt.instances.column("class_name").to_pylist(), strict=True
        )
    ]
    ids = np.zeros(int(max(gt.instance_ids.max(initial=0), 0)) + 1, np.int64)
    for o in objects:
        ids[o["id"]] = o["class_id"]
    doc = {"classes": classes, "objects": objects, "id_to_label": ids.tolist()}
    write_text(info_path, json.dumps(doc, indent=1))
    return [mesh, info_path]
