"""A dataset folder that cannot be read as it is gives one line naming the file and what to
do, with exit 1 and no traceback; views whose pose is lost are skipped and counted; and
options that belong to recordings are refused rather than ignored."""

from __future__ import annotations

import json

import pytest

from care.errors import IngestError
from evaluate.pipeline import recordings_of
from ingest.folders import DatasetLayout, detect_layout
from ingest.folders.frames import FolderFrames
from ingest.readers import is_recording, recordings_in
from ingest.source import ReadOptions
from ingest.write import write_recording


@pytest.fixture
def frames(livingroom40):
    return livingroom40[:4]


def _one_line_error(run_cli, *args) -> str:
    code, out, err = run_cli(*args)
    assert code == 1, (out, err)
    # what a terminal shows: a progress bar's carriage returns overwrite its line
    lines = [shown for line in err.split("\n") if (shown := line.split("\r")[-1].strip())]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_a_missing_poses_file_is_named(tmp_path, frames, lay, run_cli) -> None:
    folder = lay.tum(tmp_path / "rgbd_dataset_livingroom", frames)
    (folder / "groundtruth.txt").unlink()
    line = _one_line_error(run_cli, "ingest", folder, "--out", tmp_path / "store")
    assert "groundtruth.txt: missing" in line
    assert not (tmp_path / "store").exists()


def test_a_pose_count_that_differs_from_the_images_is_named(tmp_path, frames, lay, run_cli):
    scene = lay.replica(tmp_path / "Replica", frames)
    lines = (scene / "traj.txt").read_text().splitlines()
    (scene / "traj.txt").write_text("\n".join(lines[:-1]) + "\n")
    line = _one_line_error(run_cli, "topics", scene)
    assert "traj.txt: 3 poses for 4 colour images" in line
    folder = lay.redwood(tmp_path / "redwood", frames)
    (folder / "depth" / "00003.png").unlink()
    line = _one_line_error(run_cli, "ingest", folder, "--out", tmp_path / "store")
    assert "4 colour images, 3 depth images, 4 poses" in line


def test_an_unreadable_image_is_named(tmp_path, frames, lay, run_cli) -> None:
    folder = lay.redwood(tmp_path / "redwood", frames)
    image = folder / "image" / "00002.jpg"
    image.write_bytes(image.read_bytes()[:200])  # truncated
    line = _one_line_error(run_cli, "ingest", folder, "--out", tmp_path / "store")
    assert f"{image}: cannot read the image" in line
    assert not (tmp_path / "store").exists()


