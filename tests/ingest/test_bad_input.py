"""Bad input: one clear line naming the file/topic/field, exit code 1, and no store left."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from care_maps.ingest.write import write_recording
from tests.support.frames import smooth_rgb, synthetic_frames
from tests.support.messages import image_msg, tf_msg
from tests.support.recordings import rgbd_messages, write_bag

pytestmark = pytest.mark.slow

H, W = 24, 32


def _expect_failure(run_cli, tmp_path: Path, rec: Path, pattern: str, *flags: str) -> str:
    out = tmp_path / "store"
    code, _, err = run_cli("ingest", rec, "--out", out, *flags)
    assert code == 1
    # The progress bar may have drawn on stderr before the failure; the error is one line.
    lines = [line for line in err.strip().splitlines() if line.startswith("error: ")]
    assert len(lines) == 1, err
    assert err.strip().endswith(lines[0])
    assert re.search(pattern, lines[0]), lines[0]
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".store")]
    return lines[0]


def test_missing_file(run_cli, tmp_path: Path) -> None:
    _expect_failure(
        run_cli, tmp_path, tmp_path / "nope.bag", r"nope\.bag: no such file or directory"
    )


@pytest.mark.parametrize(("fmt", "name"), [("ros1", "r.bag"), ("mcap", "r.mcap")])
def test_truncated_recording(run_cli, tmp_path: Path, fmt: str, name: str) -> None:
    path = write_recording(tmp_path / name, synthetic_frames(4), fmt=fmt)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])
    _expect_failure(run_cli, tmp_path, path, rf"{name}: cannot open as .*truncated or corrupt")


def test_png_renamed_bag(run_cli, tmp_path: Path, shared_data: Path) -> None:
    fake = tmp_path / "photo.bag"
    shutil.copy(shared_data / "rgbd" / "slambook_kinect5" / "color" / "1.png", fake)
    _expect_failure(
        run_cli,
        tmp_path,
        fake,
        r"photo\.bag: is a PNG image, not a ROS 1 bag as its suffix \.bag says",
    )


def test_random_mcap(run_cli, tmp_path: Path) -> None:
    fake = tmp_path / "noise.mcap"
    fake.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    _expect_failure(
        run_cli, tmp_path, fake, r"noise\.mcap: is of no known format .* not an MCAP file"
    )


@pytest.mark.parametrize("name", ["talker_sqlite3", "talker_mcap"])
def test_no_image_topic_lists_topics(run_cli, tmp_path: Path, shared_data: Path, name: str) -> None:
    line = _expect_failure(
        run_cli,
        tmp_path,
        shared_data / "rosbag2" / name,
        r"no image topic .*topics present: .*pass --rgb TOPIC",
    )
    assert "/topic (std_msgs/msg/String, 10 msgs)" in line
    assert "/rosout (rcl_interfaces/msg/Log, 10 msgs)" in line


def _rgb(i, t):
    return image_msg(t, smooth_rgb(i, H, W), "rgb8")


def _depth(i, t, value=1500):
    return image_msg(t, np.full((H, W), value, np.uint16), "16UC1")


def test_no_camera_info(run_cli, tmp_path: Path) -> None:
    bag = write_bag(
        tmp_path / "bag",
        rgbd_messages(lambda i, t: _rgb(i, t), lambda i, t: _depth(i, t), info=False),
    )
    _expect_failure(
        run_cli,
        tmp_path,
        bag,
        r"no camera info topic \(sensor_msgs/CameraInfo\) for /camera/color/image_raw.*--camera-info",
    )


def test_no_transform_camera_to_world(run_cli, tmp_path: Path) -> None:
    msgs = rgbd_messages(lambda i, t: _rgb(i, t), lambda i, t: _depth(i, t), tf=False)
    msgs.insert(0, ("/tf", 10**9, tf_msg(10**9, "map", "base_link", (0.0, 0.0, 0.0), (0, 0, 0, 1))))
    bag = write_bag(tmp_path / "bag", msgs)
    _expect_failure(
        run_cli,
        tmp_path,
        bag,
        r"no transform from camera frame 'camera_optical_frame' to world frame 'map': camera frame 'camera_optical_frame' is not in TF \(frames present: base_link, map\)",
    )


def test_unsupported_encoding(run_cli, tmp_path: Path) -> None:
    bag = write_bag(
        tmp_path / "bag",
        rgbd_messages(
            lambda i, t: image_msg(t, np.zeros((H, W, 2), np.uint8), "yuv422"),
            lambda i, t: _depth(i, t),
        ),
    )
    _expect_failure(
        run_cli,
        tmp_path,
        bag,
        r"bag: topic /camera/color/image_raw: image encoding 'yuv422' is not supported",
    )


def test_image_depth_size_mismatch(run_cli, tmp_path: Path) -> None:
    bag = write_bag(
        tmp_path / "bag",
        rgbd_messages(
            lambda i, t: _rgb(i, t),
            lambda i, t: image_msg(t, np.full((12, 16), 900, np.uint16), "16UC1"),
        ),
    )
    _expect_failure(
        run_cli,
        tmp_path,
        bag,
        r"colour images on /camera/color/image_raw are 32x24 but depth images on /camera/depth/image_raw are 16x12",
    )


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_depth_invalid_everywhere(run_cli, tmp_path: Path, encoding: str) -> None:
    def depth(i, t):
        if encoding == "32FC1":
            return image_msg(t, np.full((H, W), np.nan, np.float32), "32FC1")
        return _depth(i, t, value=0)

    bag = write_bag(tmp_path / "bag", rgbd_messages(lambda i, t: _rgb(i, t), depth))
    _expect_failure(
        run_cli,
        tmp_path,
        bag,
        r"depth topic /camera/depth/image_raw has no valid pixel \(finite and > 0\) in any of 3 frames",
    )


def test_realsense_needs_static_pose(run_cli, tmp_path: Path, shared_data: Path) -> None:
    bag = shared_data / "rosbag1" / "realsense_single_depth_color_640x480.bag"
    _expect_failure(run_cli, tmp_path, bag, r"no pose source: .*pass --static-pose")
    # Its depth comes from another sensor (Depth_0, fx 390.4) than colour (fx 613.2).
    _expect_failure(
        run_cli, tmp_path, bag, r"comes from another sensor .*--depth-registered", "--static-pose"
    )
    # Its only colour frame is 102 ms from the nearest depth frame.
    flags = ("--static-pose", "--depth-registered")
    _expect_failure(run_cli, tmp_path, bag, r"within --max-dt 20 ms \(nearest was 102 ms\)", *flags)
    code, out, _ = run_cli("ingest", bag, "--out", tmp_path / "store", *flags, "--max-dt", "0.15")
    assert code == 0
    assert "1 views from 1 colour images" in out
    from care_maps.core.store import Store

    store = Store(tmp_path / "store")
    np.testing.assert_allclose(store.poses()[0], np.eye(4))
    assert store.intrinsics()[0][0, 0] == pytest.approx(613.20367432)  # the colour camera's K
