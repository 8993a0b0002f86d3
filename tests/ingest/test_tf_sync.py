"""TF interpolation against scipy, chains of transforms, and stamp matching."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from care_maps.core.errors import IngestError
from care_maps.ingest.decode import StampedTransform
from care_maps.ingest.sync import StampSync
from care_maps.ingest.tf import TFBuffer


def _T(rot: Rotation, t: np.ndarray) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = rot.as_matrix()
    M[:3, 3] = t
    return M


def test_interpolation_matches_scipy_slerp() -> None:
    rng = np.random.default_rng(3)
    stamps = np.array([0, 100, 250, 400]) * 1_000_000
    rots = Rotation.random(4, random_state=4)
    trans = rng.normal(size=(4, 3))
    buf = TFBuffer()
    for s, r, t in zip(stamps, rots, trans, strict=True):
        buf.add(StampedTransform("map", "cam", int(s), t, r.as_quat()), static=False)
    query = np.sort(rng.uniform(0, 400e6, 50)).astype(np.int64)
    got, valid = buf.lookup("map", "cam", query)
    assert valid.all()
    expected_rot = Slerp(stamps, rots)(query).as_matrix()
    expected_t = np.stack([np.interp(query, stamps, trans[:, k]) for k in range(3)], axis=1)
    np.testing.assert_allclose(got[:, :3, :3], expected_rot, atol=1e-9)
    np.testing.assert_allclose(got[:, :3, 3], expected_t, atol=1e-9)


def test_chain_of_static_and_dynamic_transforms() -> None:
    rng = np.random.default_rng(5)
    buf = TFBuffer()
    r_base = Rotation.random(2, random_state=1)
    t_base = rng.normal(size=(2, 3))
    for k in range(2):
        buf.add(
            StampedTransform("odom", "base", k * 10**9, t_base[k], r_base[k].as_quat()),
            static=False,
        )
    r_odom, t_odom = Rotation.random(random_state=2), rng.normal(size=3)
    buf.add(StampedTransform("map", "odom", 0, t_odom, r_odom.as_quat()), static=True)
    r_cam, t_cam = Rotation.random(random_state=3), rng.normal(size=3)
    buf.add(StampedTransform("base", "cam", 0, t_cam, r_cam.as_quat()), static=True)
    buf.add(StampedTransform("base", "lidar", 0, np.ones(3), np.array([0, 0, 0, 1.0])), static=True)
    got, valid = buf.lookup("map", "cam", np.array([10**9]))
    expected = _T(r_odom, t_odom) @ _T(r_base[1], t_base[1]) @ _T(r_cam, t_cam)
    assert valid.all()
    np.testing.assert_allclose(got[0], expected, atol=1e-9)
    # Between two sibling frames: lidar_from_cam = inv(base_from_lidar) @ base_from_cam.
    got, _ = buf.lookup("lidar", "cam", np.array([0]))
    lidar = _T(Rotation.identity(), np.ones(3))
    np.testing.assert_allclose(got[0], np.linalg.inv(lidar) @ _T(r_cam, t_cam), atol=1e-9)


def test_no_extrapolation_beyond_tolerance() -> None:
    buf = TFBuffer()
    for k in range(3):
        buf.add(
            StampedTransform("map", "cam", k * 10**8, np.zeros(3), np.array([0, 0, 0, 1.0])),
            static=False,
        )
    _, valid = buf.lookup(
        "map", "cam", np.array([-5 * 10**6, -5 * 10**7, 2 * 10**8 + 10**7]), 10**7
    )
    np.testing.assert_array_equal(valid, [True, False, True])


def test_unconnected_frames_are_named() -> None:
    buf = TFBuffer()
    buf.add(
        StampedTransform("map", "base_link", 0, np.zeros(3), np.array([0, 0, 0, 1.0])), static=True
    )
    buf.add(
        StampedTransform("odom", "camera", 0, np.zeros(3), np.array([0, 0, 0, 1.0])), static=True
    )
    with pytest.raises(
        IngestError,
        match=r"camera frame 'camera' to world frame 'map': they are in separate TF trees",
    ):
        buf.lookup("map", "camera", np.array([0]))
    with pytest.raises(
        IngestError,
        match=r"camera frame 'nowhere' is not in TF \(frames present: base_link, camera, map, odom\)",
    ):
        buf.lookup("map", "nowhere", np.array([0]))


def test_sync_matches_nearest_and_counts_drops() -> None:
    sync = StampSync({"depth": True, "class": False}, max_dt_ns=20)
    out = []
    # colour every 100 ns; depth 5 ns late except frame 3 (missing); class only for frame 1
    for k in range(6):
        t = 100 * k
        out += sync.push(None, t, f"rgb{k}")
        if k != 3:
            out += sync.push("depth", t + 5, f"d{k}")
        if k == 1:
            out += sync.push("class", t, "c1")
    out += sync.finish()
    assert [m.primary for m in out] == ["rgb0", "rgb1", "rgb2", "rgb4", "rgb5"]
    assert [m.secondary["depth"] for m in out] == ["d0", "d1", "d2", "d4", "d5"]
    assert [m.secondary["class"] for m in out] == [None, "c1", None, None, None]
    assert sync.dropped == {"no_depth": 1}


def test_sync_memory_is_bounded() -> None:
    sync = StampSync({"depth": True}, max_dt_ns=20_000_000)
    held = []
    for k in range(2000):
        t = k * 33_000_000
        sync.push(None, t, k)
        sync.push("depth", t + 1_000_000, k)
        held.append(sync.buffered())
    assert max(held) <= 4
