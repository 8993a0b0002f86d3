"""Pose sources as robots publish them: the camera's mount chain (base_link -> camera_link
-> camera_color_optical_frame) sent once on ``/tf`` rather than ``/tf_static`` (as many
drivers and ``static_transform_publisher`` replays do), at the start or at the end of the
recording, or again with every frame, with the motion on ``nav_msgs/Odometry``. Written
through rosbags from the third-party living-room frames; every view's pose must equal the
frames' own trajectory (1e-6), where before all but one view were dropped as unposed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ingest.source import ReadOptions, RecordingFrames

OPTICAL = "camera_color_optical_frame"
LINK_TO_OPTICAL_XYZW = (-0.5, 0.5, -0.5, 0.5)  # REP 103: camera_link -> optical
BASE_TO_LINK_XYZ = (0.12, -0.03, 0.45)
BASE_TO_LINK_XYZW = tuple(Rotation.from_euler("y", 8, degrees=True).as_quat())


def _matrix(xyz, xyzw) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(xyzw).as_matrix()
    T[:3, 3] = xyz
    return T


def _bag(tmp_path: Path, h, frames, chain_at: str) -> Path:
    base_to_optical = _matrix(BASE_TO_LINK_XYZ, BASE_TO_LINK_XYZW) @ _matrix(
        (0.0, 0.0, 0.0), LINK_TO_OPTICAL_XYZW
    )

    def chain(t: int) -> list:
        return [
            (
                "/tf",
                t,
                h.tf_msg(t, "base_link", "camera_link", BASE_TO_LINK_XYZ, BASE_TO_LINK_XYZW),
            ),
            ("/tf", t, h.tf_msg(t, "camera_link", OPTICAL, (0.0, 0.0, 0.0), LINK_TO_OPTICAL_XYZW)),
        ]

    stamps = [f.stamp_ns for f in frames]
    msgs = []
    if chain_at == "start":
        msgs += chain(stamps[0])
    elif chain_at == "end":
        msgs += chain(stamps[-1])
    for f in frames:
        t = f.stamp_ns
        if chain_at == "every frame":
            msgs += chain(t)
        info = h.camera_info_msg(t, f.K, f.width, f.height)
        info.header.frame_id = OPTICAL
        msgs += [
            ("/odom", t, h.odometry_msg(t, f.cam_to_world @ np.linalg.inv(base_to_optical), "odom", "base_link")),
            ("/camera/color/camera_info", t, info),
            ("/camera/color/image_raw", t, h.image_msg(t, f.rgb, "rgb8", OPTICAL)),
            ("/camera/depth/image_raw", t, h.image_msg(t, np.round(f.depth_m * 1000).astype(np.uint16), "16UC1", OPTICAL)),
        ]  # fmt: skip
    msgs.sort(key=lambda m: m[1])
    return h.write_bag(tmp_path / f"robot_{chain_at.replace(' ', '_')}", msgs)


@pytest.mark.parametrize("chain_at", ["start", "end", "every frame"])
@pytest.mark.parametrize("given", [False, True])
def test_a_static_chain_on_tf_with_odometry_poses_every_view(
    tmp_path: Path, h, livingroom_root: Path, chain_at: str, given: bool
) -> None:
    frames = h.load_livingroom(livingroom_root, 24)[::3]
    bag = _bag(tmp_path, h, frames, chain_at)
    options = ReadOptions(pose_source="/odom") if given else ReadOptions()
    with RecordingFrames(bag, options) as rf:
        got = list(rf)
        assert rf.selection.pose_source == "/odom"
        assert rf.world_frame == "odom"
        assert rf.camera_frame == OPTICAL
    assert len(got) == len(frames)
    for g, f in zip(got, frames, strict=True):
        np.testing.assert_allclose(g.cam_to_world, f.cam_to_world, atol=1e-6)


def test_a_lone_world_transform_on_tf_is_not_stretched_over_the_recording(
    tmp_path: Path, h, livingroom_root: Path
) -> None:
    # map -> camera sent once on /tf and nothing else: a moving camera's one sample, not a
    # mount; frames away from it have no pose (and ingest says so), none gets that pose
    frames = h.load_livingroom(livingroom_root, 12)[::3]
    t0 = frames[0].stamp_ns
    T = frames[0].cam_to_world
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    msgs = [("/tf", t0, h.tf_msg(t0, "map", OPTICAL, tuple(T[:3, 3]), tuple(q)))]
    for f in frames:
        t = f.stamp_ns
        info = h.camera_info_msg(t, f.K, f.width, f.height)
        info.header.frame_id = OPTICAL
        msgs += [
            ("/camera/color/camera_info", t, info),
            ("/camera/color/image_raw", t, h.image_msg(t, f.rgb, "rgb8", OPTICAL)),
            ("/camera/depth/image_raw", t, h.image_msg(t, np.round(f.depth_m * 1000).astype(np.uint16), "16UC1", OPTICAL)),
        ]  # fmt: skip
    msgs.sort(key=lambda m: m[1])
    bag = h.write_bag(tmp_path / "lone", msgs)
    with RecordingFrames(bag) as rf:
        got = list(rf)
        assert rf.stats.dropped["no_pose"] == len(frames) - 1
    assert len(got) == 1
