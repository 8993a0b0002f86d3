"""Pose sources as robots publish them, written from the third-party living-room frames
through the real writers (rosbags for ROS 1 and rosbag2, mcap for a plain MCAP file).

The camera's mount chain (base_link -> camera_link -> camera_color_optical_frame) sent on
``/tf`` rather than ``/tf_static`` (as drivers and ``static_transform_publisher`` replays
do), once at the start, once at the end or with every frame, with the motion on
``nav_msgs/Odometry``: every view's pose must equal the frames' own trajectory (1e-6),
where before all views but one were dropped as unposed. ``--pose-source`` composes with
any chain, and wins over TF's own motion; views without a pose are counted by why, and a
recording whose views mostly have none is refused in one line naming the fix.
"""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from care_maps.core.errors import IngestError
from care_maps.ingest.decode import StampedTransform
from care_maps.ingest.source import PoseFrom, ReadOptions, RecordingFrames
from care_maps.ingest.tf import TFBuffer, Uncovered
from tests.support.frames import load_livingroom
from tests.support.messages import camera_info_msg, image_msg, odometry_msg, tf_msg
from tests.support.recordings import Container, write_bag

OPTICAL = "camera_color_optical_frame"
LINK_TO_OPTICAL_XYZW = (-0.5, 0.5, -0.5, 0.5)  # REP 103: camera_link -> optical
BASE_TO_LINK_XYZ = (0.12, -0.03, 0.45)
BASE_TO_LINK_XYZW = tuple(Rotation.from_euler("y", 8, degrees=True).as_quat())


class ChainAt(StrEnum):
    """When the mount chain is published."""

    START = "start"
    END = "end"
    EVERY_FRAME = "every frame"


def _matrix(xyz, xyzw) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(xyzw).as_matrix()
    T[:3, 3] = xyz
    return T


BASE_TO_OPTICAL = _matrix(BASE_TO_LINK_XYZ, BASE_TO_LINK_XYZW) @ _matrix(
    (0.0, 0.0, 0.0), LINK_TO_OPTICAL_XYZW
)


# -- writers -----------------------------------------------------------------------------

SUFFIX = {Container.ROS1: ".bag", Container.MCAP: ".mcap"}


def _write(container: Container, path: Path, msgs: list) -> Path:
    """``(topic, t_ns, message)`` into a recording of ``container`` through its real writer
    (a ROS 1 bag named ``.bag``, a rosbag2 directory, an MCAP file named ``.mcap``)."""
    if container is not Container.ROS2:
        path = path.with_suffix(SUFFIX[container])
    return write_bag(path, msgs, container)


# -- recordings --------------------------------------------------------------------------


def _chain(t: int, topic: str = "/tf") -> list:
    return [
        (topic, t, tf_msg(t, "base_link", "camera_link", BASE_TO_LINK_XYZ, BASE_TO_LINK_XYZW)),
        (topic, t, tf_msg(t, "camera_link", OPTICAL, (0.0, 0.0, 0.0), LINK_TO_OPTICAL_XYZW)),
    ]


def _body(f) -> np.ndarray:
    """odom_from_base_link that puts the camera where the trajectory has it."""
    return f.cam_to_world @ np.linalg.inv(BASE_TO_OPTICAL)


def _tf_pose(t: int, T: np.ndarray, parent: str, child: str):
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    return tf_msg(t, parent, child, tuple(T[:3, 3]), tuple(q))


def _camera(f, depth_per_metre: float = 1000.0) -> list:
    t = f.stamp_ns
    info = camera_info_msg(t, f.K, f.width, f.height)
    info.header.frame_id = OPTICAL
    depth = np.round(f.depth_m * depth_per_metre).astype(np.uint16)
    return [
        ("/camera/color/camera_info", t, info),
        ("/camera/color/image_raw", t, image_msg(t, f.rgb, "rgb8", OPTICAL)),
        ("/camera/depth/image_raw", t, image_msg(t, depth, "16UC1", OPTICAL)),
    ]


def _robot(
    frames,
    chain_at: ChainAt = ChainAt.START,
    chain_topic: str = "/tf",
    depth_per_metre: float = 1000.0,
) -> list:
    """The user's robot: the mount chain on ``chain_topic`` at ``chain_at``, the body's
    motion on /odom (odom -> base_link)."""
    stamps = [f.stamp_ns for f in frames]
    msgs = []
    if chain_at is ChainAt.START:
        msgs += _chain(stamps[0], chain_topic)
    elif chain_at is ChainAt.END:
        msgs += _chain(stamps[-1], chain_topic)
    for f in frames:
        t = f.stamp_ns
        if chain_at is ChainAt.EVERY_FRAME:
            msgs += _chain(t, chain_topic)
        msgs.append(("/odom", t, odometry_msg(t, _body(f), "odom", "base_link")))
        msgs += _camera(f, depth_per_metre)
    return sorted(msgs, key=lambda m: m[1])


@pytest.fixture(scope="module")
def frames(livingroom_root: Path) -> list:
    """Eight living-room frames a tenth of a second apart, with their trajectory poses."""
    return load_livingroom(livingroom_root, 24)[::3]


