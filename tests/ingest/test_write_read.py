"""Recordings written by care_maps.ingest.write in every container format read back exactly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap_ros2.reader import read_ros2_messages

from care_maps.core.errors import IngestError
from care_maps.core.store import Store
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.readers import open_reader
from care_maps.ingest.source import ReadOptions, RecordingFrames
from care_maps.ingest.write import BASE_FRAME, CAMERA_FRAME, TOPICS, WORLD_FRAME, write_recording
from care_maps.runtime.execution import Execution
from tests.support.encoders import TinyEncoder
from tests.support.frames import K_SMALL, smooth_rgb, synthetic_frames
from tests.support.messages import image_msg, odometry_msg
from tests.support.recordings import rgbd_messages, write_bag

QUIET = Execution(progress=False)

FORMATS = [
    ("mcap", "rec.mcap", "sqlite3"),
    ("ros2", "rec_sqlite3", "sqlite3"),
    ("ros2", "rec_mcap", "mcap"),
    ("ros1", "rec.bag", "sqlite3"),
]


@pytest.mark.parametrize(("fmt", "name", "storage"), FORMATS)
def test_round_trip_every_format(tmp_path: Path, fmt: str, name: str, storage: str) -> None:
    frames = synthetic_frames(5, extras=True)
    path = write_recording(
        tmp_path / name,
        iter(frames),
        fmt=fmt,
        ros2_storage=storage,
        label_names=["void", "chair", "table"],
    )
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())  # no temporary left
    with RecordingFrames(path) as rf:
        got = list(rf)
        assert rf.label_names == ("void", "chair", "table")
        assert rf.world_frame == WORLD_FRAME
        assert rf.camera_frame == CAMERA_FRAME
    assert len(got) == len(frames)
    for a, b in zip(frames, got, strict=True):
        assert b.stamp_ns == a.stamp_ns
        np.testing.assert_array_equal(b.rgb, a.rgb)
        np.testing.assert_allclose(b.depth_m, a.depth_m, atol=5e-4)  # 16UC1 millimetres
        np.testing.assert_allclose(b.K, a.K, atol=1e-12)
        np.testing.assert_allclose(b.cam_to_world, a.cam_to_world, atol=1e-9)
        np.testing.assert_array_equal(b.extras["class"], a.extras["class"])
        np.testing.assert_array_equal(b.extras["instance"], a.extras["instance"])


def test_mcap_is_readable_by_mcap_ros2(tmp_path: Path) -> None:
    """An independent decoder (mcap-ros2-support) sees the ROS layout the contract promises."""
    frames = synthetic_frames(2)
    path = write_recording(tmp_path / "r.mcap", frames, fmt="mcap")
    seen: dict[str, list] = {}
    for m in read_ros2_messages(str(path)):
        seen.setdefault(m.channel.topic, []).append(m.ros_msg)
    assert set(seen) == {TOPICS[k] for k in ("rgb", "depth", "camera_info", "tf", "tf_static")}
    img = seen[TOPICS["rgb"]][0]
    assert (img.encoding, img.width, img.height) == ("rgb8", 32, 24)
    np.testing.assert_array_equal(
        np.frombuffer(bytes(img.data), np.uint8).reshape(24, 32, 3), frames[0].rgb
    )
    depth = seen[TOPICS["depth"]][1]
    assert depth.encoding == "16UC1"
    mm = np.frombuffer(bytes(depth.data), "<u2").reshape(24, 32)
    np.testing.assert_array_equal(mm, np.round(frames[1].depth_m * 1000).astype(np.uint16))
    static = seen[TOPICS["tf_static"]][0].transforms[0]
    assert (static.header.frame_id, static.child_frame_id) == (BASE_FRAME, CAMERA_FRAME)
    dyn = seen[TOPICS["tf"]][0].transforms[0]
    assert (dyn.header.frame_id, dyn.child_frame_id) == (WORLD_FRAME, BASE_FRAME)
    np.testing.assert_allclose(np.reshape(seen[TOPICS["camera_info"]][0].k, (3, 3)), K_SMALL)


def test_ros1_camera_info_uses_upper_case_fields(tmp_path: Path) -> None:
    path = write_recording(tmp_path / "r.bag", synthetic_frames(2), fmt="ros1")
    with open_reader(path) as reader:
        infos = [m for _, _, m in reader.messages([TOPICS["camera_info"]])]
        latched = [c for c in reader._reader.connections if c.topic == TOPICS["tf_static"]]
    assert hasattr(infos[0], "K")
    assert not hasattr(infos[0], "k")
    assert latched[0].ext.latching == 1


def test_compressed_rgb(tmp_path: Path) -> None:
    frames = synthetic_frames(3)
    path = write_recording(tmp_path / "r.mcap", frames, fmt="mcap", compressed_rgb=True)
    with RecordingFrames(path) as rf:
        assert rf.selection.rgb == TOPICS["rgb_compressed"]
        got = list(rf)
    for a, b in zip(frames, got, strict=True):
        assert np.abs(b.rgb.astype(int) - a.rgb).mean() < 3  # JPEG


def test_depth_offset_within_and_beyond_max_dt(tmp_path: Path) -> None:
    frames = synthetic_frames(6)
    path = write_recording(tmp_path / "r.mcap", frames, fmt="mcap", depth_offset_ns=15_000_000)
    with RecordingFrames(path) as rf:
        assert len(list(rf)) == 6
    with (
        RecordingFrames(path, ReadOptions(max_dt=0.01)) as rf,
        pytest.raises(
            IngestError, match=r"within --max-dt 10 ms \(nearest was 15 ms\); raise --max-dt"
        ),
    ):
        list(rf)
    assert rf.stats.dropped["no_depth"] == 6


def test_pipeline_store_meta_and_idempotence(tmp_path: Path) -> None:
    frames = synthetic_frames(4, extras=True)
    rec = write_recording(tmp_path / "r.bag", frames, fmt="ros1", label_names=["void", "a", "b"])
    enc = TinyEncoder()
    out = run_ingest(rec, tmp_path / "store", run=QUIET, encoder=enc)
    store = Store(out)
    assert enc.prepared_with == ("void", "a", "b")
    meta = store.meta
    assert meta.counts == {"rgb_messages": 4, "frames": 4, "dropped": {}, "skipped": {}}
    assert meta.topics["rgb"] == TOPICS["rgb"]
    assert meta.source.size == rec.stat().st_size
    assert meta.label_names == ("void", "a", "b")
    # Features equal the encoder applied to the original frames (float16 storage).
    expected = enc.encode_views(frames)
    for view_id, feat in store.iter_features():
        np.testing.assert_allclose(feat, expected[view_id], atol=2e-3)
    names, emb = store.text_embeddings()
    assert names == ["void", "a", "b"]
    np.testing.assert_allclose(emb, enc.encode_text(names), atol=1e-6)
    np.testing.assert_allclose(store.poses(), np.stack([f.cam_to_world for f in frames]), atol=1e-9)
    # Same inputs: skipped (meta.json untouched); changed options: rebuilt.
    stamp = (out / "meta.json").stat().st_mtime_ns
    run_ingest(rec, out, run=QUIET, encoder=enc)
    assert (out / "meta.json").stat().st_mtime_ns == stamp
    run_ingest(rec, out, IngestConfig(read=ReadOptions(max_dt=0.03)), run=QUIET)
    assert json.loads((out / "meta.json").read_text())["encoder"] is None
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_pose_source_odometry(tmp_path: Path) -> None:
    """A recording without TF whose pose comes from nav_msgs/Odometry of the camera frame."""
    msgs = rgbd_messages(
        lambda i, t: image_msg(t, smooth_rgb(i), "rgb8"),
        lambda i, t: image_msg(t, np.full((24, 32), 2000, np.uint16), "16UC1"),
        tf=False,
    )
    for i in range(3):
        t = 10**9 + i * 100_000_000
        place = np.eye(4)
        place[:3, 3] = (float(i), 0.0, 0.5)
        odom = odometry_msg(t, place, "odom", "camera_optical_frame")
        msgs.append(("/odom", t, odom))
    msgs.sort(key=lambda m: m[1])
    path = write_bag(tmp_path / "odom_bag", msgs)
    with RecordingFrames(path) as rf:
        got = list(rf)
        assert rf.selection.pose_source == "/odom"
        assert rf.world_frame == "odom"
    np.testing.assert_allclose([f.cam_to_world[0, 3] for f in got], [0.0, 1.0, 2.0])


def test_vocabulary_file_text_embeddings_cached(tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "r.mcap", synthetic_frames(2), fmt="mcap")
    vocab = tmp_path / "vocab.txt"
    vocab.write_text("# classes\nchair\nsofa table\n\nchair\n")
    enc = TinyEncoder()
    out = run_ingest(
        rec, tmp_path / "store", IngestConfig(vocabulary=str(vocab)), run=QUIET, encoder=enc
    )
    names, emb = Store(out).text_embeddings()
    assert names == ["chair", "sofa table"]
    np.testing.assert_allclose(emb, enc.encode_text(names), atol=1e-6)
    assert Store(out).encoder.vocabulary == ("chair", "sofa table")
