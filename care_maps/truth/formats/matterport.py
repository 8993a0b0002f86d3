"""Matterport3D houses: region (or house) segmentation meshes, their ``.fsegs.json`` and
``.semseg.json``, and the ``.house`` file's regions as rooms.

Layout read (``<house>/`` as unpacked from the dataset)::

    <house>/region_segmentations/region<i>.ply|.fsegs.json|.semseg.json
    <house>/house_segmentations/<house>.house          (optional: room polygons and names)
    <house>/house_segmentations/<house>.ply|.fsegs.json|.semseg.json   (used if no regions)

Fields used: PLY vertex ``x, y, z``; face ``vertex_indices`` and ``category_id`` (an index
into ``category_mapping.tsv``, used only for a segGroup without a ``label``); ``fsegs.json``
``segIndices`` (segment of each face); ``semseg.json`` ``segGroups`` (``id``, ``label``: the
raw category, ``segments``). Each region is a room: from the ``.house`` file its ``R`` line
(label letter -> room type, height band ``zlo..zhi``) and the polygon of its ``S``/``V``
lines; without a ``.house`` file the convex hull of the region's vertices and their height
range. ``category_mapping.tsv`` is looked for in the house directory and its parents.
"""

from __future__ import annotations

import csv
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
from care_maps.truth.geometry import _hull
from care_maps.truth.model import GroundTruth, Room

__all__ = ["CATEGORY_MAPPING", "ROOM_TYPES", "read_matterport", "write_matterport"]

CATEGORY_MAPPING = "category_mapping.tsv"
"""Matterport3D's class table, looked for in the house folder and its parents."""

ROOM_TYPES = {
    "a": "bathroom", "b": "bedroom", "c": "closet", "d": "dining room", "e": "entryway",
    "f": "familyroom", "g": "garage", "h": "hallway", "i": "library", "j": "laundryroom",
    "k": "kitchen", "l": "living room", "m": "meetingroom", "n": "lounge", "o": "office",
    "p": "porch", "r": "rec", "s": "stairs", "t": "toilet", "u": "utilityroom", "v": "tv",
    "w": "workout", "x": "outdoor", "y": "balcony", "z": "other room", "B": "bar",
    "C": "classroom", "D": "dining booth", "S": "spa", "Z": "junk", "-": "no label",
}  # fmt: skip
"""Region label letters of the ``.house`` file (Matterport's data_organization.md)."""


def _house_dir(path: Path) -> Path:
    path = Path(path)
    if path.is_file():
        path = path.parent
    if path.name in ("region_segmentations", "house_segmentations"):
        path = path.parent
    if not (path / "region_segmentations").is_dir() and not (path / "house_segmentations").is_dir():
        msg = f"{path}: not a Matterport3D house (no region_segmentations/ or house_segmentations/)"
        raise GroundTruthError(msg)
    return path


def _meshes(house: Path) -> list[Path]:
    regions = sorted(
        (house / "region_segmentations").glob("region*.ply"),
        key=lambda p: int("".join(c for c in p.stem if c.isdigit()) or 0),
    )
    if regions:
        return regions
    meshes = sorted((house / "house_segmentations").glob("*.ply"))
    if not meshes:
        msg = f"{house}: no region_segmentations/region*.ply nor house_segmentations/*.ply"
        raise GroundTruthError(msg)
    return meshes[:1]


def _category_names(house: Path) -> dict[int, str]:
    for folder in (house, *house.parents):
        tsv = folder / CATEGORY_MAPPING
        if tsv.is_file():
            with tsv.open(newline="") as fh:
                return {
                    int(r["index"]): r.get("raw_category") or r.get("category") or ""
                    for r in csv.DictReader(fh, delimiter="\t")
                    if (r.get("index") or "").strip().isdigit()
                }
    return {}


