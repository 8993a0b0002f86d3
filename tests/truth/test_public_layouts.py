"""Readers against small files in the public datasets' documented layouts, built here from
their schemas (ScanNet's scans/<scene>/ files, Matterport3D's region_segmentations and .house,
Replica's habitat/ files), several written by other tools (Open3D, plyfile), with expectations
worked out by hand."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest
from plyfile import PlyData, PlyElement

from care_maps.core.errors import GroundTruthError
from care_maps.truth.geometry import box_floor_distance, points_in_box, yaw_rotation
from care_maps.truth.load import GtFormat, detect_format, read_class_map, read_ground_truth

LABELS = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "labels"

# ten vertices: four of a chair (segment 10), four + two of a table (segments 11, 12), and
# vertex 9 also in segment 12 (on the table)
XYZ = np.array(
    [[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0], [0.5, 0.5, 0.8],
     [2, 2, 0], [3, 2, 0], [2, 3, 0], [3, 3, 0.7], [2.5, 2.5, 0.7], [2.6, 2.6, 0.7]],
    np.float64,
)  # fmt: skip
SEGS = [10, 10, 10, 10, 11, 11, 11, 11, 12, 12]
FACES = [[0, 1, 2], [1, 2, 3], [4, 5, 6], [5, 6, 7], [6, 7, 8], [7, 8, 9]]


def _scannet_json(folder: Path, scene: str, groups: list[dict]) -> None:
    (folder / f"{scene}_vh_clean_2.0.010000.segs.json").write_text(
        json.dumps(
            {
                "params": {"kThresh": "0.0001", "segMinVerts": "20"},
                "sceneId": scene,
                "segIndices": SEGS,
            }
        )
    )
    agg = {"sceneId": f"scannet.{scene}", "appId": "Annotator.v1.0", "segGroups": groups,
           "segmentsFile": f"scannet.{scene}_vh_clean_2.0.010000.segs.json"}  # fmt: skip
    (folder / f"{scene}.aggregation.json").write_text(json.dumps(agg))


GROUPS = [
    {"id": 0, "objectId": 0, "segments": [10], "label": "office chair"},
    {"id": 1, "objectId": 1, "segments": [11, 12], "label": "table"},
]


def test_scannet_mesh_written_by_open3d(tmp_path: Path) -> None:
    scene = "scene0000_00"
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(XYZ), o3d.utility.Vector3iVector(FACES)
    )
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.full((10, 3), 0.5))
    assert o3d.io.write_triangle_mesh(str(tmp_path / f"{scene}_vh_clean_2.ply"), mesh)
    _scannet_json(tmp_path, scene, GROUPS)
    gt = read_ground_truth(tmp_path / f"{scene}_vh_clean_2.ply")
    assert gt.frame == "scannet"
    assert gt.instance_class_names() == {1: "office chair", 2: "table"}
    np.testing.assert_array_equal(gt.point_instance, [1, 1, 1, 1, 2, 2, 2, 2, 2, 2])
    np.testing.assert_allclose(
        gt.instances.column("bbox_max").to_pylist()[1], [3, 3, 0.7], atol=1e-6
    )
    # the ScanNet label table maps the raw category to NYU40
    mapping = read_class_map(f"{LABELS / 'scannetv2-labels.combined.tsv'}:raw_category:nyu40class")
    renamed = read_ground_truth(tmp_path, class_map=mapping)
    assert sorted(renamed.instance_class_names().values()) == ["chair", "table"]


def test_scannet_binary_ply_with_scannet_vertex_properties(tmp_path: Path) -> None:
    """plyfile writes ScanNet's exact vertex layout (x, y, z float; red, green, blue, alpha
    uchar) and faces; a vertex in two groups takes the later group, as ScanNet's export."""
    scene = "scene0707_00"
    vertex = np.zeros(
        10,
        [
            ("x", "f4"),
            ("y", "f4"),
            ("z", "f4"),
            ("red", "u1"),
            ("green", "u1"),
            ("blue", "u1"),
            ("alpha", "u1"),
        ],
    )
    vertex["x"], vertex["y"], vertex["z"] = XYZ.T
    face = np.array([(f,) for f in FACES], [("vertex_indices", "i4", (3,))])
    PlyData(
        [
            PlyElement.describe(vertex, "vertex"),
            PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"}),
        ]
    ).write(str(tmp_path / f"{scene}_vh_clean_2.ply"))
    groups = [*GROUPS, {"id": 2, "objectId": 2, "segments": [12], "label": "box"}]
    _scannet_json(tmp_path, scene, groups)
    gt = read_ground_truth(tmp_path / f"{scene}.aggregation.json")
    np.testing.assert_array_equal(gt.point_instance, [1, 1, 1, 1, 2, 2, 2, 2, 3, 3])
    assert detect_format(tmp_path) is GtFormat.SCANNET