def _read(bag: Path, options: ReadOptions | None = None) -> tuple[list, RecordingFrames]:
    with RecordingFrames(bag, options) as rf:
        return list(rf), rf


def _assert_trajectory(got, frames) -> None:
    assert len(got) == len(frames)
    for g, f in zip(got, frames, strict=True):
        assert g.stamp_ns == f.stamp_ns
        np.testing.assert_allclose(g.cam_to_world, f.cam_to_world, atol=1e-6)


# -- the user's case: a static chain once on /tf, the motion on /odom ---------------------


@pytest.mark.parametrize("container", list(Container))
@pytest.mark.parametrize("chain_at", [ChainAt.START, ChainAt.END])
def test_a_chain_once_on_tf_with_odometry_poses_every_view(
    tmp_path: Path, frames, container: Container, chain_at: ChainAt
) -> None:
    bag = _write(container, tmp_path / "robot", _robot(frames, chain_at))
    got, rf = _read(bag)
    assert rf.selection.pose_source == "/odom"
    assert rf.world_frame == "odom"
    assert rf.camera_frame == OPTICAL
    assert rf.describe()["pose"]["from"] == PoseFrom.FOUND
    assert not rf.stats.dropped
    _assert_trajectory(got, frames)


def test_a_chain_repeated_on_tf_with_every_frame_is_static_too(tmp_path: Path, frames) -> None:
    bag = _write(Container.ROS2, tmp_path / "robot", _robot(frames, ChainAt.EVERY_FRAME))
    got, rf = _read(bag)
    assert (rf.selection.pose_source, rf.world_frame) == ("/odom", "odom")
    _assert_trajectory(got, frames)


# -- --pose-source with any chain ----------------------------------------------------------


@pytest.mark.parametrize(
    ("container", "chain_topic"),
    [(Container.ROS2, "/tf"), (Container.ROS1, "/tf"), (Container.MCAP, "/tf_static")],
)
def test_a_given_pose_source_composes_with_the_chain_wherever_published(
    tmp_path: Path, frames, container: Container, chain_topic: str
) -> None:
    msgs = _robot(frames, ChainAt.START, chain_topic)
    bag = _write(container, tmp_path / "robot", msgs)
    got, rf = _read(bag, ReadOptions(pose_source="/odom"))
    pose = rf.describe()["pose"]
    assert pose["from"] == PoseFrom.GIVEN
    assert "places 'base_link' under 'odom'" in pose["reason"]
    assert rf.world_frame == "odom"
    _assert_trajectory(got, frames)


def test_a_given_pose_source_wins_over_tf_motion(tmp_path: Path, frames) -> None:
    # TF moves base_link too (a drifting wheel odometry, 0.3 m off); /odom is the right one
    drift = np.eye(4)
    drift[0, 3] = 0.3
    msgs = _robot(frames, ChainAt.START)
    msgs += [
        ("/tf", f.stamp_ns, _tf_pose(f.stamp_ns, drift @ _body(f), "odom", "base_link"))
        for f in frames
    ]
    bag = _write(Container.ROS2, tmp_path / "robot", sorted(msgs, key=lambda m: m[1]))
    # without the flag TF's own motion holds (it moves the camera, no topic is guessed)
    got, rf = _read(bag)
    assert rf.selection.pose_source is None
    assert rf.describe()["pose"]["from"] == PoseFrom.TF
    np.testing.assert_allclose(
        got[0].cam_to_world[:3, 3], (drift @ frames[0].cam_to_world)[:3, 3], atol=1e-6
    )
    got, rf = _read(bag, ReadOptions(pose_source="/odom"))
    pose = rf.describe()["pose"]
    assert pose["from"] == PoseFrom.GIVEN
    assert "instead of TF's moving transform odom->base_link" in pose["reason"]
    _assert_trajectory(got, frames)


def test_care_topics_says_which_pose_source_wins(tmp_path: Path, frames) -> None:
    bag = _write(Container.ROS2, tmp_path / "robot", _robot(frames, ChainAt.END))
    with RecordingFrames(bag) as rf:
        described = rf.describe()
    assert described["topics"]["pose_source"] == "/odom"
    assert described["pose"]["from"] == "found pose source"
    assert "TF moves nothing on the camera's chain" in described["pose"]["reason"]


# -- views without a pose: why, and a refusal naming the fix -------------------------------


def _moving_tf_only(frames, posed: range, *, odom: bool) -> list:
    """The chain on /tf_static, the body on /tf for the frames in ``posed`` only; /odom
    (the whole trajectory) beside it when ``odom``."""
    msgs = _chain(frames[0].stamp_ns, "/tf_static")
    for k, f in enumerate(frames):
        t = f.stamp_ns
        if k in posed:
            msgs.append(("/tf", t, _tf_pose(t, _body(f), "odom", "base_link")))
        if odom:
            msgs.append(("/odom", t, odometry_msg(t, _body(f), "odom", "base_link")))
        msgs += _camera(f)
    return sorted(msgs, key=lambda m: m[1])


