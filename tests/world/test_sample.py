"""The bundled sample recording: present, small, complete, readable by ingest and by Rerun."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import numpy as np
import pytest

from care_maps.truth.formats.native import read_native

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "care_maps" / "data" / "sample" / "scene_000.mcap"


def test_sample_is_small_and_has_ground_truth() -> None:
    total = sum(p.stat().st_size for p in SAMPLE.parent.iterdir())
    assert total <= 15 * 2**20
    gt = read_native(SAMPLE)
    names = set(gt.instances.column("class_name").to_pylist())
    assert 15 <= len(names) <= 30
    assert len(gt.rooms) >= 2
    assert gt.info["unseen_instances"] == []
    index = json.loads((SAMPLE.parent / "index.json").read_text())
    assert index["recordings"][0]["recording"] == SAMPLE.name


def test_readme_command_matches_how_the_sample_was_made() -> None:
    readme = (ROOT / "care_maps" / "data" / "README.md").read_text()
    line = next(ln for ln in readme.splitlines() if ln.startswith("care sample make"))
    args = shlex.split(line)
    flag = {args[i]: args[i + 1] for i in range(3, len(args) - 1) if args[i].startswith("--")}
    config = json.loads((SAMPLE.parent / "index.json").read_text())["config"]
    assert int(flag["--seed"]) == config["seed"]
    assert int(flag["--rooms"]) == config["num_rooms"]
    assert int(flag["--width"]) == config["width"]
    assert int(flag["--height"]) == config["height"]
    assert int(flag["--frames"]) == config["frames"]
    assert "--jpeg" in args
    assert config["compressed_rgb"]


def test_rerun_reads_the_sample_mcap() -> None:
    from rerun.chunk import McapReader

    rows: dict[str, int] = {}
    for chunk in McapReader(SAMPLE).stream():
        for name in chunk.to_record_batch().schema.names:
            key = f"{chunk.entity_path} {name}"
            rows[key] = rows.get(key, 0) + chunk.num_rows
    frames = json.loads((SAMPLE.parent / "index.json").read_text())["recordings"][0]["num_frames"]
    assert rows.get("/camera/color/image_raw/compressed EncodedImage:blob") == frames
    assert rows.get("/camera/depth/image_raw DepthImage:buffer") == frames


def test_sample_ingests_and_lands_on_ground_truth() -> None:
    from care_maps.geometry.transforms import backproject, transform_points
    from care_maps.ingest.source import RecordingFrames

    gt = read_native(SAMPLE)
    with RecordingFrames(SAMPLE) as frames:
        assert frames.label_names == gt.class_names
        for i, f in enumerate(frames):
            if i % 20:
                continue
            pts, pix = backproject(f.depth_m, f.K, stride=4)
            world = transform_points(f.cam_to_world, pts)
            agree = gt.label_points(world) == f.extras["instance"][pix[:, 1], pix[:, 0]]
            assert np.mean(agree) > 0.9


@pytest.mark.slow
def test_readme_command_regenerates_the_sample_byte_for_byte(tmp_path: Path) -> None:
    from care_maps.world.record import DatasetConfig, make_dataset

    readme = (ROOT / "care_maps" / "data" / "README.md").read_text()
    args = shlex.split(next(ln for ln in readme.splitlines() if ln.startswith("care sample make")))
    flag = {args[i]: args[i + 1] for i in range(3, len(args) - 1) if args[i].startswith("--")}
    make_dataset(
        DatasetConfig(
            out=tmp_path,
            scenes=int(flag["--scenes"]),
            seed=int(flag["--seed"]),
            num_rooms=int(flag["--rooms"]),
            width=int(flag["--width"]),
            height=int(flag["--height"]),
            frames=int(flag["--frames"]),
            compressed_rgb="--jpeg" in args,
            workers=1,
            progress=False,
        )
    )
    for name in ("scene_000.gt.parquet", "scene_000.gt.json"):
        assert (tmp_path / name).read_bytes() == (SAMPLE.parent / name).read_bytes(), name
    # Messages: the same topics, stamps and bytes, except that /tf poses (trigonometry of
    # the trajectory) may differ in the last bits between numpy/scipy builds.
    new, old = _messages(tmp_path / SAMPLE.name), _messages(SAMPLE)
    assert [m[:2] for m in new] == [m[:2] for m in old]
    for (topic, _, a), (_, _, b) in zip(new, old, strict=True):
        if topic != "/tf":
            assert a == b, topic
            continue
        np.testing.assert_allclose(_tf_values(a), _tf_values(b), rtol=0, atol=1e-12)


def _messages(path: Path) -> list[tuple[str, int, bytes]]:
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages()]


def _tf_values(data: bytes) -> list[float]:
    from rosbags.typesys import Stores, get_typestore

    msg = get_typestore(Stores.ROS2_HUMBLE).deserialize_cdr(data, "tf2_msgs/msg/TFMessage")
    out = []
    for t in msg.transforms:
        tr, q = t.transform.translation, t.transform.rotation
        out += [tr.x, tr.y, tr.z, q.x, q.y, q.z, q.w]
    return out
