"""A camera frame in REP 103's body convention (x forward, y left, z up: ``camera_link``, no
optical child) is found and turned into the optical frame, or refused naming
``--camera-convention``; never read as optical.

The third-party living-room frames (poses of an optical camera in the first camera's y-down
world) are turned into a z-up world by hand (scipy), written through rosbags twice, with TF
``map -> camera_color_optical_frame`` (the reference) and ``map -> camera_link`` with the
link's pose (REP 103's link -> optical rotation, as a quaternion); both must give the same
poses and the same grid."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from care_maps.core.errors import IngestError
from care_maps.core.store import read_table
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.ingest.conventions import BODY_FROM_OPTICAL, CameraConvention, find_convention
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.source import ReadOptions, RecordingFrames
from care_maps.runtime.execution import Execution
from tests.support.encoders import TinyEncoder
from tests.support.frames import load_livingroom
from tests.support.messages import camera_info_msg, image_msg, tf_msg
from tests.support.recordings import write_bag

OPTICAL = "camera_color_optical_frame"
LINK = "camera_link"
LINK_TO_OPTICAL_XYZW = (-0.5, 0.5, -0.5, 0.5)
"""REP 103: ``camera_link`` (x forward, z up) -> optical (z forward, x right, y down)."""
CELL = 0.05
QUIET = Execution(progress=False)

ZUP_FROM_YDOWN = np.eye(4)
ZUP_FROM_YDOWN[:3, :3] = (
    Rotation.from_euler("z", 40, degrees=True) * Rotation.from_euler("x", -90, degrees=True)
).as_matrix()
ZUP_FROM_YDOWN[:3, 3] = [0.5, 1.0, 1.3]
"""The living room's world is its first camera's frame, y down (the floor lies along +y:
``tests/ingest/test_map_frame.py`` finds up = -y from the floor); this puts -y on +z."""


def _matrix(xyzw) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(xyzw).as_matrix()
    return T


LINK_FROM_OPTICAL = _matrix(LINK_TO_OPTICAL_XYZW)


def _quarter(frame):
    from care_maps.core.frames import Frame

    K = frame.K.copy()
    K[:2] /= 4
    K[:2, 2] = (frame.K[:2, 2] - 1.5) / 4
    rgb, depth = frame.rgb[::4, ::4].copy(), frame.depth_m[::4, ::4].copy()
    return Frame(frame.stamp_ns, rgb, depth, K, ZUP_FROM_YDOWN @ frame.cam_to_world)


@pytest.fixture(scope="module")
def frames(livingroom_root: Path) -> list:
    return [_quarter(f) for f in load_livingroom(livingroom_root, 60)[::4]]


def _bag(path: Path, frames, camera: str, world: str = "map", poses=None) -> Path:
    """A robot bag: TF ``world -> camera`` at each image, camera info and images stamped
    with ``camera``; ``poses``: the TF poses (default the frames' optical ones)."""
    msgs = []
    for k, f in enumerate(frames):
        t = f.stamp_ns
        pose = f.cam_to_world if poses is None else poses[k]
        q = Rotation.from_matrix(pose[:3, :3]).as_quat()
        info = camera_info_msg(t, f.K, f.width, f.height)
        info.header.frame_id = camera
        depth_mm = np.round(f.depth_m * 1000).astype(np.uint16)
        msgs += [
            ("/tf", t, tf_msg(t, world, camera, tuple(pose[:3, 3]), tuple(q))),
            ("/camera/color/camera_info", t, info),
            ("/camera/color/image_raw", t, image_msg(t, f.rgb, "rgb8", camera)),
            ("/camera/depth/image_raw", t, image_msg(t, depth_mm, "16UC1", camera)),
        ]
    return write_bag(path, msgs)


def _link_poses(frames) -> list[np.ndarray]:
    """``world_from_link`` of each frame: the optical pose with the link -> optical
    rotation taken off (scipy's quaternion, not the code under test)."""
    return [f.cam_to_world @ np.linalg.inv(LINK_FROM_OPTICAL) for f in frames]


@pytest.fixture(scope="module")
def bags(frames, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("convention")
    return {
        "optical": _bag(root / "optical", frames, OPTICAL),
        "body": _bag(root / "body", frames, LINK, poses=_link_poses(frames)),
    }


def test_the_rotation_is_rep_103s() -> None:
    """Hand-worked: the optical axes in body axes are x = -y_body, y = -z_body, z = x_body."""
    np.testing.assert_allclose(BODY_FROM_OPTICAL, LINK_FROM_OPTICAL, atol=1e-15)
    R = BODY_FROM_OPTICAL[:3, :3]
    np.testing.assert_array_equal(R @ [1, 0, 0], [0, -1, 0])
    np.testing.assert_array_equal(R @ [0, 1, 0], [0, 0, -1])
    np.testing.assert_array_equal(R @ [0, 0, 1], [1, 0, 0])


def test_the_world_is_z_up(frames) -> None:
    """The test's own premise: the optical cameras' +y points down the new world's z."""
    down = np.array([-f.cam_to_world[2, 1] for f in frames])
    assert np.all(down > 0.9), down


def _read(bag: Path, options: ReadOptions | None = None) -> tuple[list, RecordingFrames]:
    with RecordingFrames(bag, options) as rf:
        return list(rf), rf


def test_a_body_frame_is_found_and_posed_as_optical(bags, frames) -> None:
    got, rf = _read(bags["body"])
    assert rf.camera_frame == LINK
    assert rf.convention.convention is CameraConvention.BODY
    assert "geometry" in rf.convention.reason
    assert rf.describe()["camera_convention"]["convention"] == "body"
    assert len(got) == len(frames)
    for g, f in zip(got, frames, strict=True):
        np.testing.assert_allclose(g.cam_to_world, f.cam_to_world, atol=1e-6)


def test_the_optical_reference_is_read_as_before(bags, frames) -> None:
    got, rf = _read(bags["optical"])
    assert rf.convention.convention is CameraConvention.OPTICAL
    assert "frame name" in rf.convention.reason
    for g, f in zip(got, frames, strict=True):
        np.testing.assert_allclose(g.cam_to_world, f.cam_to_world, atol=1e-6)


def test_the_option_converts_as_given(bags, frames) -> None:
    got, rf = _read(bags["body"], ReadOptions(camera_convention="body"))
    assert rf.convention.convention is CameraConvention.BODY
    assert "given" in rf.convention.reason
    for g, f in zip(got, frames, strict=True):
        np.testing.assert_allclose(g.cam_to_world, f.cam_to_world, atol=1e-6)
    # optical given: the frame is read as it is (the user's word wins)
    got, _ = _read(bags["body"], ReadOptions(camera_convention=CameraConvention.OPTICAL))
    np.testing.assert_allclose(got[0].cam_to_world, _link_poses(frames)[0], atol=1e-6)


def _cells(store: Path) -> set[tuple[int, int]]:
    table = read_table(store / "cells.parquet", ["x", "y"])
    xy = np.stack([table.column(c).to_numpy() for c in ("x", "y")], 1)
    return {tuple(c) for c in np.floor(xy / CELL + 0.5).astype(int).tolist()}


@pytest.mark.slow
def test_the_body_bag_gives_the_reference_grid(bags, tmp_path: Path) -> None:
    cells = {}
    for name, bag in bags.items():
        config = IngestConfig(vocabulary="red,green,blue")
        store = run_ingest(bag, tmp_path / name, config, run=QUIET, encoder=TinyEncoder())
        build_grid(store, GridConfig(cell_size=CELL, stride=2))
        cells[name] = _cells(store)
    ref, body = cells["optical"], cells["body"]
    assert len(ref) > 200
    assert len(ref ^ body) <= 0.01 * len(ref), (len(ref), len(body), len(ref ^ body))


def test_a_body_name_with_unclear_axes_is_refused_in_one_line(
    run_cli, tmp_path: Path, frames
) -> None:
    """The link's poses in the living room's own y-down world: neither +z up nor +y down
    along that world's z, and the name is a body's; the model is never loaded."""
    ydown = np.linalg.inv(ZUP_FROM_YDOWN)
    poses = [ydown @ p for p in _link_poses(frames)]
    bag = _bag(tmp_path / "ydown_body", frames, LINK, poses=poses)
    empty = tmp_path / "weights"
    empty.mkdir()  # no model in it: loading would fail
    code, _, err = run_cli(
        "ingest", bag, "--out", tmp_path / "store", "--encoder", "clip", "--weights", empty
    )
    assert code == 1
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "--camera-convention" in lines[0]
    assert LINK in lines[0]
    assert not (tmp_path / "store").exists()
    with pytest.raises(IngestError, match="--camera-convention body"):
        _read(bag)
    # given, it is read: the same poses as the reference, in that world
    got, _ = _read(bag, ReadOptions(camera_convention=CameraConvention.BODY))
    for g, f in zip(got, frames, strict=True):
        np.testing.assert_allclose(g.cam_to_world, ydown @ f.cam_to_world, atol=1e-6)


def test_an_optical_camera_under_another_name_stays_optical(tmp_path: Path, frames) -> None:
    """A camera frame named neither optical nor like a body, posed as optical in the z-up
    world: the geometry says optical, nothing is converted."""
    bag = _bag(tmp_path / "camera", frames, "camera")
    got, rf = _read(bag)
    assert rf.convention.convention is CameraConvention.OPTICAL
    for g, f in zip(got, frames, strict=True):
        np.testing.assert_allclose(g.cam_to_world, f.cam_to_world, atol=1e-6)


def test_geometry_against_a_name_is_refused() -> None:
    """Hand-worked poses: a level camera turning about world z. Its +z up (a body's axes)
    under a name that says nothing is refused; under camera_link it is a body; a y-down
    world whose camera turns about its y axis is not taken for a z-up one."""
    yaws = np.radians(np.arange(0, 360, 30))
    body = np.repeat(np.eye(4)[None], len(yaws), axis=0)
    body[:, :3, :3] = Rotation.from_euler("z", yaws[:, None]).as_matrix()
    assert find_convention(LINK, "map", body).convention is CameraConvention.BODY
    with pytest.raises(IngestError, match=r"not a body's.*--camera-convention"):
        find_convention("camera", "map", body)
    optical = body @ BODY_FROM_OPTICAL
    assert find_convention("camera", "map", optical).convention is CameraConvention.OPTICAL
    assert find_convention(LINK, "map", optical).convention is CameraConvention.OPTICAL
    # an optical camera in a y-down world, turning about that world's y: its +z sweeps
    # through world z, and the turning shows which axis is vertical
    ydown = np.repeat(np.eye(4)[None], len(yaws), axis=0)
    pans = np.radians(np.arange(-60, 60, 10))
    ydown[:, :3, :3] = Rotation.from_euler("y", pans[:, None]).as_matrix()
    found = find_convention("camera", "world", ydown)
    assert found.convention is CameraConvention.OPTICAL
    assert "turned about its y axis" in found.reason
