"""ScanNet (v2) scans: ``<scene>_vh_clean_2.ply``, ``<scene>_vh_clean_2.0.010000.segs.json`` and
``<scene>.aggregation.json`` (or ``<scene>_vh_clean.aggregation.json``), as ScanNet ships
them in ``scans/<scene>/``.

Fields used: the PLY's vertex ``x, y, z`` (colours, faces ignored); the segs file's
``segIndices`` (one over-segment id per vertex); the aggregation's ``segGroups``, each an
object with ``objectId`` (instance = objectId + 1), ``label`` (the annotator's raw class
name; map it with ``--gt-class-map scannetv2-labels.combined.tsv:raw_category:nyu40class``)
and ``segments``. A vertex in two groups takes the later one, as ScanNet's own export does.
Points are in the scan's frame (``axisAlignment`` of ``<scene>.txt`` is not applied: use
``--gt-transform``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from care_maps.core.errors import GroundTruthError
from care_maps.truth.formats.common import (
    field,
    from_labelled_points,
    read_json,
    read_ply,
    vertices_xyz,
    write_ply,
    write_text,
)
from care_maps.truth.model import GroundTruth

__all__ = ["SEGS_SUFFIX", "read_scannet", "scannet_files", "write_scannet"]

MESH_SUFFIX = "_vh_clean_2.ply"
SEGS_SUFFIX = "_vh_clean_2.0.010000.segs.json"
AGG_SUFFIXES = (".aggregation.json", "_vh_clean.aggregation.json")


def scannet_files(path: Path) -> tuple[Path, Path, Path]:
    """``(mesh, segs, aggregation)`` of the scene that ``path`` (any of its files, or its
    directory) belongs to."""
    path = Path(path)
    if path.is_dir():
        meshes = sorted(path.glob(f"*{MESH_SUFFIX}"))
        if not meshes:
            msg = f"{path}: no *{MESH_SUFFIX} in this directory (a ScanNet scene has one)"
            raise GroundTruthError(msg)
        path = meshes[0]
    name = path.name
    for suffix in (MESH_SUFFIX, SEGS_SUFFIX, *AGG_SUFFIXES):
        if name.endswith(suffix):
            scene = name[: -len(suffix)]
            break
    else:
        msg = f"{path}: not a ScanNet file name (<scene>{MESH_SUFFIX}, <scene>{SEGS_SUFFIX}, <scene>.aggregation.json)"
        raise GroundTruthError(msg)
    folder = path.parent
    aggs = [folder / f"{scene}{s}" for s in AGG_SUFFIXES]
    agg = next((p for p in aggs if p.is_file()), aggs[0])
    return folder / f"{scene}{MESH_SUFFIX}", folder / f"{scene}{SEGS_SUFFIX}", agg


def read_scannet(path: Path) -> GroundTruth:
    """Ground truth of a ScanNet scene (see the module docstring)."""
    mesh, segs_path, agg_path = scannet_files(path)
    ply = read_ply(mesh)
    xyz = vertices_xyz(ply, mesh)
    segs = field(read_json(segs_path, "ScanNet over-segmentation"), "segIndices", segs_path, list)
    if len(segs) != len(xyz):
        msg = f"{segs_path}: {len(segs)} segIndices for {len(xyz)} vertices of {mesh.name}"
        raise GroundTruthError(msg)
    seg_of_vertex = np.asarray(segs, np.int64)
    groups = field(read_json(agg_path, "ScanNet aggregation"), "segGroups", agg_path, list)
    inst = np.zeros(len(xyz), np.int64)
    class_of: dict[int, str] = {}
    for n, group in enumerate(groups):
        object_id = (
            field(group, "objectId", agg_path, int)
            if "objectId" in group
            else field(group, "id", agg_path, int)
        )
        label = field(group, "label", agg_path, str)
        segments = np.asarray(field(group, "segments", agg_path, list), np.int64)
        if not label.strip():
            msg = f"{agg_path}: segGroups[{n}] has an empty label"
            raise GroundTruthError(msg)
        class_of[object_id + 1] = label
        inst[np.isin(seg_of_vertex, segments)] = object_id + 1
    return from_labelled_points(
        xyz, inst, class_of, path=agg_path, frame="scannet",
        info={"format": "scannet", "files": [mesh.name, segs_path.name, agg_path.name]},
    )  # fmt: skip


def write_scannet(gt: GroundTruth, folder: Path, scene: str) -> list[Path]:
    """Write ``gt`` as a ScanNet scene: a vertex-only ``_vh_clean_2.ply`` (with ScanNet's vertex
    properties), one over-segment per instance (structure is segment 0, in no group), and the
    aggregation of those segments."""
    from plyfile import PlyElement

    folder = Path(folder)
    mesh, segs_path, agg_path = (
        folder / f"{scene}{MESH_SUFFIX}", folder / f"{scene}{SEGS_SUFFIX}", folder / f"{scene}.aggregation.json",
    )  # fmt: skip
    pts = np.asarray(gt.points, np.float32).reshape(-1, 3)
    props = [
        ("x", "f4"),
        ("y", "f4"),
        ("z", "f4"),
        ("red", "u1"),
        ("green", "u1"),
        ("blue", "u1"),
        ("alpha", "u1"),
    ]
    vertex = np.zeros(len(pts), props)
    vertex["x"], vertex["y"], vertex["z"] = pts.T
    vertex["red"] = vertex["green"] = vertex["blue"] = 128
    vertex["alpha"] = 255
    face = np.zeros(0, [("vertex_indices", "i4", (3,))])
    write_ply(
        mesh,
        [
            PlyElement.describe(vertex, "vertex"),
            PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"}),
        ],
    )
    seg = np.asarray(gt.point_instance, np.int64)
    write_text(
        segs_path,
        json.dumps(
            {
                "params": {"kThresh": "0.0001", "segMinVerts": "20"},
                "sceneId": scene,
                "segIndices": seg.tolist(),
            }
        ),
    )
    groups = [
        {"id": int(i) - 1, "objectId": int(i) - 1, "segments": [int(i)], "label": name}
        for i, name in zip(
            gt.instance_ids.tolist(), gt.instances.column("class_name").to_pylist(), strict=True
        )
    ]
    doc = {
        "sceneId": f"scannet.{scene}",
        "appId": "care.world",
        "segGroups": groups,
        "segmentsFile": f"scannet.{segs_path.name}",
    }
    write_text(agg_path, json.dumps(doc, indent=1))
    return [mesh, segs_path, agg_path]
