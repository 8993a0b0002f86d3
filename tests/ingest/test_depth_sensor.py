"""Depth from another sensor than the colour camera is refused, never paired pixel by pixel
with colour: the real RealSense recording (librealsense's own bag, depth and colour from two
sensors with their own intrinsics) and the topic layouts of the common ROS drivers."""

from __future__ import annotations

from pathlib import Path

import pytest

from care_maps.ingest.readers import TopicInfo
from care_maps.ingest.topics import depth_camera_info, registered_depth_topics, select_topics

IMAGE, INFO = "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo"


def _topics(*named: tuple[str, str]) -> dict[str, TopicInfo]:
    return {name: TopicInfo(name, kind, 10) for name, kind in named}


def test_realsense_recording_is_refused_naming_both_intrinsics(
    run_cli, shared_data: Path, tmp_path: Path
) -> None:
    bag = shared_data / "rosbag1" / "realsense_single_depth_color_640x480.bag"
    args = ("ingest", bag, "--static-pose", "--max-dt", "0.2", "--out", tmp_path / "store")
    code, _, err = run_cli(*args)
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    # the file's own camera infos: fx 390.43 (Depth_0) and 613.2 (Color_0)
    assert "/device_0/sensor_0/Depth_0/info/camera_info" in lines[0]
    assert "fx 390.4" in lines[0]
    assert "613.2" in lines[0]
    assert "--depth-registered" in lines[0]
    assert "Traceback" not in err
    assert not (tmp_path / "store").exists()
    # the user's word that it is registered lets it through
    code, out, err = run_cli(*args, "--depth-registered")
    assert code == 0, err
    assert "1 views from 1 colour images" in out


@pytest.mark.parametrize(
    ("depth", "expected_info"),
    [
        # realsense2_camera with align_depth: the aligned topic's info is the colour camera's
        ("/camera/aligned_depth_to_color/image_raw", "/camera/aligned_depth_to_color/camera_info"),
        # the raw depth stream: its own sensor's info
        ("/camera/depth/image_rect_raw", "/camera/depth/camera_info"),
    ],
)
def test_the_depth_topics_own_info_is_found(depth: str, expected_info: str) -> None:
    topics = _topics(
        ("/camera/color/image_raw", IMAGE),
        ("/camera/color/camera_info", INFO),
        ("/camera/depth/image_rect_raw", IMAGE),
        ("/camera/depth/camera_info", INFO),
        ("/camera/aligned_depth_to_color/image_raw", IMAGE),
        ("/camera/aligned_depth_to_color/camera_info", INFO),
    )
    sel = select_topics(topics, depth=depth)
    assert sel.camera_info == "/camera/color/camera_info"
    assert depth_camera_info(topics, sel) == expected_info
    assert registered_depth_topics(topics, sel.rgb) == ["/camera/aligned_depth_to_color/image_raw"]
    assert select_topics(topics).depth == "/camera/aligned_depth_to_color/image_raw"  # preferred


def test_a_recording_with_one_camera_info_has_nothing_to_compare() -> None:
    topics = _topics(
        ("/camera/color/image_raw", IMAGE),
        ("/camera/depth/image_raw", IMAGE),
        ("/camera/color/camera_info", INFO),
    )
    assert depth_camera_info(topics, select_topics(topics)) is None
