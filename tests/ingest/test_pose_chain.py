"""A robot's usual pose layout (REP 105): the motion on ``nav_msgs/Odometry`` (odom ->
base_link), the camera on the static TF chain (base_link -> camera_link ->
camera_color_optical_frame). Written through rosbags from the third-party living-room
frames; the poses ingest finds are checked against the frames' own trajectory composed by
hand with scipy's rotations."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from care_maps.ingest.source import RecordingFrames
from tests.support.frames import load_livingroom
from tests.support.messages import camera_info_msg, image_msg, odometry_msg, tf_msg
from tests.support.recordings import write_bag

OPTICAL = "camera_color_optical_frame"
# camera_link (x forward, z up) -> optical (z forward, x right, y down), REP 103
LINK_TO_OPTICAL_XYZW = (-0.5, 0.5, -0.5, 0.5)
BASE_TO_LINK_XYZ = (0.12, -0.03, 0.45)
BASE_TO_LINK_XYZW = tuple(Rotation.from_euler("y", 8, degrees=True).as_quat())


def _matrix(xyz, xyzw) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(xyzw).as_matrix()
    T[:3, 3] = xyz
    return T


def test_odometry_and_a_static_chain_give_every_view_its_pose(
    tmp_path: Path, livingroom_root: Path
) -> None:
    frames = load_livingroom(livingroom_root, 24)[::4]
    base_to_optical = _matrix(BASE_TO_LINK_XYZ, BASE_TO_LINK_XYZW) @ _matrix(
        (0.0, 0.0, 0.0), LINK_TO_OPTICAL_XYZW
    )
    t0 = frames[0].stamp_ns
    msgs = [
        ("/tf_static", t0, tf_msg(t0, "base_link", "camera_link", BASE_TO_LINK_XYZ,
                                  BASE_TO_LINK_XYZW)),
        ("/tf_static", t0, tf_msg(t0, "camera_link", OPTICAL, (0.0, 0.0, 0.0),
                                  LINK_TO_OPTICAL_XYZW)),
    ]  # fmt: skip
    for f in frames:
        t = f.stamp_ns
        # the body's pose that puts the camera where the trajectory has it
        T_odom_base = f.cam_to_world @ np.linalg.inv(base_to_optical)
        info = camera_info_msg(t, f.K, f.width, f.height)
        info.header.frame_id = OPTICAL
        depth_mm = np.round(f.depth_m * 1000).astype(np.uint16)
        msgs += [
            ("/odom", t, odometry_msg(t, T_odom_base, "odom", "base_link")),
            ("/camera/color/camera_info", t, info),
            ("/camera/color/image_raw", t, image_msg(t, f.rgb, "rgb8", OPTICAL)),
            ("/camera/depth/image_raw", t, image_msg(t, depth_mm, "16UC1", OPTICAL)),
        ]
    msgs.sort(key=lambda m: m[1])
    bag = write_bag(tmp_path / "robot_bag", msgs)
    with RecordingFrames(bag) as rf:
        got = list(rf)
        assert rf.selection.pose_source == "/odom"
        assert rf.world_frame == "odom"
        assert rf.camera_frame == OPTICAL
    assert len(got) == len(frames)
    for g, f in zip(got, frames, strict=True):
        np.testing.assert_allclose(g.cam_to_world, f.cam_to_world, atol=1e-6)