def _read_house(house: Path) -> dict[int, Room]:
    """Rooms (by region index) from ``house_segmentations/<house>.house``, if present."""
    files = sorted((house / "house_segmentations").glob("*.house"))
    if not files:
        return {}
    path = files[0]
    regions: dict[int, tuple[str, float, float]] = {}
    surface_region: dict[int, int] = {}
    polygon: dict[int, list[tuple[float, float]]] = {}
    try:
        for line in path.read_text().splitlines():
            f = line.split()
            if not f:
                continue
            if f[0] == "R":  # R region_index level_index 0 0 label px py pz xlo ylo zlo xhi yhi zhi
                regions[int(f[1])] = (f[5], float(f[11]), float(f[14]))
            elif f[0] == "S":  # S surface_index region_index 0 label px py pz nx ny nz ...
                surface_region[int(f[1])] = int(f[2])
            elif f[0] == "V":  # V vertex_index surface_index label px py pz nx ny nz 0 0 0
                region = surface_region.get(int(f[2]))
                if region is not None:
                    polygon.setdefault(region, []).append((float(f[4]), float(f[5])))
    except (IndexError, ValueError) as err:
        msg = f"{path}: malformed line ({err}); see Matterport's data_organization.md"
        raise GroundTruthError(msg) from err
    return {
        i: Room(i, ROOM_TYPES.get(label, label.replace("_", " ")), np.asarray(polygon[i]), zlo, zhi)
        for i, (label, zlo, zhi) in regions.items()
        if len(polygon.get(i, [])) >= 3
    }


def read_matterport(path: Path) -> GroundTruth:
    """Ground truth of a Matterport3D house (see the module docstring)."""
    house = _house_dir(path)
    meshes = _meshes(house)
    house_rooms = _read_house(house)
    categories: dict[int, str] | None = None
    class_of: dict[int, str] = {}
    all_xyz, all_inst, room_of_instance, rooms = [], [], {}, []
    used: set[int] = set()
    for region, mesh in enumerate(meshes):
        stem = mesh.with_suffix("")
        fsegs_path, semseg_path = Path(f"{stem}.fsegs.json"), Path(f"{stem}.semseg.json")
        ply = read_ply(mesh)
        xyz = vertices_xyz(ply, mesh)
        faces = face_array(ply, mesh)
        seg_of_face = np.asarray(
            field(
                read_json(fsegs_path, "Matterport face segments"), "segIndices", fsegs_path, list
            ),
            np.int64,
        )
        if len(seg_of_face) != len(faces):
            msg = (
                f"{fsegs_path}: {len(seg_of_face)} segIndices for {len(faces)} faces of {mesh.name}"
            )
            raise GroundTruthError(msg)
        groups = field(
            read_json(semseg_path, "Matterport object segmentation"), "segGroups", semseg_path, list
        )
        face_inst = np.zeros(len(faces), np.int64)
        category = None
        for n, group in enumerate(groups):
            gid = int(field(group, "id", semseg_path, int)) + 1
            if gid in used:  # ids restart in every region: keep them unique over the house
                gid = max(used | set(class_of)) + 1
            used.add(gid)
            label = group.get("label")
            members = np.isin(
                seg_of_face, np.asarray(field(group, "segments", semseg_path, list), np.int64)
            )
            if not label:
                if category is None:
                    category = face_property(ply, mesh, "category_id").astype(np.int64)
                if categories is None:
                    categories = _category_names(house)
                ids = np.unique(category[members])
                label = categories.get(int(ids[0])) if len(ids) else None
                if not label:
                    msg = f"{semseg_path}: segGroups[{n}] has no label and no category_mapping.tsv names its category_id"
                    raise GroundTruthError(msg)
            class_of[gid] = str(label)
            room_of_instance[gid] = region
            face_inst[members] = gid
        all_inst.append(vertex_labels_from_faces(len(xyz), faces, face_inst, mesh))
        all_xyz.append(xyz)
        room = house_rooms.get(region)
        if room is None and len(xyz) >= 3:
            hull = _hull(xyz[:, :2].astype(np.float64))
            room = (
                Room(
                    region, f"region{region}", hull, float(xyz[:, 2].min()), float(xyz[:, 2].max())
                )
                if len(hull) >= 3
                else None
            )
        if (room is not None and len(meshes) > 1) or (room is not None and house_rooms):
            rooms.append(room)
    if len(meshes) == 1 and not house_rooms:
        room_of_instance = {}
    return from_labelled_points(
        np.concatenate(all_xyz), np.concatenate(all_inst), class_of, path=house,
        rooms=rooms, room_of_instance=room_of_instance if rooms else None, frame="matterport",
        info={"format": "matterport", "files": [str(m.relative_to(house)) for m in meshes]},
    )  # fmt: skip


