"""``care ingest --rrd`` and ``care topics`` through the CLI; the .rrd read back with RrdReader."""

from __future__ import annotations

from pathlib import Path

import pytest
from rerun.chunk import RrdReader

from care_maps.core.store import Store
from care_maps.core.viz import rrd_entity_counts
from care_maps.ingest import viz
from care_maps.ingest.write import write_recording
from tests.support.frames import load_livingroom, synthetic_frames

pytestmark = pytest.mark.slow


def test_ingest_logs_rerun_entities(run_cli, tmp_path: Path) -> None:
    rec = write_recording(tmp_path / "r.mcap", synthetic_frames(7), fmt="mcap")
    rrd = tmp_path / "ingest.rrd"
    code, out, err = run_cli(
        "ingest", rec, "--out", tmp_path / "store", "--rrd", rrd, "--rrd-every", "3"
    )
    assert code == 0, err
    assert "7 views from 7 colour images" in out
    assert Store(tmp_path / "store").num_views == 7
    counts = rrd_entity_counts(rrd)
    e = lambda name: "/" + name  # noqa: E731
    assert counts[(e(viz.RGB_ENTITY), "EncodedImage:blob")] == 7
    assert counts[(e(viz.DEPTH_ENTITY), "EncodedDepthImage:blob")] == 7
    assert counts[(e(viz.CAMERA_ENTITY), "Pinhole:image_from_camera")] == 1  # static
    assert counts[(e(viz.CAMERA_ENTITY), "Transform3D:translation")] == 7
    for index in (0, 3, 6):  # the map builds up: one entity per logged frame
        assert counts[(e(f"{viz.MAP_ENTITY}/{index}"), "Points3D:positions")] == 1
    # the path so far from the second frame on
    assert counts[(e(viz.TRAJECTORY_ENTITY), "LineStrips3D:strips")] == 6
    assert RrdReader(rrd).blueprints()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    # the depth view's scale, drawn once with the depth view's own colour map and range
    assert counts[(e(viz.DEPTH_SCALE_ENTITY), "DepthImage:buffer")] == 1
    # by default a short recording has every view back-projected
    again = tmp_path / "again.rrd"
    code, _, err = run_cli("ingest", rec, "--out", tmp_path / "store2", "--rrd", again)
    assert code == 0, err
    clouds = {p for p, c in rrd_entity_counts(again) if p.startswith(e(viz.MAP_ENTITY) + "/")}
    assert clouds == {e(f"{viz.MAP_ENTITY}/{i}") for i in range(7)}


def test_topics_lists_and_shows_choice(run_cli, tmp_path: Path) -> None:
    rec = write_recording(
        tmp_path / "r.bag",
        synthetic_frames(2, extras=True),
        fmt="ros1",
        label_names=["void", "x"],
    )
    code, out, _ = run_cli("topics", rec)
    assert code == 0
    assert "/camera/color/image_raw" in out
    assert "sensor_msgs/msg/CameraInfo" in out
    assert "rgb          /camera/color/image_raw" in out
    assert "class_names  /care/class_names" in out
    assert "world frame  map, camera frame camera_optical_frame" in out


def test_topics_on_talker_bag(run_cli, shared_data: Path) -> None:
    code, out, _ = run_cli("topics", shared_data / "rosbag2" / "talker_sqlite3")
    assert code == 1
    assert "/topic" in out
    assert "std_msgs/msg/String" in out
    assert "no image topic" in out


def test_rrd_of_an_up_to_date_store_is_written_from_it(
    run_cli, tmp_path: Path, livingroom_root: Path, save_tiny_clip
) -> None:
    """``--rrd`` on a store that is up to date writes the file from the store's views: the
    store is not ingested again and the maps built in it stay, byte for byte. The file
    holds what an ingest that logged would have (the same entities, counts and poses)."""
    import hashlib

    import numpy as np

    from care_maps.core.frames import Frame

    frames = []  # third-party frames at a quarter of their size
    for f in load_livingroom(livingroom_root, 12)[::2]:
        K = f.K.copy()
        K[:2] /= 4
        K[:2, 2] = (f.K[:2, 2] - 1.5) / 4
        frames.append(
            Frame(f.stamp_ns, f.rgb[::4, ::4].copy(), f.depth_m[::4, ::4].copy(), K, f.cam_to_world)
        )
    rec = write_recording(tmp_path / "r.bag", frames, fmt="ros1")
    store, logged = tmp_path / "store", tmp_path / "logged"
    weights = save_tiny_clip(tmp_path / "weights", layers=2)
    model = ("--encoder", "clip", "--weights", weights, "--vocabulary", "chair,sofa,table")
    code, _, err = run_cli("ingest", rec, "--out", logged, "--rrd", tmp_path / "ref.rrd", *model)
    assert code == 0, err
    assert run_cli("ingest", rec, "--out", store, *model)[0] == 0
    code, _, err = run_cli("fuse", "grid", store)
    assert code == 0, err

    def snapshot() -> dict[str, str]:
        return {
            p.name: hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(store.iterdir())
            if p.is_file()
        }

    before = snapshot()
    rrd = tmp_path / "later.rrd"
    code, _, err = run_cli("ingest", rec, "--out", store, "--rrd", rrd, *model)
    assert code == 0, err
    assert snapshot() == before  # nothing ingested again, the grid kept
    got, ref = rrd_entity_counts(rrd), rrd_entity_counts(tmp_path / "ref.rrd")
    assert got == ref

    def poses(path: Path) -> np.ndarray:
        rows = []
        for chunk in RrdReader(path).stream():
            if chunk.entity_path != "/" + viz.CAMERA_ENTITY:
                continue
            batch = chunk.to_record_batch()
            for name in batch.schema.names:
                if name.endswith("Transform3D:translation"):
                    rows += [v for v in batch.column(name).to_pylist() if v is not None]
        return np.asarray(rows, dtype=np.float64).reshape(-1, 3)

    np.testing.assert_allclose(poses(rrd), poses(tmp_path / "ref.rrd"), atol=1e-6)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    # other options rebuild the store: the maps made from the old one are named first
    code, _, err = run_cli("ingest", rec, "--out", store, "--every", "2", *model)
    assert code == 0, err
    said = [line for line in err.splitlines() if "run `care fuse` again" in line]
    assert len(said) == 1, err
    assert said[0].startswith(f"{store}: rebuilt for another recording or other ingest options")
    for name in ("cells.parquet", "map.yaml", "map_frame.json"):
        assert name in said[0]
        assert not (store / name).exists()


def test_cloud_cadence_of_short_and_long_recordings() -> None:
    assert viz.cloud_every(None, viz.SHORT_RECORDING) == 1
    assert viz.cloud_every(None, viz.SHORT_RECORDING + 1) == viz.CLOUD_EVERY
    assert viz.cloud_every(None, None) == viz.CLOUD_EVERY  # length unknown: the long way
    assert viz.cloud_every(3, 5) == 3  # asked for
