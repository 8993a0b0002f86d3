"""Faults of the poses ``care ingest`` reads: ambiguous and impossible ones.

A view is one image and one pose. Two different transforms for one (parent, child, stamp),
or two different colour images at one stamp, leave the view undecidable; a camera a million
kilometres out or jumping 50 m in a tenth of a second is a corrupt transform. Each is one
line naming the topic or the view and its stamp, and no store; the same transform (or
image) repeated is accepted, and the limits are options that let the same recording in.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from care_maps.core.errors import IngestError
from care_maps.ingest.source import ReadOptions
from tests.support.faults import assert_fault, read_meta, snapshot
from tests.support.recordings import grey_bag

T0 = 10**9
DT = 100_000_000
CAM = "camera_optical_frame"
RGB = "/camera/color/image_raw"
IDENTITY = (0.0, 0.0, 0.0, 1.0)


def track(xs: list[float], parent: str = "map") -> tuple:
    """A dynamic ``parent`` -> camera transform on /tf at each default colour stamp (100 ms
    apart), the camera at x = ``xs[i]``."""
    return tuple((T0 + i * DT, parent, CAM, (x, 0.0, 1.0), IDENTITY) for i, x in enumerate(xs))


def ingest(care, bag: Path, out: Path, *flags: str) -> tuple[int, str, str]:
    return care("ingest", bag, "--out", out, *flags)


# -- several messages at one stamp ---------------------------------------------------------


@pytest.mark.slow
def test_twelve_colour_images_at_one_stamp_are_refused(care, tmp_path: Path) -> None:
    bag = grey_bag(tmp_path / "bag", stamps=[T0] * 12)
    code, _, err = ingest(care, bag, tmp_path / "store")
    assert_fault(
        code,
        err,
        rf"colour topic {RGB} has different images at one stamp, {T0} ns; .*re-stamp",
        clean=(tmp_path,),
    )
    assert not (tmp_path / "store").exists()


@pytest.mark.slow
def test_twelve_colour_images_with_twelve_poses_at_one_stamp(care, tmp_path: Path) -> None:
    """The images of frame 0 with the pose of frame 11 must never make a view."""
    poses = tuple((T0, "map", CAM, (0.1 * i, 0.0, 1.0), IDENTITY) for i in range(12))
    bag = grey_bag(tmp_path / "bag", stamps=[T0] * 12, tf_edges=(), dynamic=poses)
    code, _, err = ingest(care, bag, tmp_path / "store")
    assert_fault(
        code,
        err,
        rf"TF transform 'map' -> '{CAM}' at stamp {T0} ns on /tf: two different transforms",
        clean=(tmp_path,),
    )
    assert not (tmp_path / "store").exists()


@pytest.mark.slow
def test_the_same_colour_image_again_is_dropped_and_counted(care, tmp_path: Path) -> None:
    bag = grey_bag(tmp_path / "bag", stamps=[T0] * 12, shades=[7] * 12)
    code, out, err = ingest(care, bag, tmp_path / "store")
    assert code == 0, err
    assert "1 views from 12 colour images" in out
    assert read_meta(tmp_path / "store")["counts"]["dropped"] == {"duplicate_stamp": 11}


@pytest.mark.slow
@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        (
            {"tf_edges": (), "dynamic": (*track([0, 0.5, 1.0]), (T0 + DT, "map", CAM, (9.0, 0, 1), IDENTITY))},
            rf"TF transform 'map' -> '{CAM}' at stamp {T0 + DT} ns on /tf: two different "
            r"transforms at one stamp \(translation \[0\.5, 0\.0, 1\.0\].*then translation "
            r"\[9\.0, 0\.0, 1\.0\]",
        ),
        (
            {"tf_edges": (("map", "odom"), ("map", "odom")), "xyz": (0.0, 0.0, 1.0),
             "dynamic": track([0, 0.5, 1.0], parent="odom")},
            rf"TF transform 'map' -> 'odom' at stamp {T0} ns on /tf_static: two different "
            r"transforms at one stamp",
        ),
    ],
    ids=["tf", "tf_static"],
)  # fmt: skip
def test_two_transforms_at_one_stamp_are_refused(
    care, tmp_path: Path, kwargs: dict, pattern: str
) -> None:
    bag = grey_bag(tmp_path / "bag", **kwargs)
    code, _, err = ingest(care, bag, tmp_path / "store")
    assert_fault(code, err, pattern + r".*fix the recording's transforms", clean=(tmp_path,))
    assert not (tmp_path / "store").exists()


@pytest.mark.slow
def test_the_same_transform_again_is_accepted(care, tmp_path: Path) -> None:
    """/tf_static republished and a /tf message recorded twice: nothing new, no word."""
    poses = track([0, 0.5, 1.0], parent="odom")
    bag = grey_bag(
        tmp_path / "bag",
        tf_edges=(("map", "odom"), ("map", "odom")),
        xyz=(0.0, 0.0, 0.0),
        dynamic=(*poses, poses[1], poses[1]),
    )
    code, out, err = ingest(care, bag, tmp_path / "store")
    assert code == 0, err
    assert "error" not in err.lower()
    assert "warn" not in err.lower()
    assert "3 views from 3 colour images" in out

    from care_maps.core.store import Store

    positions = Store(tmp_path / "store").poses(in_map=False)[:, :3, 3].tolist()
    assert positions == [[0.0, 0.0, 1.0], [0.5, 0.0, 1.0], [1.0, 0.0, 1.0]]


# -- impossible poses ------------------------------------------------------------------------


@pytest.mark.slow
def test_a_camera_a_million_kilometres_out_is_refused(care, tmp_path: Path) -> None:
    bag = grey_bag(tmp_path / "bag", tf_edges=(), dynamic=track([0.0, 1e9, 0.2]))
    code, _, err = ingest(care, bag, tmp_path / "store")
    assert_fault(
        code,
        err,
        rf"view 1 at stamp {T0 + DT} ns: camera frame '{CAM}' in world frame 'map' lies 1e\+09 m "
        r"from the origin .* beyond --max-translation 10000 m; .*raise --max-translation",
        clean=(tmp_path,),
    )
    assert not (tmp_path / "store").exists()
    # the world may be that large: both limits raised, the same recording ingests
    code, out, err = ingest(
        care, bag, tmp_path / "store", "--max-translation", "2e9", "--max-speed", "2e10"
    )
    assert code == 0, err
    assert "3 views from 3 colour images" in out


@pytest.mark.slow
def test_a_jump_of_50_m_in_a_tenth_of_a_second_is_refused(care, tmp_path: Path) -> None:
    bag = grey_bag(tmp_path / "bag", n=4, tf_edges=(), dynamic=track([0.0, 1.0, 51.0, 52.0]))
    code, _, err = ingest(care, bag, tmp_path / "store")
    assert_fault(
        code,
        err,
        rf"view 2 at stamp {T0 + 2 * DT} ns: camera frame '{CAM}' in world frame 'map' moved "
        rf"50 m in 100 ms since the previous view \(stamp {T0 + DT} ns\): 500 m/s, faster than "
        r"--max-speed 50 m/s; .*raise --max-speed",
        clean=(tmp_path,),
    )
    assert not (tmp_path / "store").exists()
    code, out, err = ingest(care, bag, tmp_path / "store", "--max-speed", "600")
    assert code == 0, err
    assert "4 views from 4 colour images" in out


@pytest.mark.slow
def test_limits_are_not_part_of_the_store(care, tmp_path: Path) -> None:
    """Limits only refuse: a store they let through is current whatever their values (so
    stores made before they existed stay current), and its meta.json does not record them."""
    bag = grey_bag(tmp_path / "bag", tf_edges=(), dynamic=track([0.0, 1.0, 2.0]))
    store = tmp_path / "store"
    assert ingest(care, bag, store)[0] == 0
    before = snapshot(store)
    meta = read_meta(store)
    assert "max_speed" not in meta["config"]["read"]
    assert "max_translation" not in meta["config"]["read"]
    code, _, err = ingest(care, bag, store, "--max-speed", "20", "--max-translation", "5e3")
    assert code == 0, err
    assert snapshot(store) == before


# -- the options -----------------------------------------------------------------------------


@pytest.mark.slow
def test_limits_are_ingest_options(care) -> None:
    code, out, _ = care("ingest", "--help")
    assert code == 0
    assert "--max-translation" in out
    assert "--max-speed" in out


@pytest.mark.slow
@pytest.mark.parametrize(
    ("flags", "pattern"),
    [
        (("--max-speed", "0"), r"max_speed=0\.0 \(must be a finite number > 0\)"),
        (("--max-translation", "-5"), r"max_translation=-5\.0 \(must be a finite number > 0\)"),
    ],
    ids=["speed-zero", "translation-negative"],
)
def test_limits_must_be_positive(care, tmp_path: Path, flags: tuple, pattern: str) -> None:
    bag = grey_bag(tmp_path / "bag")
    code, _, err = ingest(care, bag, tmp_path / "store", *flags)
    assert_fault(code, err, pattern, clean=(tmp_path,))
    assert not (tmp_path / "store").exists()


@pytest.mark.parametrize("value", [math.nan, math.inf, 0.0, -1.0])
def test_limits_are_checked_in_the_library(value: float) -> None:
    with pytest.raises(IngestError, match="must be a finite number > 0"):
        ReadOptions(max_speed=value)
    with pytest.raises(IngestError, match="must be a finite number > 0"):
        ReadOptions(max_translation=value)
