"""The layouts of ETH3D SLAM, Bonn RGB-D Dynamic and 7-Scenes read what their datasets ship:
ETH3D's ``calibration.txt`` and ``associated.txt``, Bonn's published camera and its marker
ground truth, 7-Scenes' per-frame files, its 65535 for no depth and its one camera. The
grids against the bag: ``test_layouts``."""

from __future__ import annotations

import numpy as np
import pytest

from care_maps.ingest.folders import LAYOUTS, DatasetLayout, detect_layout
from care_maps.ingest.folders.bonn import CAMERA_IN_MARKER, BonnLayout
from care_maps.ingest.folders.eth3d import Eth3dLayout
from care_maps.ingest.folders.frames import FolderFrames
from care_maps.ingest.folders.sevenscenes import SevenScenesLayout
from care_maps.ingest.source import ReadOptions
from tests.support import layouts


@pytest.fixture
def frames(livingroom40):
    return livingroom40[:6]


def _matching(folder) -> set[DatasetLayout]:
    return {kind for kind, cls in LAYOUTS.items() if cls.detect(folder)}


def test_eth3d_reads_its_calibration_and_associations(tmp_path, frames) -> None:
    folder = layouts.eth3d(tmp_path / "sofa_1", frames)
    assert _matching(folder) == {DatasetLayout.ETH3D}
    # depth.txt's stamps half a second off: only associated.txt pairs the images
    lines = (folder / "depth.txt").read_text().splitlines()
    shifted = [f"{float(t) + 0.5:.6f} {name}" for t, name in (line.split() for line in lines)]
    (folder / "depth.txt").write_text("\n".join(shifted) + "\n")
    with FolderFrames(folder) as opened:
        got = list(opened)
        described = opened.describe()["topics"]
    assert len(got) == len(frames)
    assert described["pairs"] == "associated.txt"
    assert described["intrinsics"]["source"] == "calibration.txt"
    assert described["depth_scale"] == 5000.0
    np.testing.assert_array_equal(got[0].K, frames[0].K)
    np.testing.assert_allclose(got[0].depth_m, frames[0].depth_m, atol=1e-4)
    np.testing.assert_allclose(got[3].cam_to_world, frames[3].cam_to_world, atol=1e-5)
    (folder / "associated.txt").unlink()  # TUM's association then finds no depth in 20 ms
    assert not Eth3dLayout(folder, max_dt=0.02).views()
    # without calibration.txt the same lists are a TUM sequence
    (folder / "calibration.txt").unlink()
    assert detect_layout(folder) == DatasetLayout.TUM


def test_bonn_uses_its_camera_and_turns_the_marker_poses_into_the_camera(tmp_path, frames) -> None:
    folder = layouts.bonn(tmp_path / "rgbd_bonn_livingroom", frames)
    assert _matching(folder) == {DatasetLayout.BONN}
    with FolderFrames(folder) as opened:
        described = opened.describe()["topics"]
        lenses = opened.distortions
        world = opened.world_frame
    assert world == "bonn_world"
    K = described["intrinsics"]
    assert (K["fx"], K["fy"], K["cx"], K["cy"]) == (542.822841, 542.576870, 315.593520, 237.756098)
    assert (K["width"], K["height"]) == (640, 480)
    assert [lens.coefficients for lens in lenses] == [
        (0.039903, -0.099343, -0.000730, -0.000144, 0.0)
    ]
    assert described["depth_scale"] == 5000.0
    R = CAMERA_IN_MARKER[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    views = BonnLayout(folder, max_dt=0.02).views()
    for view, frame in zip(views, frames, strict=True):
        np.testing.assert_allclose(view.cam_to_world, frame.cam_to_world, atol=1e-3)
    # the marker poses as written are not the camera's: read as TUM they are far off
    tum = layouts.tum(
        tmp_path / "rgbd_dataset_freiburg3_livingroom", frames, layouts.bonn_marker_pose
    )
    with FolderFrames(tum) as opened:
        first = next(iter(opened))
    assert np.abs(first.cam_to_world[:3, :3] - frames[0].cam_to_world[:3, :3]).max() > 0.1


def test_seven_scenes_reads_its_frames(tmp_path, frames) -> None:
    folder = layouts.seven_scenes(tmp_path / "chess" / "seq-01", frames)
    assert _matching(folder) == {DatasetLayout.SEVEN_SCENES}
    assert detect_layout(tmp_path / "chess") is None
    (folder / "frame-000004.pose.txt").write_text("inf inf inf inf\n" * 4)  # tracking lost
    (folder / "frame-000005.depth.png").unlink()
    with FolderFrames(folder) as opened:
        got = list(opened)
        described = opened.describe()["topics"]
        dropped = dict(opened.stats.dropped)
    assert dropped == {"no_pose": 1, "no_depth": 1}
    assert len(got) == 4
    K = described["intrinsics"]
    assert (K["fx"], K["fy"], K["cx"], K["cy"]) == (585.0, 585.0, 320.0, 240.0)
    assert described["depth_scale"] == 1000.0
    for frame, ref in zip(got, frames, strict=False):
        assert not (frame.depth_m == 65.535).any()  # no reading is no depth
        np.testing.assert_array_equal(frame.depth_m == 0, ref.depth_m == 0)
        np.testing.assert_allclose(frame.depth_m, ref.depth_m, atol=5e-4)
        np.testing.assert_allclose(frame.cam_to_world, ref.cam_to_world, atol=1e-6)
        assert frame.stamp_ns == 0 or frame.stamp_ns % 33_333_333 == 0
    own = SevenScenesLayout(folder, max_dt=0.02).describe()["intrinsics"]
    assert own["source"] == "7-Scenes depth camera"
    with FolderFrames(folder, ReadOptions(intrinsics="525,525,319.5,239.5")) as opened:
        assert opened.describe()["topics"]["intrinsics"]["fx"] == 525.0
