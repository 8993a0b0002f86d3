"""``--intrinsics`` for recordings without a camera info: four numbers, a ROS camera_info
YAML (as ``camera_calibration`` writes it) or the dataset's own Open3D intrinsics JSON give
the same frames as the camera info topic would; without any, the error names the option.

The third-party living-room frames (their K: fx = fy = 525, cx = 319.5, cy = 239.5, from
the dataset's ``camera_intrinsic.json``) are written through rosbags with and without a
camera info topic."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from care_maps.core.errors import IngestError
from care_maps.ingest.intrinsics import CameraIntrinsics
from care_maps.ingest.source import ReadOptions, RecordingFrames
from tests.support.frames import K_SMALL, load_livingroom, smooth_rgb
from tests.support.messages import camera_info_msg, image_msg, tf_msg
from tests.support.recordings import rgbd_messages, write_bag

OPTICAL = "camera_color_optical_frame"
NUMBERS = "525,525,319.5,239.5"
K_LIVINGROOM = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])
D = (0.05, -0.1, 0.001, -0.002, 0.02)
"""A plumb_bob D, so that the lens is removed the same way from either source."""

CAMERA_INFO_YAML = """\
image_width: 640
image_height: 480
camera_name: livingroom
camera_matrix:
  rows: 3
  cols: 3
  data: [525, 0, 319.5, 0, 525, 239.5, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [{d}]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [525, 0, 319.5, 0, 0, 525, 239.5, 0, 0, 0, 1, 0]
"""
"""The layout ``camera_calibration`` / ``camera_info_manager`` write."""


@pytest.fixture(scope="module")
def frames(livingroom_root: Path) -> list:
    return load_livingroom(livingroom_root, 12)[::4]


def _bag(path: Path, frames, *, info: bool, d=None) -> Path:
    msgs = []
    for f in frames:
        t = f.stamp_ns
        q = Rotation.from_matrix(f.cam_to_world[:3, :3]).as_quat()
        depth_mm = np.round(f.depth_m * 1000).astype(np.uint16)
        msgs += [
            ("/tf", t, tf_msg(t, "map", OPTICAL, tuple(f.cam_to_world[:3, 3]), tuple(q))),
            ("/camera/color/image_raw", t, image_msg(t, f.rgb, "rgb8", OPTICAL)),
            ("/camera/depth/image_raw", t, image_msg(t, depth_mm, "16UC1", OPTICAL)),
        ]
        if info:
            msg = camera_info_msg(t, f.K, f.width, f.height, d=d)
            msg.header.frame_id = OPTICAL
            msgs.append(("/camera/color/camera_info", t, msg))
    return write_bag(path, msgs)


@pytest.fixture(scope="module")
def bags(frames, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("intrinsics")
    return {
        "info": _bag(root / "info", frames, info=True),
        "info_d": _bag(root / "info_d", frames, info=True, d=D),
        "none": _bag(root / "none", frames, info=False),
    }


def _read(bag: Path, options: ReadOptions | None = None) -> list:
    with RecordingFrames(bag, options) as rf:
        # the frames are resolved on entering, before any model would load
        assert rf.camera_frame == OPTICAL
        assert rf.world_frame == "map"
        return list(rf)


def _same(got: list, ref: list) -> None:
    assert len(got) == len(ref) > 0
    for g, r in zip(got, ref, strict=True):
        assert g.stamp_ns == r.stamp_ns
        np.testing.assert_array_equal(g.K, r.K)
        np.testing.assert_array_equal(g.rgb, r.rgb)
        np.testing.assert_array_equal(g.depth_m, r.depth_m)
        np.testing.assert_array_equal(g.cam_to_world, r.cam_to_world)


def test_numbers_give_the_camera_infos_frames(bags, frames) -> None:
    ref = _read(bags["info"])
    np.testing.assert_array_equal(ref[0].K, K_LIVINGROOM)
    _same(_read(bags["none"], ReadOptions(intrinsics=NUMBERS)), ref)
    given = CameraIntrinsics(525, 525, 319.5, 239.5)
    _same(_read(bags["none"], ReadOptions(intrinsics=given)), ref)


def test_a_camera_info_yaml_gives_the_same_frames(bags, tmp_path: Path) -> None:
    ref = _read(bags["info_d"])
    yaml_file = tmp_path / "livingroom.yaml"
    yaml_file.write_text(CAMERA_INFO_YAML.format(d=", ".join(map(str, D))))
    got = _read(bags["none"], ReadOptions(intrinsics=str(yaml_file)))
    _same(got, ref)
    assert not np.array_equal(got[0].rgb, _read(bags["info"])[0].rgb)  # D was applied


def test_the_datasets_own_intrinsics_json(bags, livingroom_root: Path) -> None:
    """Open3D's PinholeCameraIntrinsic JSON, as the dataset ships it (column-major)."""
    path = livingroom_root / "camera_intrinsic.json"
    given = CameraIntrinsics.from_text(str(path))
    assert (given.fx, given.fy, given.cx, given.cy) == (525.0, 525.0, 319.5, 239.5)
    assert (given.width, given.height) == (640, 480)
    _same(_read(bags["none"], ReadOptions(intrinsics=given)), _read(bags["info"]))


def test_intrinsics_replace_a_wrong_camera_info(bags, frames, tmp_path: Path) -> None:
    """A camera info with another K is not read when --intrinsics is given."""
    wrong = [type(f)(f.stamp_ns, f.rgb, f.depth_m, f.K * [[2], [2], [1]], f.cam_to_world)
             for f in frames]  # fmt: skip
    bag = _bag(tmp_path / "wrong", wrong, info=True)
    assert _read(bag)[0].K[0, 0] == 1050.0
    _same(_read(bag, ReadOptions(intrinsics=NUMBERS)), _read(bags["info"]))


def test_no_camera_info_names_the_option(run_cli, bags, tmp_path: Path) -> None:
    empty = tmp_path / "weights"
    empty.mkdir()  # no model in it: loading would fail
    code, _, err = run_cli(
        "ingest", bags["none"], "--out", tmp_path / "store", "--encoder", "clip",
        "--weights", empty,
    )  # fmt: skip
    assert code == 1
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "no camera info topic" in lines[0]
    assert "--intrinsics" in lines[0]
    code, out, err = run_cli("topics", bags["none"], "--intrinsics", NUMBERS)
    assert code == 0, err
    assert "camera_info  None" in out


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("--intrinsics", "525,525,319.5"), "expected fx,fy,cx,cy"),
        (("--intrinsics", "0,525,319.5,239.5"), "fx, fy must be > 0"),
        (("--intrinsics", "missing.yaml"), "cannot read it"),
    ],
)
def test_bad_intrinsics_are_a_usage_error(run_cli, bags, args, expected) -> None:
    code, _, err = run_cli("topics", bags["none"], *args)
    assert code == 2
    assert "--intrinsics" in err
    assert expected in " ".join(err.split())