def test_a_malformed_line_is_named_with_its_number(tmp_path, frames, lay) -> None:
    folder = lay.generic(tmp_path / "generic", frames)
    lines = (folder / "poses.txt").read_text().splitlines()
    lines[2] = lines[2] + " 1.0"
    (folder / "poses.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(IngestError, match=r"poses\.txt: line 3 has 9 fields, expected 8"):
        FolderFrames(folder).__enter__()


def test_a_folder_of_two_layouts_names_both_and_the_option(tmp_path, frames, lay, run_cli):
    folder = lay.generic(tmp_path / "both", frames)
    redwood = lay.redwood(tmp_path / "redwood", frames)
    (folder / "trajectory.log").write_bytes((redwood / "trajectory.log").read_bytes())
    line = _one_line_error(run_cli, "topics", folder)
    assert "more than one dataset layout (redwood, generic)" in line
    assert "--format redwood" in line
    code, out, err = run_cli("topics", folder, "--format", "generic")
    assert code == 0, err
    assert "layout generic: 4 views" in out
    assert is_recording(folder)  # one recording: ingest says which layout to pick


def test_a_lost_pose_is_skipped_and_counted(tmp_path, frames, lay) -> None:
    scene = lay.replica(tmp_path / "Replica", frames)
    lines = (scene / "traj.txt").read_text().splitlines()
    lines[1] = " ".join(["-inf"] * 16)  # tracking lost, as ScanNet writes it
    (scene / "traj.txt").write_text("\n".join(lines) + "\n")
    with FolderFrames(scene) as opened:
        got = list(opened)
        stats = opened.stats
    assert len(got) == 3
    assert stats.dropped == {"no_pose": 1}
    assert stats.rgb_messages == 4


def test_a_pose_that_is_not_rigid_or_jumps_is_refused(tmp_path, frames, lay) -> None:
    scene = lay.replica(tmp_path / "Replica", frames)
    lines = (scene / "traj.txt").read_text().splitlines()
    values = [float(v) for v in lines[2].split()]
    (scene / "traj.txt").write_text(
        "\n".join([*lines[:2], " ".join(str(v * 2) for v in values), *lines[3:]]) + "\n"
    )
    with pytest.raises(IngestError, match=r"frame000002\.jpg \(pose from traj\.txt\).*not a rigid"):
        list(FolderFrames(scene).__enter__())
    values[3] += 100.0  # 100 m in a 30th of a second
    (scene / "traj.txt").write_text(
        "\n".join([*lines[:2], " ".join(str(v) for v in values), *lines[3:]]) + "\n"
    )
    with pytest.raises(IngestError, match=r"frame000002\.jpg.*faster than --max-speed"):
        list(FolderFrames(scene).__enter__())


def test_options_of_recordings_are_refused_for_a_folder(tmp_path, frames, lay, run_cli):
    folder = lay.redwood(tmp_path / "redwood", frames)
    line = _one_line_error(run_cli, "topics", folder, "--rgb", "/camera/rgb", "--static-pose")
    assert "--rgb, --static-pose only apply to recordings" in line
    bag = write_recording(tmp_path / "rec.mcap", frames, fmt="mcap")
    line = _one_line_error(run_cli, "ingest", bag, "--out", tmp_path / "s", "--format", "tum")
    assert "--format tum reads dataset folders, and this is a recording" in line
    with pytest.raises(IngestError, match=r"no metadata\.yaml.*nor a dataset folder"):
        FolderFrames(tmp_path, ReadOptions(format=None)).__enter__()


def test_a_forced_layout_says_what_the_folder_lacks(tmp_path, frames, lay, run_cli) -> None:
    folder = lay.redwood(tmp_path / "redwood", frames)
    line = _one_line_error(run_cli, "topics", folder, "--format", "generic")
    assert "intrinsics.json: missing" in line


def test_scene_folders_are_recordings_for_care_run(tmp_path, frames, lay) -> None:
    release = tmp_path / "Replica"
    lay.replica(release, frames, "room0")
    lay.replica(release, frames, "room1")
    lay.tum(release / "rgbd_dataset_livingroom", frames)
    write_recording(release / "hall.mcap", frames, fmt="mcap")
    assert detect_layout(release / "room0") == DatasetLayout.REPLICA
    assert not is_recording(release)
    assert [p.name for p in recordings_in(release)] == [
        "hall.mcap", "rgbd_dataset_livingroom", "room0", "room1",
    ]  # fmt: skip
    assert recordings_of(release / "room1") == [("room1", release / "room1")]
    assert [name for name, _ in recordings_of(release)] == [
        "hall", "rgbd_dataset_livingroom", "room0", "room1",
    ]  # fmt: skip


def test_a_replica_render_of_another_size_needs_its_camera(tmp_path, frames, lay, run_cli):
    scene = lay.replica(tmp_path / "Replica", frames)
    (tmp_path / "Replica" / "cam_params.json").unlink()  # NICE-SLAM's 1200x680 camera
    line = _one_line_error(run_cli, "ingest", scene, "--out", tmp_path / "store")
    assert "640x480 image, but the intrinsics (NICE-SLAM replica.yaml) are for 1200x680" in line
    assert "cam_params.json" in line
    camera = {"camera": {"w": 640, "h": 480, "fx": 525.0, "fy": 525.0, "cx": 319.5,
                         "cy": 239.5, "scale": 6553.5}}  # fmt: skip
    (scene / "cam_params.json").write_text(json.dumps(camera))
    with FolderFrames(scene) as opened:
        assert opened.describe()["topics"]["intrinsics"]["source"] == "cam_params.json"