def write_matterport(gt: GroundTruth, house: Path, name: str) -> list[Path]:
    """Write ``gt`` as a Matterport3D house: one region per room (its instances' points and the
    structure inside it; structure outside every room goes to region 0), a ``.house`` file
    with the rooms' polygons and height bands, and ``category_mapping.tsv`` naming the
    classes. Every point is a vertex of its own degenerate triangle, so it keeps its bits."""
    from plyfile import PlyElement

    house = Path(house)
    written = []
    pts = np.asarray(gt.points, np.float32).reshape(-1, 3)
    inst = np.asarray(gt.point_instance, np.int64)
    rooms = gt.rooms or []
    room_index = {r.room_id: n for n, r in enumerate(rooms)}
    inst_room = dict(
        zip(gt.instance_ids.tolist(), gt.instances.column("room_id").to_pylist(), strict=True)
    )
    point_room = (
        np.array([room_index.get(inst_room.get(int(i), -1), -1) for i in inst], np.int64)
        if len(inst)
        else np.zeros(0, np.int64)
    )
    if rooms:
        struct = point_room < 0
        rid = gt.room_of(pts[struct, :2])
        point_room[struct] = [room_index.get(int(r), 0) for r in rid]
    point_room = np.maximum(point_room, 0)
    names = dict(
        zip(gt.instance_ids.tolist(), gt.instances.column("class_name").to_pylist(), strict=True)
    )
    cat_index = {n: i + 1 for i, n in enumerate(sorted(set(names.values())))}
    for region in range(max(len(rooms), 1)):
        sel = np.flatnonzero(point_room == region)
        stem = house / "region_segmentations" / f"region{region}"
        vertex = np.zeros(
            len(sel),
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
        vertex["x"], vertex["y"], vertex["z"] = pts[sel].T
        vertex["nz"] = 1.0
        face = np.zeros(
            len(sel),
            [
                ("vertex_indices", "i4", (3,)),
                ("material_id", "i4"),
                ("segment_id", "i4"),
                ("category_id", "i4"),
            ],
        )
        face["vertex_indices"] = np.repeat(np.arange(len(sel))[:, None], 3, axis=1)
        face["segment_id"] = inst[sel]
        face["category_id"] = [cat_index.get(names.get(int(i), ""), 0) for i in inst[sel]]
        write_ply(
            Path(f"{stem}.ply"),
            [
                PlyElement.describe(vertex, "vertex"),
                PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"}),
            ],
        )
        write_text(Path(f"{stem}.fsegs.json"), json.dumps({"segIndices": inst[sel].tolist()}))
        here = sorted({int(i) for i in inst[sel] if i > 0 and int(i) in names})
        groups = [
            {"id": i - 1, "objectId": i - 1, "label": names[i], "segments": [i]} for i in here
        ]
        write_text(Path(f"{stem}.semseg.json"), json.dumps({"segGroups": groups}, indent=1))
        written += [Path(f"{stem}.ply"), Path(f"{stem}.fsegs.json"), Path(f"{stem}.semseg.json")]
    letters = {v: k for k, v in ROOM_TYPES.items()}
    lines = [
        f"ASCII 1.1\nH {name} - 0 0 0 0 0 0 0 {len(rooms)} 0 1  0 0 0 0 0  0 0 0 0 0 0  0 0 0 0 0"
    ]
    vertex_lines: list[str] = []
    surfaces: list[str] = []
    for n, r in enumerate(rooms):
        poly = np.asarray(r.floor_polygon)
        zlo = r.z_min if np.isfinite(r.z_min) else -1e3
        zhi = r.z_max if np.isfinite(r.z_max) else 1e3
        lo, hi = poly.min(axis=0), poly.max(axis=0)
        label = letters.get(r.name, r.name.replace(" ", "_") or "-")
        lines.append(
            f"R {n} 0 0 0 {label}  0 0 0  {lo[0]!r} {lo[1]!r} {zlo!r} {hi[0]!r} {hi[1]!r} {zhi!r}  0 0 0 0 0"
        )
        surfaces.append(
            f"S {n} {n} 0 floor 0 0 0  0 0 1  {lo[0]!r} {lo[1]!r} {zlo!r} {hi[0]!r} {hi[1]!r} {zlo!r}  0 0 0 0 0"
        )
        vertex_lines += [
            f"V {len(vertex_lines) + k} {n} floor  {x!r} {y!r} {zlo!r}  0 0 1  0 0 0"
            for k, (x, y) in enumerate(poly.tolist())
        ]
    house_file = house / "house_segmentations" / f"{name}.house"
    write_text(house_file, "\n".join([*lines, *surfaces, *vertex_lines]) + "\n")
    tsv = house / CATEGORY_MAPPING
    rows = ["index\traw_category\tcategory"] + [
        f"{i}\t{n}\t{n}" for n, i in sorted(cat_index.items(), key=lambda kv: kv[1])
    ]
    write_text(tsv, "\n".join(rows) + "\n")
    return [*written, house_file, tsv]
