"""``care run`` takes every ``care ingest`` option (made from the same configs): the option
its own error names works there too, on a user's recording without any pose."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from care_maps.core.store import Store
from tests.support.frames import load_livingroom
from tests.support.messages import camera_info_msg, image_msg
from tests.support.recordings import write_bag

pytestmark = pytest.mark.slow


def test_run_takes_the_option_its_error_names(
    run_cli, tmp_path: Path, livingroom_root: Path, save_tiny_clip
) -> None:
    # third-party frames at a quarter of their size, no TF and no pose topic
    msgs = []
    for f in load_livingroom(livingroom_root, 9)[::3]:
        t, K = f.stamp_ns, f.K.copy()
        K[:2] /= 4
        K[:2, 2] = (f.K[:2, 2] - 1.5) / 4
        rgb, depth = f.rgb[::4, ::4].copy(), f.depth_m[::4, ::4]
        msgs += [
            ("/camera/color/camera_info", t, camera_info_msg(t, K, 160, 120)),
            ("/camera/color/image_raw", t, image_msg(t, rgb, "rgb8")),
            ("/camera/depth/image_raw", t,
             image_msg(t, np.round(depth * 1000).astype(np.uint16), "16UC1")),
        ]  # fmt: skip
    bag = write_bag(tmp_path / "no_pose", msgs)
    weights = save_tiny_clip(tmp_path / "weights", layers=2)
    args = ("run", bag, "--out", tmp_path / "out", "--encoder", "clip", "--weights", weights,
            "--vocabulary", "chair,sofa,table")  # fmt: skip
    code, _, err = run_cli(*args)
    assert code == 1
    assert "--static-pose" in err
    code, out, err = run_cli(*args, "--static-pose", "--every", "2")
    assert code == 0, err
    store = Store(tmp_path / "out" / "stores" / "no_pose")
    assert store.num_views == 2  # --every 2 of 3 frames
    # what each stage found, as care ingest and care fuse print it
    where = tmp_path / "out" / "stores" / "no_pose"
    assert f"{where}: 2 views from 3 colour images, skipped {{'every': 1}}" in out
    assert f"{where}: map frame" in out
    assert f"{where / 'cells.parquet'}: " in out
    assert f"{where / 'map.yaml'}: in frame " in out
    identity = np.broadcast_to(np.eye(4), (2, 4, 4))
    np.testing.assert_allclose(store.poses(in_map=False), identity)  # as recorded