def test_views_outside_tf_are_counted_by_why(tmp_path: Path, frames) -> None:
    msgs = _moving_tf_only(frames, range(2, 7), odom=False)
    got, rf = _read(_write(Container.ROS2, tmp_path / "robot", msgs))
    assert dict(rf.stats.dropped) == {
        Uncovered.BEFORE_FIRST.value: 2,
        Uncovered.AFTER_LAST.value: 1,
    }
    _assert_trajectory(got, frames[2:7])


@pytest.mark.parametrize("odom", [True, False])
def test_a_recording_mostly_without_poses_is_refused_naming_the_fix(
    tmp_path: Path, frames, odom: bool
) -> None:
    bag = _write(Container.ROS2, tmp_path / "robot", _moving_tf_only(frames, range(3), odom=odom))
    with pytest.raises(IngestError) as err, RecordingFrames(bag) as rf:
        list(rf)
    line = str(err.value)
    assert "\n" not in line
    assert line.startswith(f"{bag}: 5 of 8 colour images on /camera/color/image_raw have no pose")
    assert "no_pose_after_last_transform 5" in line
    assert "world frame 'odom' (chosen)" in line
    assert f"TF frames: base_link, {OPTICAL}, camera_link, odom" in line
    assert "--world-frame" in line
    if odom:
        assert "pass --pose-source /odom" in line
        # and what it names works
        got, _ = _read(bag, ReadOptions(pose_source="/odom"))
        _assert_trajectory(got, frames)
    else:
        assert "no other odometry or pose topic" in line


def test_a_lone_world_transform_on_tf_is_not_stretched_over_the_recording(
    tmp_path: Path, frames
) -> None:
    # map -> camera once on /tf and nothing else: more likely a moving camera's only sample
    # than a mount: it poses the views near its stamp only, and the recording is refused as
    # soon as most views surely have no pose
    t0 = frames[0].stamp_ns
    msgs = [("/tf", t0, _tf_pose(t0, frames[0].cam_to_world, "map", OPTICAL))]
    msgs += [m for f in frames for m in _camera(f)]
    bag = _write(Container.ROS2, tmp_path / "lone", sorted(msgs, key=lambda m: m[1]))
    with pytest.raises(IngestError, match=r"^[^\n]*: 5 of 8 colour images .* have no pose") as err:
        _read(bag)
    line = str(err.value)
    assert "no_pose_after_last_transform 5" in line
    assert f"if map->{OPTICAL} is a fixed mount, publish it on /tf_static" in line


def test_transforms_that_never_overlap_leave_a_gap() -> None:
    buf = TFBuffer()
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for k, t in enumerate((0, 10**8)):
        buf.add(StampedTransform("map", "odom", t, np.array([k, 0.0, 0.0]), q), static=False)
    for k, t in enumerate((6 * 10**8, 7 * 10**8)):
        buf.add(StampedTransform("odom", "cam", t, np.array([0.0, k, 0.0]), q), static=False)
    times = [0, 4 * 10**8, 7 * 10**8]
    _, valid = buf.lookup("map", "cam", np.array(times))
    assert not valid.any()
    assert [buf.uncovered("map", "cam", t) for t in times] == [
        Uncovered.BEFORE_FIRST,
        Uncovered.BETWEEN,
        Uncovered.AFTER_LAST,
    ]


# -- the rule itself ----------------------------------------------------------------------


def test_only_transforms_that_never_change_are_static() -> None:
    buf = TFBuffer()
    q = np.array([0.0, 0.0, 0.0, 1.0])
    buf.add(StampedTransform("base", "once", 5, np.ones(3), q), static=False)
    for t in range(3):  # the same transform again, but for the last bits
        xyz = np.ones(3) + 1e-9 * t
        buf.add(StampedTransform("base", "repeated", t, xyz, -q), static=False)
        buf.add(StampedTransform("base", "moving", t, np.full(3, t * 1e-3), q), static=False)
    assert buf.freeze_unchanging() == ["once", "repeated"]
    assert buf.moving() == ["moving"]
    _, valid = buf.lookup("base", "once", np.array([-(10**12), 10**12]))
    assert valid.all()


# -- --depth-scale for recordings -----------------------------------------------------------


def test_depth_in_tenths_of_a_millimetre_reads_with_depth_scale(tmp_path: Path, frames) -> None:
    mm = _write(Container.ROS2, tmp_path / "mm", _robot(frames))
    tenths = _write(Container.ROS1, tmp_path / "tenths", _robot(frames, depth_per_metre=10_000))
    reference, _ = _read(mm)
    got, _ = _read(tenths, ReadOptions(depth_scale=10_000))
    _assert_trajectory(got, frames)
    for g, r in zip(got, reference, strict=True):
        np.testing.assert_allclose(g.depth_m, r.depth_m, rtol=1e-6)
    unscaled, _ = _read(tenths)  # read as millimetres: ten times too deep
    np.testing.assert_allclose(unscaled[0].depth_m, 10 * reference[0].depth_m, rtol=1e-6)
