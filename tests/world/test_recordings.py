"""Rendered recordings: read back through ingest's readers in every format, depth on the
ground-truth surfaces, labels consistent with the ground truth, trajectory through every room."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from care_maps.geometry.transforms import backproject, transform_points
from care_maps.ingest.source import RecordingFrames
from care_maps.truth.formats.native import read_native
from care_maps.world.scene import NAV_CELL
from care_maps.world.trajectory import plan_trajectory


def _read(path: Path) -> list:
    with RecordingFrames(path) as frames:
        return list(frames)


def test_trajectory_visits_every_room_inside_the_navigation_zone(tiny_scene) -> None:
    scene, poses = tiny_scene
    gt = scene.ground_truth()
    xy = poses[:, :2, 3]
    assert set(gt.room_of(xy).tolist()) == {r.room_id for r in scene.rooms}
    cells = np.floor((xy - scene.nav_origin) / NAV_CELL).astype(int)
    assert scene.nav_mask[cells[:, 0], cells[:, 1]].all()
    np.testing.assert_allclose(poses[:, 2, 3], 1.5)
    # optical frame: proper rotations, y axis (down) pointing below the horizon
    R = poses[:, :3, :3]
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
    assert (R[:, 2, 1] < 0).all()
    # smooth: sampled densely, neither position nor heading jumps between frames
    dense = plan_trajectory(scene, 300)
    assert np.linalg.norm(np.diff(dense[:, :2, 3], axis=0), axis=1).max() < 0.15
    cos = np.sum(dense[1:, :3, 2] * dense[:-1, :3, 2], axis=1)
    assert np.arccos(np.clip(cos, -1, 1)).max() < 0.25
    # looking around: the gaze covers every direction
    yaw = np.arctan2(dense[:, 1, 2], dense[:, 0, 2])
    assert len(np.unique(np.floor((yaw + np.pi) / (np.pi / 4)))) == 8


@pytest.mark.slow
@pytest.mark.parametrize("fmt", ["mcap", "ros2", "ros1"])
def test_every_format_ingests_alike(tiny_recordings: dict[str, Path], tiny_scene, fmt: str) -> None:
    _, poses = tiny_scene
    frames = _read(tiny_recordings[fmt])
    reference = _read(tiny_recordings["mcap"])
    assert len(frames) == len(poses)
    for f, ref, T in zip(frames, reference, poses, strict=True):
        np.testing.assert_allclose(f.cam_to_world, T, atol=1e-6)
        np.testing.assert_array_equal(f.depth_m, ref.depth_m)
        np.testing.assert_array_equal(f.rgb, ref.rgb)
        np.testing.assert_array_equal(f.extras["instance"], ref.extras["instance"])
        np.testing.assert_array_equal(f.extras["class"], ref.extras["class"])
    with RecordingFrames(tiny_recordings[fmt]) as rf:
        assert rf.label_names == read_native(tiny_recordings[fmt]).class_names


@pytest.mark.slow
def test_depth_lands_on_ground_truth_surfaces(tiny_recordings: dict[str, Path], tiny_scene) -> None:
    scene, _ = tiny_scene
    gt = read_native(tiny_recordings["mcap"])
    mesh = scene.mesh
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(
        o3d.core.Tensor(mesh.vertices.astype(np.float32)),
        o3d.core.Tensor(mesh.triangles.astype(np.uint32)),
    )
    to_points, to_mesh, agree = [], [], []
    for f in _read(tiny_recordings["ros2"]):
        pts, pix = backproject(f.depth_m, f.K)
        world = transform_points(f.cam_to_world, pts)
        to_points.append(gt._tree.query(world)[0])
        to_mesh.append(rc.compute_distance(o3d.core.Tensor(world.astype(np.float32))).numpy())
        inst = f.extras["instance"][pix[:, 1], pix[:, 0]]
        agree.append(gt.label_points(world, max_dist=0.05) == inst)
    assert np.median(np.concatenate(to_points)) < 0.01
    assert np.median(np.concatenate(to_mesh)) < 0.01
    assert np.quantile(np.concatenate(to_mesh), 0.99) < 0.01  # mm depth quantisation only
    assert np.mean(np.concatenate(agree)) > 0.97


def test_labels_and_unseen_report(tiny_recordings: dict[str, Path]) -> None:
    gt = read_native(tiny_recordings["mcap"])
    frames = _read(tiny_recordings["mcap"])
    seen: Counter[int] = Counter()
    for f in frames:
        ids, counts = np.unique(f.extras["instance"], return_counts=True)
        seen.update(dict(zip(ids.tolist(), counts.tolist(), strict=True)))
        # class image = class of the instance (structure: wall/floor/ceiling with instance 0)
        cls = f.extras["class"]
        inst = f.extras["instance"]
        table = dict(zip(gt.instance_ids.tolist(), gt.instance_class_ids.tolist(), strict=True))
        lut = np.zeros(max(table) + 1, np.int64)
        lut[list(table)] = list(table.values())
        objects = inst > 0
        np.testing.assert_array_equal(cls[objects], lut[inst[objects]])
        assert set(np.unique(cls[~objects]).tolist()) <= {1, 2, 3}
    unseen = {i for i in gt.instance_ids.tolist() if seen[i] < 20}
    assert unseen == set(gt.info["unseen_instances"])
    assert gt.info["num_frames"] == len(frames)


def test_rerun_reads_the_mcap_natively(tiny_recordings: dict[str, Path]) -> None:
    from rerun.chunk import McapReader

    rows: Counter[tuple[str, str]] = Counter()
    for chunk in McapReader(tiny_recordings["mcap"]).stream():
        for name in chunk.to_record_batch().schema.names:
            rows[(str(chunk.entity_path), name)] += chunk.num_rows
    n = len(_read(tiny_recordings["mcap"]))
    assert rows[("/camera/color/image_raw", "Image:buffer")] == n
    assert rows[("/camera/depth/image_raw", "DepthImage:buffer")] == n
    assert rows[("/camera/color/camera_info", "Pinhole:image_from_camera")] == n
