"""A recording in several files is one recording: the third-party living-room frames written
whole and split in two (ROS 1 bags as ``rosbag record --split`` cuts them, MCAP files that
overlap), through the real writers, with the static TF in the first file only and the moving
TF crossing the boundary; the split files make the store the whole file makes. Files of
another kind or recording, or missing, are refused in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from care_maps.core.errors import IngestError
from care_maps.core.store import Store
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.source import RecordingFrames
from tests.support.cli import InProcessCli
from tests.support.encoders import TinyEncoder
from tests.support.faults import assert_fault
from tests.support.frames import load_livingroom
from tests.support.recordings import OPTICAL, Container, Stamped, robot_messages, write_bag

pytestmark = pytest.mark.slow

FRAMES = 12
"""Views of the recording: the split falls between view 5 and view 6."""
TF_LAG_NS = 45_000_000
"""How late each /tf message is logged after its stamp (more than a frame's 33 ms), so the
transform that poses the first file's last view lies in the second file."""


def _messages(
    root: Path, *, rgb: str = "/camera/color/image_raw", frame: str = OPTICAL
) -> list[Stamped]:
    """The living room as a robot records it: map -> base_link on /tf (logged late),
    base_link -> camera on /tf_static, colour, depth and camera info at each view."""
    return robot_messages(load_livingroom(root, FRAMES), rgb=rgb, frame=frame, tf_lag_ns=TF_LAG_NS)


def _cut(msgs: list[Stamped]) -> int:
    """Log time of the split: just after the colour image of view ``FRAMES // 2 - 1``."""
    stamps = sorted({t for topic, t, _ in msgs if topic.endswith("image_raw")})
    return stamps[FRAMES // 2 - 1] + 1


def _write_split(
    folder: Path, msgs: list[Stamped], container: Container, suffix: str
) -> tuple[Path, Path]:
    """The messages in two files: as ``rosbag record --split`` cuts them for a ROS 1 bag
    (by log time), overlapping for MCAP (the second file also holds the moving transforms
    of the first file's last two views, logged before the first file ends). The first in
    time is named after the second, so name order is not time order."""
    cut = _cut(msgs)
    if container is Container.ROS1:
        first = [m for m in msgs if m[1] < cut]
        second = [m for m in msgs if m[1] >= cut]
    else:
        early = cut - 2 * 33_333_333 - TF_LAG_NS
        late = [m[0] == "/tf" and early < m[1] < cut for m in msgs]
        first = [m for m, moved in zip(msgs, late, strict=True) if m[1] < cut and not moved]
        second = [m for m, moved in zip(msgs, late, strict=True) if m[1] >= cut or moved]
        assert any(late)
        assert second[0][1] < first[-1][1]  # the files overlap in time
    assert any(m[0] == "/tf_static" for m in first)
    assert not any(m[0] == "/tf_static" for m in second)
    return (
        write_bag(folder / f"run_b{suffix}", first, container),
        write_bag(folder / f"run_a{suffix}", second, container),
    )


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory, livingroom_root: Path) -> dict:
    """Per container, the whole recording and its two files (first in time, second)."""
    folder = tmp_path_factory.mktemp("split")
    msgs = _messages(livingroom_root)
    made = {}
    for container, suffix in ((Container.ROS1, ".bag"), (Container.MCAP, ".mcap")):
        whole = write_bag(folder / f"whole{suffix}", msgs, container)
        made[container] = (whole, _write_split(folder, msgs, container, suffix))
    return made


def _views(store: Path) -> tuple[list[int], np.ndarray, list[bytes]]:
    """Each view's stamp, pose, and colour and depth bytes."""
    frames = [f for _, f in Store(store).iter_frames(extras=False, in_map=False)]
    poses = np.stack([f.cam_to_world for f in frames])
    pixels = [f.rgb.tobytes() + f.depth_m.tobytes() for f in frames]
    return [f.stamp_ns for f in frames], poses, pixels


def _meta(store: Path) -> dict:
    return json.loads((store / "meta.json").read_text())


@pytest.mark.parametrize("container", [Container.ROS1, Container.MCAP])
def test_split_files_make_the_store_the_whole_file_makes(
    recordings: dict, tmp_path: Path, container: Container
) -> None:
    whole, (first, second) = recordings[container]
    one = run_ingest(whole, tmp_path / "one")
    # given out of time order, and named against it: read in the order of their times
    split = run_ingest([second, first], tmp_path / "split")
    stamps, poses, pixels = _views(one)
    got_stamps, got_poses, got_pixels = _views(split)
    assert len(stamps) == FRAMES  # every view posed: the boundary's view by TF of both files
    assert got_stamps == stamps
    np.testing.assert_array_equal(got_poses, poses)
    assert got_pixels == pixels
    a, b = _meta(one), _meta(split)
    for key in ("topics", "world_frame", "camera_frame", "camera_convention", "counts"):
        assert a[key] == b[key], key
    assert b["source"]["name"] == first.name
    assert [f["name"] for f in b["source"]["files"]] == [first.name, second.name]
    assert b["source"]["size"] == first.stat().st_size + second.stat().st_size
    assert "files" not in a["source"]  # one file's store is as it was


def test_the_grid_map_of_split_files_is_the_whole_files(recordings: dict, tmp_path: Path) -> None:
    whole, parts = recordings[Container.ROS1]
    tables = {}
    for name, source in (("one", whole), ("split", list(parts))):
        config = IngestConfig(vocabulary="tv,sofa,table,lamp")
        store = run_ingest(source, tmp_path / name, config, encoder=TinyEncoder())
        build_grid(store, GridConfig(cell_size=0.05, stride=2))
        tables[name] = {p.name: p.read_bytes() for p in sorted(store.glob("*.parquet"))}
    assert "cells.parquet" in tables["one"]
    assert tables["one"] == tables["split"]


def test_every_file_is_in_the_fingerprint(
    recordings: dict, tmp_path: Path, livingroom_root: Path
) -> None:
    _, (first, second) = recordings[Container.ROS1]
    parts = [tmp_path / first.name, tmp_path / second.name]
    for src, dst in zip((first, second), parts, strict=True):
        dst.write_bytes(src.read_bytes())
    store = run_ingest(parts, tmp_path / "store")
    built = _meta(store)["fingerprint"]
    views = (store / "views.parquet").stat().st_mtime_ns
    run_ingest(list(reversed(parts)), store)  # the same files: up to date, nothing rebuilt
    assert (store / "views.parquet").stat().st_mtime_ns == views
    # the second file re-recorded without its last view: the store is rebuilt
    msgs = _messages(livingroom_root)
    last = max(t for topic, t, _ in msgs if topic.endswith("image_raw"))
    shorter = [m for m in msgs if m[1] >= _cut(msgs) and not (m[1] == last and m[0] != "/tf")]
    parts[1].unlink()
    write_bag(parts[1], shorter, Container.ROS1)
    run_ingest(parts, store)
    assert _meta(store)["fingerprint"] != built
    assert Store(store).num_views == FRAMES - 1


def test_a_missing_file_is_refused_in_one_line(
    recordings: dict, tmp_path: Path, run_cli: InProcessCli
) -> None:
    _, (first, _) = recordings[Container.ROS1]
    missing = tmp_path / "run_c.bag"
    code, _, err = run_cli("ingest", first, missing, "--out", tmp_path / "store")
    assert_fault(code, err, rf"{missing}: no such file or directory; check the path")
    assert not (tmp_path / "store").exists()


def test_files_of_two_kinds_are_refused_in_one_line(
    recordings: dict, tmp_path: Path, run_cli: InProcessCli
) -> None:
    _, (bag, _) = recordings[Container.ROS1]
    _, (_, mcap) = recordings[Container.MCAP]
    code, _, err = run_cli("ingest", bag, mcap, "--out", tmp_path / "store")
    assert_fault(
        code, err, rf"{mcap}: is an MCAP file but {bag} is a ROS 1 bag; .* all of one kind"
    )
    with pytest.raises(IngestError, match="given twice"):
        run_ingest([bag, bag], tmp_path / "twice")


@pytest.mark.parametrize(
    ("other", "found"),
    [
        ({"rgb": "/other/color/image_raw"}, r"image topics .*, but .* not a file of the same"),
        (
            {"frame": "other_camera"},
            r"colour images .* in frame 'other_camera', but .* not a file of the",
        ),
    ],
)
def test_a_file_of_another_recording_is_refused_in_one_line(
    recordings: dict,
    tmp_path: Path,
    livingroom_root: Path,
    run_cli: InProcessCli,
    other: dict,
    found: str,
) -> None:
    _, (first, _) = recordings[Container.ROS1]
    msgs = _messages(livingroom_root, **other)
    foreign = write_bag(
        tmp_path / "foreign.bag", [m for m in msgs if m[1] >= _cut(msgs)], Container.ROS1
    )
    code, _, err = run_cli("ingest", first, foreign, "--out", tmp_path / "store")
    assert_fault(code, err, rf"^error: {foreign}: {found}")


def test_care_topics_reads_the_files_as_one(recordings: dict, run_cli: InProcessCli) -> None:
    whole, (first, second) = recordings[Container.MCAP]
    code, out, err = run_cli("topics", second, first)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == f"one recording in 2 files, in time order: {first}, {second}"
    code, alone, err = run_cli("topics", whole)
    assert code == 0, err
    # the same topics and counts, choices and geometry as the whole file's
    assert lines[1:] == alone.splitlines()


def test_the_frames_of_split_files_are_posed_across_the_boundary(recordings: dict) -> None:
    whole, (first, second) = recordings[Container.ROS1]
    with RecordingFrames([second, first]) as split:
        assert split.parts == (first, second)
        assert split.path == first
        got = [f.stamp_ns for f in split]
        assert split.stats.dropped == {}
    with RecordingFrames(whole) as one:
        assert got == [f.stamp_ns for f in one]


def test_the_static_chain_may_lie_in_a_later_file(
    recordings: dict, tmp_path: Path, livingroom_root: Path
) -> None:
    whole, _ = recordings[Container.ROS1]
    msgs = _messages(livingroom_root)
    cut = _cut(msgs)
    static = [m for m in msgs if m[0] == "/tf_static"]
    moving = [m for m in msgs if m[0] != "/tf_static"]
    # the mount published once, latched, and recorded only after the split
    first = write_bag(tmp_path / "run_0.bag", [m for m in moving if m[1] < cut], Container.ROS1)
    later = [(topic, cut, msg) for topic, _, msg in static]
    second = sorted(later + [m for m in moving if m[1] >= cut], key=lambda m: m[1])
    rest = write_bag(tmp_path / "run_1.bag", second, Container.ROS1)
    with RecordingFrames([first, rest]) as split:
        got = list(split)
    with RecordingFrames(whole) as one:
        expected = list(one)
    assert [f.stamp_ns for f in got] == [f.stamp_ns for f in expected]
    np.testing.assert_array_equal(
        np.stack([f.cam_to_world for f in got]), np.stack([f.cam_to_world for f in expected])
    )