def test_scannet_missing_field_and_count_mismatch(tmp_path: Path) -> None:
    scene = "scene0001_00"
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(XYZ), o3d.utility.Vector3iVector(FACES)
    )
    o3d.io.write_triangle_mesh(str(tmp_path / f"{scene}_vh_clean_2.ply"), mesh)
    _scannet_json(tmp_path, scene, [{"id": 0, "objectId": 0, "segments": [10]}])
    with pytest.raises(GroundTruthError, match="missing field 'label'"):
        read_ground_truth(tmp_path)
    (tmp_path / f"{scene}_vh_clean_2.0.010000.segs.json").write_text(
        json.dumps({"segIndices": [1, 2]})
    )
    with pytest.raises(GroundTruthError, match="2 segIndices for 10 vertices"):
        read_ground_truth(tmp_path)


def _region(
    folder: Path, index: int, offset: np.ndarray, groups: list[dict], category: list[int]
) -> None:
    vertex = np.zeros(
        10,
        [
            ("x", "f4"),
            ("y", "f4"),
            ("z", "f4"),
            ("nx", "f4"),
            ("ny", "f4"),
            ("nz", "f4"),
            ("tx", "f4"),
            ("ty", "f4"),
        ],
    )
    pts = XYZ + offset
    vertex["x"], vertex["y"], vertex["z"] = pts.T
    face = np.zeros(
        len(FACES),
        [
            ("vertex_indices", "i4", (3,)),
            ("material_id", "i4"),
            ("segment_id", "i4"),
            ("category_id", "i4"),
        ],
    )
    face["vertex_indices"] = FACES
    face["category_id"] = category
    stem = folder / "region_segmentations" / f"region{index}"
    stem.parent.mkdir(parents=True, exist_ok=True)
    PlyData(
        [
            PlyElement.describe(vertex, "vertex"),
            PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"}),
        ]
    ).write(f"{stem}.ply")
    # face segments: faces 0-1 segment 5, faces 2-5 segment 6
    Path(f"{stem}.fsegs.json").write_text(json.dumps({"segIndices": [5, 5, 6, 6, 6, 6]}))
    Path(f"{stem}.semseg.json").write_text(json.dumps({"segGroups": groups}))


def test_matterport_house_regions_are_rooms(tmp_path: Path) -> None:
    house = tmp_path / "17DRP5sb8fy"
    _region(house, 0, np.zeros(3), [{"id": 0, "objectId": 0, "label": "chair", "segments": [5]},
                                    {"id": 1, "objectId": 1, "label": "table", "segments": [6]}], [0] * 6)  # fmt: skip
    # region 1 is upstairs (z + 3); its table group has no label: category_id 1 names it
    _region(house, 1, np.array([0, 0, 3.0]), [{"id": 0, "objectId": 0, "segments": [6]}], [1] * 6)
    shutil.copy(LABELS / "matterport_category_mapping.tsv", house / "category_mapping.tsv")
    (house / "house_segmentations").mkdir()
    (house / "house_segmentations" / "17DRP5sb8fy.house").write_text(
        "ASCII 1.1\nH 17DRP5sb8fy - 0 0 0 0 0 0 0 2 0 2  0 0 0 0 0  0 0 0 4 4 6  0 0 0 0 0\n"
        "R 0 0 0 0 k  1 1 0  -1 -1 -0.5 4 4 2.5  0 0 0 0 0\n"
        "R 1 1 0 0 b  1 1 3  -1 -1 2.5 4 4 5.5  0 0 0 0 0\n"
        "S 0 0 0 floor 0 0 0  0 0 1  -1 -1 0 4 4 0  0 0 0 0 0\n"
        "S 1 1 0 floor 0 0 3  0 0 1  -1 -1 3 4 4 3  0 0 0 0 0\n"
        + "".join(
            f"V {i} 0 floor  {x} {y} 0  0 0 1  0 0 0\n"
            for i, (x, y) in enumerate([(-1, -1), (4, -1), (4, 4), (-1, 4)])
        )
        + "".join(
            f"V {i + 4} 1 floor  {x} {y} 3  0 0 1  0 0 0\n"
            for i, (x, y) in enumerate([(-1, -1), (4, -1), (4, 4), (-1, 4)])
        )
    )
    gt = read_ground_truth(house)
    assert [(r.room_id, r.name, r.z_min, r.z_max) for r in gt.rooms] == [
        (0, "kitchen", -0.5, 2.5),
        (1, "bedroom", 2.5, 5.5),
    ]
    names = gt.instance_class_names()
    assert sorted(names.values()) == ["chair", "table", "wall"]  # category_mapping index 1 = wall
    rooms = dict(
        zip(gt.instance_ids.tolist(), gt.instances.column("room_id").to_pylist(), strict=True)
    )
    wall = next(i for i, n in names.items() if n == "wall")
    assert rooms[wall] == 1
    # the same floor position is a different room one storey up
    np.testing.assert_array_equal(gt.room_of(np.array([[1.0, 1.0, 0.5], [1.0, 1.0, 3.5]])), [0, 1])
    # vertices 0-3 (faces 0-1, segment 5) are the chair; 4-9 the table, in region 0
    assert (gt.point_instance[:4] == gt.point_instance[0]).all()
    assert names[int(gt.point_instance[0])] == "chair"
    assert detect_format(house / "region_segmentations" / "region0.ply") is GtFormat.MATTERPORT