def test_intrinsics_for_another_image_size_are_refused(bags, tmp_path: Path) -> None:
    yaml_file = tmp_path / "half.yaml"
    text = CAMERA_INFO_YAML.format(d="0, 0, 0, 0, 0")
    yaml_file.write_text(text.replace("640", "320").replace("480", "240"))
    with pytest.raises(IngestError, match=r"--intrinsics are for 320x240 images .* 640x480"):
        _read(bags["none"], ReadOptions(intrinsics=str(yaml_file)))


def test_both_sources_are_refused() -> None:
    with pytest.raises(IngestError, match="either it or --camera-info"):
        ReadOptions(camera_info="/camera/color/camera_info", intrinsics=NUMBERS)


def test_intrinsics_and_static_pose_need_no_small_topic(tmp_path: Path) -> None:
    """Neither TF nor camera info: only the images are read, each with the given K."""
    msgs = rgbd_messages(
        lambda i, t: image_msg(t, smooth_rgb(i), "rgb8"),
        lambda i, t: image_msg(t, np.full((24, 32), 2000, np.uint16), "16UC1"),
        info=False,
        tf=False,
    )
    bag = write_bag(tmp_path / "images_only", msgs)
    options = ReadOptions(static_pose=True, intrinsics="40,40,16,12")
    with RecordingFrames(bag, options) as rf:
        got = list(rf)
    assert len(got) == 3
    for frame in got:
        np.testing.assert_array_equal(frame.K, K_SMALL)
        np.testing.assert_array_equal(frame.cam_to_world, np.eye(4))
