"""Encoded images of recordings, decoded by other tools than ours (Pillow, imageio)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import rerun as rr
from PIL import Image

from care_maps.core.viz import APP_ID, depth_png, jpeg, open_scene_recording, overview_eye


def test_depth_png_is_millimetres_in_16_bits() -> None:
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.2, 9.0, (24, 32)).astype(np.float32)
    depth[0, :4] = [0.0, np.nan, np.inf, 70.0]  # invalid, invalid, invalid, beyond 16 bits
    decoded = np.asarray(Image.open(io.BytesIO(depth_png(depth))))
    assert decoded.dtype == np.uint16
    np.testing.assert_allclose(decoded[1:] / 1000.0, depth[1:], atol=0.0005 + 1e-6)
    assert decoded[0, :4].tolist() == [0, 0, 0, 65535]


def test_jpeg_decodes_close_to_the_image() -> None:
    y, x = np.mgrid[0:48, 0:64]
    rgb = np.stack([x * 4, y * 5, (x + y) * 2], axis=-1).astype(np.uint8)  # smooth: JPEG-friendly
    data = jpeg(rgb)
    assert data[:3] == b"\xff\xd8\xff"
    decoded = np.asarray(Image.open(io.BytesIO(data)).convert("RGB")).astype(int)
    assert np.abs(decoded - rgb).mean() < 2.0
    assert len(data) < rgb.nbytes / 3


def test_scene_recordings_share_app_and_recording_id(tmp_path) -> None:
    """Two stages of one scene open as one recording (they merge); another scene does not."""
    from rerun.chunk import RrdReader

    for name in ("s1.grid", "s1.eval", "s2.grid"):
        rec = open_scene_recording(tmp_path / f"{name}.rrd", name.split(".")[0])
        rec.flush()
        rec.disconnect()
    entries = {
        name: RrdReader(tmp_path / f"{name}.rrd").recordings()[0]
        for name in ("s1.grid", "s1.eval", "s2.grid")
    }
    assert {e.application_id for e in entries.values()} == {APP_ID}
    assert entries["s1.grid"].recording_id == entries["s1.eval"].recording_id
    assert entries["s1.grid"].recording_id != entries["s2.grid"].recording_id


def test_overview_eye_looks_at_the_middle_from_above() -> None:
    pts = np.array([[0.0, 0.0, 0.0], [10.0, 4.0, 2.5]] * 50)
    eye = overview_eye(pts)
    target = np.asarray(eye.look_target.as_arrow_array().to_pylist()[0])
    position = np.asarray(eye.position.as_arrow_array().to_pylist()[0])
    np.testing.assert_allclose(target, [5.0, 2.0, 1.25])
    assert position[2] > target[2] + 5.0  # above
    assert position[1] < target[1]  # south


def test_a_stage_recording_starts_on_no_other_stages_timelines(tmp_path: Path) -> None:
    """Every stage's file of a scene shares one recording id, and the SDK keeps a thread's
    times per id: the second file opened in a thread must not log on the first's times."""
    from rerun.chunk import RrdReader

    first = open_scene_recording(tmp_path / "a.rrd", "scene_000")
    first.set_time("instance", sequence=34)
    first.log("world/a", rr.Points3D([[0.0, 0.0, 0.0]]))
    second = open_scene_recording(tmp_path / "b.rrd", "scene_000")
    second.log("world/b", rr.Points3D([[1.0, 0.0, 0.0]]))
    first.flush()
    second.flush()
    names = {
        name
        for chunk in RrdReader(tmp_path / "b.rrd").stream()
        if chunk.entity_path == "/world/b"
        for name in chunk.to_record_batch().schema.names
    }
    assert "Points3D:positions" in names
    assert "instance" not in names
