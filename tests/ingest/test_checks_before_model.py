"""What can be checked without the model is checked before it loads: a recording without a
pose source is refused for that, not for the weights the model would have failed on."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def test_a_recording_fault_is_named_before_the_model_loads(run_cli, tmp_path: Path, h) -> None:
    msgs = h.rgbd_messages(
        lambda i, t: h.image_msg(t, h.smooth_rgb(i), "rgb8"),
        lambda i, t: h.image_msg(t, np.full((24, 32), 2000, np.uint16), "16UC1"),
        tf=False,
    )
    bag = h.write_bag(tmp_path / "no_pose", msgs)
    empty = tmp_path / "weights"
    empty.mkdir()  # no model in it: loading would fail
    code, _, err = run_cli(
        "ingest", bag, "--out", tmp_path / "store", "--encoder", "clip", "--weights", empty
    )
    assert code == 1
    assert "no pose source" in err
    assert "--static-pose" in err
    assert not (tmp_path / "store").exists()