def test_replica_quads_and_undefined_objects(tmp_path: Path) -> None:
    habitat = tmp_path / "room_0" / "habitat"
    habitat.mkdir(parents=True)
    vertex = np.zeros(
        10,
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
    vertex["x"], vertex["y"], vertex["z"] = XYZ.T
    quads = [[0, 1, 3, 2], [4, 5, 7, 6], [6, 7, 9, 8]]
    face = np.array(
        [(q, o) for q, o in zip(quads, [3, 7, 9], strict=True)],
        [("vertex_indices", "i4", (4,)), ("object_id", "i4")],
    )
    PlyData(
        [
            PlyElement.describe(vertex, "vertex"),
            PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"}),
        ]
    ).write(str(habitat / "mesh_semantic.ply"))
    info = {
        "classes": [{"id": 1, "name": "sofa"}, {"id": 2, "name": "rug"}],
        "objects": [{"id": 3, "class_id": 1, "class_name": "sofa"}, {"id": 7, "class_id": 2},
                    {"id": 9, "class_id": 0, "class_name": "undefined"}],
        "id_to_label": [0, 0, 0, 1, 0, 0, 0, 2, 0, 0],
    }  # fmt: skip
    (habitat / "info_semantic.json").write_text(json.dumps(info))
    gt = read_ground_truth(tmp_path / "room_0")
    assert gt.instance_class_names() == {3: "sofa", 7: "rug"}
    # vertices 6, 7 belong to quads of objects 7 and 9: the later (undefined) face wins
    np.testing.assert_array_equal(gt.point_instance, [3, 3, 3, 3, 7, 7, 0, 0, 0, 0])


def test_labelled_point_cloud_written_by_open3d(tmp_path: Path) -> None:
    pc = o3d.t.geometry.PointCloud(o3d.core.Tensor(XYZ.astype(np.float32)))
    pc.point["instance"] = o3d.core.Tensor(np.array([[1]] * 4 + [[2]] * 4 + [[0]] * 2, np.int32))
    pc.point["label"] = o3d.core.Tensor(np.array([[5]] * 4 + [[7]] * 4 + [[1]] * 2, np.int32))
    assert o3d.t.io.write_point_cloud(str(tmp_path / "office.ply"), pc)
    (tmp_path / "office.classes.tsv").write_text("id\tname\n1\twall\n5\tchair\n7\tdesk\n")
    gt = read_ground_truth(tmp_path / "office.ply")
    assert gt.instance_class_names() == {1: "chair", 2: "desk"}
    np.testing.assert_array_equal(gt.points, XYZ.astype(np.float32))


def test_corrupt_and_truncated_ply_are_one_error(tmp_path: Path) -> None:
    pc = o3d.t.geometry.PointCloud(o3d.core.Tensor(XYZ.astype(np.float32)))
    pc.point["instance"] = o3d.core.Tensor(np.ones((10, 1), np.int32))
    pc.point["label"] = o3d.core.Tensor(np.ones((10, 1), np.int32))
    o3d.t.io.write_point_cloud(str(tmp_path / "a.ply"), pc)
    data = (tmp_path / "a.ply").read_bytes()
    (tmp_path / "a.ply").write_bytes(data[: len(data) - 30])
    (tmp_path / "a.classes.json").write_text(json.dumps(["void", "chair"]))
    with pytest.raises(GroundTruthError, match="not a readable PLY"):
        read_ground_truth(tmp_path / "a.ply")
    (tmp_path / "b.ply").write_text("not a ply at all")
    with pytest.raises(GroundTruthError, match="not a readable PLY"):
        read_ground_truth(tmp_path / "b.ply")


def test_annotation_csv_without_header_yaml_with_rooms(tmp_path: Path) -> None:
    (tmp_path / "scan.annotations.csv").write_text(
        "chair,1,1,0.45,0.5,0.5,0.9,0.3,kitchen\nlamp,3,1,1,0.2,0.2,2\n"
    )
    (tmp_path / "scan.rooms.yaml").write_text(
        "rooms:\n  - {name: kitchen, polygon: [[0, 0], [2, 0], [2, 2], [0, 2]]}\n"
    )
    gt = read_ground_truth(tmp_path / "scan.annotations.csv")
    assert gt.instance_class_names() == {1: "chair", 2: "lamp"}
    assert gt.instances.column("room_id").to_pylist() == [0, -1]
    assert gt.box_only.all()
    rotation = gt.boxes()[2]
    np.testing.assert_allclose(rotation[0], yaw_rotation(0.3))
    yaml_doc = (
        "frame: map\nrooms:\n  - {name: hall, polygon: [[0, 0], [4, 0], [4, 2], [0, 2]], z_min: 0, z_max: 2.5}\n"
        "objects:\n  - {class: chair, center: [1, 1, 0.45], size: [0.5, 0.5, 0.9], yaw: 0.3}\n"
    )
    (tmp_path / "b.yaml").write_text(yaml_doc)
    gt = read_ground_truth(tmp_path / "b.yaml")
    assert gt.frame == "map"
    assert gt.rooms[0].z_max == 2.5
    assert gt.instances.column("room_id").to_pylist() == [0]


@pytest.mark.slow
def test_box_membership_and_floor_distance_against_brute_force() -> None:
    """A box turned by 30 degrees: membership by its own axes, and the floor distance to its
    footprint against the distance to a dense sampling of the footprint."""
    rng = np.random.default_rng(0)
    center, size, rot = (
        np.array([1.0, 2.0, 0.5]),
        np.array([2.0, 1.0, 1.0]),
        yaw_rotation(np.pi / 6),
    )
    pts = rng.uniform(-1, 4, (2000, 3))
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    d = pts - center
    u = c * d[:, 0] + s * d[:, 1]
    v = -s * d[:, 0] + c * d[:, 1]
    expected = (np.abs(u) <= 1) & (np.abs(v) <= 0.5) & (np.abs(d[:, 2]) <= 0.5)
    np.testing.assert_array_equal(points_in_box(pts, center, size, rot), expected)
    gu, gv = np.meshgrid(np.linspace(-1, 1, 401), np.linspace(-0.5, 0.5, 201))
    foot = np.c_[
        center[0] + c * gu.ravel() - s * gv.ravel(), center[1] + s * gu.ravel() + c * gv.ravel()
    ]
    xy = rng.uniform(-2, 5, (300, 2))
    ref = np.linalg.norm(xy[:, None] - foot[None], axis=2).min(axis=1)
    got = box_floor_distance(xy, center[None], size[None], rot[None])[:, 0]
    np.testing.assert_allclose(got, ref, atol=0.006)


def test_transform_from_numbers_npy_and_scannet_axis_alignment(tmp_path: Path) -> None:
    from care_maps.truth.load import parse_transform

    m = np.arange(16, dtype=float).reshape(4, 4)
    np.testing.assert_array_equal(parse_transform(",".join(map(str, m.ravel()))), m)
    np.save(tmp_path / "t.npy", m)
    np.testing.assert_array_equal(parse_transform(tmp_path / "t.npy"), m)
    # ScanNet's <scene>.txt meta file: one "axisAlignment = 16 numbers" line among others
    (tmp_path / "scene0000_00.txt").write_text(
        "colorHeight = 968\ncolorWidth = 1296\naxisAlignment = "
        + " ".join(map(str, m.ravel()))
        + "\nnumDepthFrames = 5578\n"
    )
    np.testing.assert_array_equal(parse_transform(tmp_path / "scene0000_00.txt"), m)
    with pytest.raises(GroundTruthError, match="give a 4x4"):
        parse_transform("1,2,3")


def test_points_in_nested_boxes_go_to_the_smallest() -> None:
    from care_maps.truth.geometry import label_points_by_boxes

    rng = np.random.default_rng(3)
    pts = rng.uniform(-1, 3, (5000, 3))
    center = np.array([[1.0, 1.0, 1.0], [1.2, 1.1, 1.0], [2.5, 0.0, 0.5]])
    size = np.array([[2.0, 2.0, 2.0], [0.5, 0.4, 0.3], [0.6, 0.6, 0.6]])
    rot = yaw_rotation(np.array([0.0, 0.7, -0.4]))
    got = label_points_by_boxes(pts, np.array([4, 5, 6]), center, size, rot)
    inside = [points_in_box(pts, c, s, r) for c, s, r in zip(center, size, rot, strict=True)]
    expected = np.where(inside[1], 5, np.where(inside[2], 6, np.where(inside[0], 4, 0)))
    np.testing.assert_array_equal(got, expected)
