"""A dataset folder that cannot be read as it is gives one line naming the file and what to
do, with exit 1 and no traceback; views whose pose is lost are skipped and counted; and
options that belong to recordings are refused rather than ignored."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from PIL import Image

from care_maps.core.errors import IngestError
from care_maps.evaluate.pipeline import recordings_of
from care_maps.ingest.folders import DatasetLayout, detect_layout
from care_maps.ingest.folders.frames import FolderFrames
from care_maps.ingest.folders.generic import read_intrinsics_json
from care_maps.ingest.readers import is_recording, recordings_in
from care_maps.ingest.source import ReadOptions
from care_maps.ingest.write import write_recording
from tests.support import layouts


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


def test_a_missing_poses_file_is_named(tmp_path, frames, run_cli) -> None:
    folder = layouts.tum(tmp_path / "rgbd_dataset_livingroom", frames)
    (folder / "groundtruth.txt").unlink()
    out = tmp_path / "store"
    line = _one_line_error(run_cli, "ingest", folder, "--out", out, "--intrinsics", "primesense")
    assert "groundtruth.txt: missing" in line
    assert not (tmp_path / "store").exists()


def test_a_tum_folder_without_a_camera_is_refused(tmp_path, frames, run_cli) -> None:
    """No sensor in the name, no intrinsics.json, no --intrinsics: no default camera is
    guessed; care topics and care ingest both say what to give."""
    folder = layouts.tum(tmp_path / "rgbd_dataset_livingroom", frames)
    for command in (("topics", folder), ("ingest", folder, "--out", tmp_path / "store")):
        line = _one_line_error(run_cli, *command)
        assert f"{folder}: the folder's name names no TUM sensor" in line
        assert "--intrinsics" in line
        assert "intrinsics.json" in line
    assert not (tmp_path / "store").exists()
    code, out, err = run_cli("topics", folder, "--intrinsics", "primesense")
    assert code == 0, err
    assert "'source': '--intrinsics'" in out


def test_a_pose_count_that_differs_from_the_images_is_named(tmp_path, frames, run_cli):
    scene = layouts.replica(tmp_path / "Replica", frames)
    lines = (scene / "traj.txt").read_text().splitlines()
    (scene / "traj.txt").write_text("\n".join(lines[:-1]) + "\n")
    line = _one_line_error(run_cli, "topics", scene)
    assert "traj.txt: 3 poses for 4 colour images" in line
    folder = layouts.redwood(tmp_path / "redwood", frames)
    (folder / "depth" / "00003.png").unlink()
    line = _one_line_error(run_cli, "ingest", folder, "--out", tmp_path / "store")
    assert "4 colour images, 3 depth images, 4 poses" in line


def test_an_unreadable_image_is_named(tmp_path, frames, run_cli) -> None:
    folder = layouts.redwood(tmp_path / "redwood", frames)
    image = folder / "image" / "00002.jpg"
    image.write_bytes(image.read_bytes()[:200])  # truncated
    line = _one_line_error(run_cli, "ingest", folder, "--out", tmp_path / "store")
    assert f"{image}: cannot read the image" in line
    assert not (tmp_path / "store").exists()


def test_a_malformed_line_is_named_with_its_number(tmp_path, frames) -> None:
    folder = layouts.generic(tmp_path / "generic", frames)
    lines = (folder / "poses.txt").read_text().splitlines()
    lines[2] = lines[2] + " 1.0"
    (folder / "poses.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(IngestError, match=r"poses\.txt: line 3 has 9 fields, expected 8"):
        FolderFrames(folder).__enter__()


def test_a_folder_of_two_layouts_names_both_and_the_option(tmp_path, frames, run_cli):
    folder = layouts.generic(tmp_path / "both", frames)
    redwood = layouts.redwood(tmp_path / "redwood", frames)
    (folder / "trajectory.log").write_bytes((redwood / "trajectory.log").read_bytes())
    line = _one_line_error(run_cli, "topics", folder)
    assert "more than one dataset layout (redwood, generic)" in line
    assert "--format redwood" in line
    code, out, err = run_cli("topics", folder, "--format", "generic")
    assert code == 0, err
    assert "layout generic: 4 views" in out
    assert is_recording(folder)  # one recording: ingest says which layout to pick


def test_a_lost_pose_is_skipped_and_counted(tmp_path, frames) -> None:
    scene = layouts.replica(tmp_path / "Replica", frames)
    lines = (scene / "traj.txt").read_text().splitlines()
    lines[1] = " ".join(["-inf"] * 16)  # tracking lost, as ScanNet writes it
    (scene / "traj.txt").write_text("\n".join(lines) + "\n")
    with FolderFrames(scene) as opened:
        got = list(opened)
        stats = opened.stats
    assert len(got) == 3
    assert stats.dropped == {"no_pose": 1}
    assert stats.rgb_messages == 4


def test_a_pose_that_is_not_rigid_or_jumps_is_refused(tmp_path, frames) -> None:
    scene = layouts.replica(tmp_path / "Replica", frames)
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


def test_options_of_recordings_are_refused_for_a_folder(tmp_path, frames, run_cli):
    folder = layouts.redwood(tmp_path / "redwood", frames)
    line = _one_line_error(run_cli, "topics", folder, "--rgb", "/camera/rgb", "--static-pose")
    assert "--rgb, --static-pose only apply to recordings" in line
    bag = write_recording(tmp_path / "rec.mcap", frames, fmt="mcap")
    line = _one_line_error(run_cli, "ingest", bag, "--out", tmp_path / "s", "--format", "tum")
    assert "--format tum reads dataset folders, and this is a recording" in line
    with pytest.raises(IngestError, match=r"no metadata\.yaml.*nor a dataset folder"):
        FolderFrames(tmp_path, ReadOptions(format=None)).__enter__()


def test_a_forced_layout_says_what_the_folder_lacks(tmp_path, frames, run_cli) -> None:
    folder = layouts.redwood(tmp_path / "redwood", frames)
    line = _one_line_error(run_cli, "topics", folder, "--format", "generic")
    assert "intrinsics.json: missing" in line


def test_scene_folders_are_recordings_for_care_run(tmp_path, frames) -> None:
    release = tmp_path / "Replica"
    layouts.replica(release, frames, "room0")
    layouts.replica(release, frames, "room1")
    layouts.tum(release / "rgbd_dataset_livingroom", frames)
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


def test_a_replica_render_of_another_size_needs_its_camera(tmp_path, frames, run_cli):
    scene = layouts.replica(tmp_path / "Replica", frames)
    (tmp_path / "Replica" / "cam_params.json").unlink()  # NICE-SLAM's 1200x680 camera
    line = _one_line_error(run_cli, "ingest", scene, "--out", tmp_path / "store")
    assert "640x480 image, but the intrinsics (NICE-SLAM replica.yaml) are for 1200x680" in line
    assert "cam_params.json" in line
    camera = {"camera": {"w": 640, "h": 480, "fx": 525.0, "fy": 525.0, "cx": 319.5,
                         "cy": 239.5, "scale": 6553.5}}  # fmt: skip
    (scene / "cam_params.json").write_text(json.dumps(camera))
    with FolderFrames(scene) as opened:
        assert opened.describe()["topics"]["intrinsics"]["source"] == "cam_params.json"


# -- the generic layout's bad input: one line each, naming the file ---------------------------


def _rewrite_json(folder, **fields) -> None:
    path = folder / "intrinsics.json"
    data = json.loads(path.read_text())
    data.update(fields)
    for key in [k for k, v in data.items() if v is None]:
        del data[key]
    path.write_text(json.dumps(data))


def test_stamps_in_nanoseconds_are_refused_at_read(tmp_path, frames, run_cli) -> None:
    folder = layouts.generic(tmp_path / "generic", frames)
    lines = (folder / "poses.txt").read_text().splitlines()
    ns = [f"{f.stamp_ns + 1_700_000_000 * 10**9} {line.split(maxsplit=1)[1]}"
          for f, line in zip(frames, lines, strict=True)]  # fmt: skip
    (folder / "poses.txt").write_text("\n".join(ns) + "\n")
    line = _one_line_error(run_cli, "ingest", folder, "--out", tmp_path / "store")
    assert f"{folder / 'poses.txt'}: line 1: time" in line
    assert "stamps look like nanoseconds" in line
    assert "write seconds" in line
    assert "internal error" not in line


def test_a_16_bit_grey_colour_image_is_scaled_to_8_bit(tmp_path, frames) -> None:
    """A 16-bit grey PNG (Pillow's I;16) is read as its values scaled by 255/65535, the same
    grey in three channels, not clipped at 255 (all white)."""
    folder = layouts.generic(tmp_path / "generic", frames[:1])
    grey16 = (np.arange(480 * 640, dtype=np.int64).reshape(480, 640) * 211) % 65536
    Image.fromarray(grey16.astype(np.uint16)).save(folder / "rgb" / "000000.png")
    with FolderFrames(folder) as opened:
        rgb = next(iter(opened)).rgb
    # the reference, independently: 8-bit value v8 of v16 is the nearest to v16 / 257
    expected = np.floor(grey16 / 257.0 + 0.5).astype(np.uint8)
    assert rgb.dtype == np.uint8
    np.testing.assert_array_equal(rgb, np.repeat(expected[..., None], 3, axis=-1))
    assert (rgb.min(), rgb.max()) == (0, 255)


def test_a_view_of_another_size_is_refused_without_width_and_height(
    tmp_path, frames, run_cli
) -> None:
    folder = layouts.generic(tmp_path / "generic", frames)
    _rewrite_json(folder, width=None, height=None)
    image = folder / "rgb" / "000002.png"
    Image.fromarray(frames[2].rgb[:240, :320]).save(image)
    Image.fromarray(np.zeros((240, 320), np.uint16)).save(folder / "depth" / "000002.png")
    line = _one_line_error(run_cli, "ingest", folder, "--out", tmp_path / "store")
    assert f"{image}: 320x240 image, but the first view 000000.png is 640x480" in line
    assert "intrinsics.json's fx, fy, cx, cy and its width and height fields" in line


@pytest.mark.parametrize("value", ["Infinity", "NaN", "0", "-5", '"mm"'])
def test_a_bad_depth_scale_is_named(tmp_path, frames, run_cli, value: str) -> None:
    folder = layouts.generic(tmp_path / "generic", frames)
    path = folder / "intrinsics.json"
    text = path.read_text().replace('"depth_scale": 1000.0', f'"depth_scale": {value}')
    path.write_text(text)
    assert json.loads(text)  # Python's json takes Infinity and NaN
    line = _one_line_error(run_cli, "topics", folder)
    assert line.startswith(f"error: {path}: depth_scale")
    assert "fix the depth_scale field" in line or "in the depth_scale field" in line


@pytest.mark.parametrize(("field", "value"), [("fx", "Infinity"), ("cy", "NaN"), ("fy", "0")])
def test_a_camera_that_is_not_one_is_named(tmp_path, frames, field: str, value: str):
    folder = layouts.generic(tmp_path / "generic", frames)
    path = folder / "intrinsics.json"
    data = json.loads(path.read_text())
    text = path.read_text().replace(f'"{field}": {data[field]}', f'"{field}": {value}')
    path.write_text(text)
    with pytest.raises(IngestError, match=rf"^{re.escape(str(path))}: {field} .*fix those fields"):
        read_intrinsics_json(path)
    with pytest.raises(IngestError, match=rf"^{re.escape(str(path))}: {field} "):
        FolderFrames(folder).__enter__()
