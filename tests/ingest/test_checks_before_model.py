"""What can be checked without the model is checked before it loads: a recording without a
pose source is refused for that, not for the weights the model would have failed on."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.support.frames import smooth_rgb
from tests.support.messages import image_msg
from tests.support.recordings import rgbd_messages, write_bag


def test_a_recording_fault_is_named_before_the_model_loads(run_cli, tmp_path: Path) -> None:
    msgs = rgbd_messages(
        lambda i, t: image_msg(t, smooth_rgb(i), "rgb8"),
        lambda i, t: image_msg(t, np.full((24, 32), 2000, np.uint16), "16UC1"),
        tf=False,
    )
    bag = write_bag(tmp_path / "no_pose", msgs)
    empty = tmp_path / "weights"
    empty.mkdir()  # no model in it: loading would fail
    code, _, err = run_cli(
        "ingest", bag, "--out", tmp_path / "store", "--encoder", "clip", "--weights", empty
    )
    assert code == 1
    assert "no pose source" in err
    assert "--static-pose" in err
    assert not (tmp_path / "store").exists()
