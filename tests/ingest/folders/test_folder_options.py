"""What a user states about a dataset folder (``--intrinsics``, ``--depth-scale``,
``--pose-convention``, ``--quaternion-order``, ``--camera-convention``) is taken by every
layout, recorded in what the store is read as, and refused in one line where a layout has
nothing it could mean. The folders are the living-room frames written by the writers of
``tests/support/layouts.py``, their poses rewritten here in the stated convention from the
frames' own poses."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from care_maps.core.errors import IngestError
from care_maps.ingest.folders.frames import FOLDER_OPTIONS, FolderFrames, folder_identity
from care_maps.ingest.intrinsics import CameraIntrinsics
from care_maps.ingest.source import ReadOptions
from tests.support import layouts

OPTICAL_IN_BODY = np.array(
    [[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
"""REP 103: the optical frame's axes in a body frame's (x = -y_body, y = -z_body,
z = x_body), written out here."""


@pytest.fixture
def frames(livingroom40):
    return livingroom40[:4]


def _read(folder: Path, **options) -> tuple[list, dict]:
    with FolderFrames(folder, ReadOptions(**options)) as opened:
        got = list(opened)
        described = opened.describe()["topics"]
    return got, described


def _write_poses(folder: Path, frames, pose_of, order: str = "xyzw") -> None:
    """poses.txt with ``pose_of(frame)`` per line, its quaternion in ``order``."""
    lines = []
    for f in frames:
        T = pose_of(f)
        q = Rotation.from_matrix(T[:3, :3]).as_quat()  # x y z w
        q = q if order == "xyzw" else np.roll(q, 1)
        seconds = f"{f.stamp_ns // 10**9}.{f.stamp_ns % 10**9:09d}"
        lines.append(" ".join([seconds, *(f"{v:.9f}" for v in (*T[:3, 3], *q))]))
    (folder / "poses.txt").write_text("\n".join(lines) + "\n")


def _set_json(folder: Path, **fields) -> None:
    path = folder / "intrinsics.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), **fields}))


def _poses(got) -> np.ndarray:
    return np.stack([f.cam_to_world for f in got])


def test_world_to_camera_wxyz_poses_from_the_file_or_the_options(tmp_path, frames):
    folder = layouts.generic(tmp_path / "generic", frames)
    truth = np.stack([f.cam_to_world for f in frames])
    default = folder_identity(folder, ReadOptions())
    _write_poses(folder, frames, lambda f: np.linalg.inv(f.cam_to_world), order="wxyz")
    # the options say it
    got, described = _read(folder, pose_convention="world-to-camera", quaternion_order="wxyz")
    np.testing.assert_allclose(_poses(got), truth, atol=1e-6)
    assert described["pose_convention"] == "world-to-camera"
    assert described["quaternion_order"] == "wxyz"
    # the file says it, and the options win over it
    _set_json(folder, poses="world-to-camera", quaternion_order="wxyz")
    got, described = _read(folder)
    np.testing.assert_allclose(_poses(got), truth, atol=1e-6)
    assert folder_identity(folder, ReadOptions()) != default  # another reading, another store
    _write_poses(folder, frames, lambda f: f.cam_to_world)
    got, described = _read(folder, pose_convention="camera-to-world", quaternion_order="xyzw")
    np.testing.assert_allclose(_poses(got), truth, atol=1e-6)
    assert "pose_convention" not in described
    assert "quaternion_order" not in described
    # a value the file cannot mean is named with its field
    _set_json(folder, poses="camera_to_world")
    with pytest.raises(IngestError, match=r"intrinsics\.json: poses 'camera_to_world'; choose"):
        _read(folder)


def test_body_frame_poses_are_turned_into_the_optical_frame(tmp_path, frames) -> None:
    folder = layouts.generic(tmp_path / "generic", frames)
    _write_poses(folder, frames, lambda f: f.cam_to_world @ np.linalg.inv(OPTICAL_IN_BODY))
    got, described = _read(folder, camera_convention="body")
    np.testing.assert_allclose(_poses(got), [f.cam_to_world for f in frames], atol=1e-6)
    assert described["camera_convention"] == "body"


def test_depth_scale_overrides_the_layouts(tmp_path, frames) -> None:
    folder = layouts.generic(tmp_path / "generic", frames)  # millimetres
    _set_json(folder, depth_scale=5000.0)  # and a file that says otherwise
    got, described = _read(folder, depth_scale=1000.0)
    np.testing.assert_allclose(got[0].depth_m, frames[0].depth_m, atol=5e-4)
    assert described["depth_scale"] == 1000.0
    redwood = layouts.redwood(tmp_path / "redwood", frames)
    got, described = _read(redwood, depth_scale=500.0)
    np.testing.assert_allclose(got[0].depth_m, 2 * frames[0].depth_m, atol=1e-3)
    assert described["depth_scale"] == 500.0


def test_intrinsics_replace_the_layouts_camera(tmp_path, frames) -> None:
    redwood = layouts.redwood(tmp_path / "redwood", frames)
    default = folder_identity(redwood, ReadOptions())
    got, described = _read(redwood, intrinsics="500,501,320,240")
    assert (got[0].K[0, 0], got[0].K[1, 1], got[0].K[0, 2], got[0].K[1, 2]) == (500, 501, 320, 240)
    assert described["intrinsics"]["source"] == "--intrinsics"
    assert folder_identity(redwood, ReadOptions(intrinsics="500,501,320,240")) != default
    # a named camera with a lens: its distortion is removed, and the JPEG then differs from the image
    got, _ = _read(redwood, intrinsics="freiburg1")
    with FolderFrames(redwood, ReadOptions(intrinsics="freiburg1")) as opened:
        assert [d.coefficients for d in opened.distortions] == [
            (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)
        ]
    assert got[0].rgb_jpeg is None
    plain, _ = _read(redwood, intrinsics="517.3,516.5,318.6,255.3")
    assert np.abs(got[0].rgb.astype(int) - plain[0].rgb.astype(int)).mean() > 1.0
    # a generic folder needs no intrinsics.json when the camera is given (millimetres)
    generic = layouts.generic(tmp_path / "generic", frames)
    (generic / "intrinsics.json").unlink()
    got, described = _read(generic, intrinsics="primesense")
    assert described["depth_scale"] == 1000.0
    np.testing.assert_allclose(got[0].depth_m, frames[0].depth_m, atol=5e-4)


def test_named_cameras() -> None:
    primesense = CameraIntrinsics.from_text("primesense")
    assert (primesense.fx, primesense.fy, primesense.cx, primesense.cy) == (525, 525, 319.5, 239.5)
    assert (primesense.width, primesense.height) == (640, 480)
    assert primesense.lens.is_zero
    fr2 = CameraIntrinsics.from_text("Freiburg2")
    assert (fr2.fx, fr2.fy, fr2.cx, fr2.cy) == (520.9, 521.0, 325.1, 249.7)
    assert fr2.lens.coefficients == (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)
    fr3 = CameraIntrinsics.from_text("freiburg3")
    assert (fr3.fx, fr3.fy, fr3.cx, fr3.cy, fr3.distortion) == (535.4, 539.2, 320.1, 247.6, ())
    with pytest.raises(IngestError, match=r"primesense, freiburg1, freiburg2, freiburg3"):
        CameraIntrinsics.from_text("kinect")


def test_tum_sensor_by_its_short_name(tmp_path, frames) -> None:
    folder = layouts.tum(tmp_path / "fr3_livingroom", frames)
    got, described = _read(folder)
    assert (got[0].K[0, 0], got[0].K[1, 1]) == (535.4, 539.2)
    assert described["intrinsics"]["source"] == "TUM freiburg3"
    for name in ("rgbd_dataset_livingroom", "frame3_room", "fr33_room"):
        folder = layouts.tum(tmp_path / name, frames[:2])
        with pytest.raises(IngestError, match=r"names no TUM sensor.*--intrinsics"):
            _read(folder)


def test_options_a_layout_cannot_take_are_refused(tmp_path, frames, run_cli) -> None:
    redwood = layouts.redwood(tmp_path / "redwood", frames)
    with pytest.raises(IngestError, match=r"--quaternion-order speaks of pose lines.*redwood"):
        _read(redwood, quaternion_order="wxyz")
    code, _, err = run_cli("topics", redwood, "--quaternion-order", "wxyz")
    assert code == 1
    assert err.count("\n") == 1
    assert "4x4 matrices; leave it out" in err
    # accepted by every folder, for the geometric check that reads it
    assert "accept_geometry" in FOLDER_OPTIONS
    got, _ = _read(redwood, accept_geometry=True)
    assert len(got) == 4
