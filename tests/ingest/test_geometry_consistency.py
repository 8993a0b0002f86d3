"""The geometric consistency check's arithmetic: a hand-worked pair (a wall seen from two
positions), and the third-party living-room and slambook frames as given and with each usual
mistake made on purpose, each found and named by the mistake that undoes it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from care_maps.geometry.consistency import (
    DepthSample,
    Hypothesis,
    Mistake,
    Status,
    agreement,
    depth_scales,
    judge,
    pair_agreement,
    pick_pairs,
    reorder_quaternion,
    subsample,
)
from care_maps.geometry.transforms import BODY_FROM_OPTICAL
from tests.support.frames import load_livingroom, load_slambook

K = np.array([[50.0, 0.0, 39.5], [0.0, 50.0, 29.5], [0.0, 0.0, 1.0]])
"""An 80x60 camera (no subsampling needed)."""


def _wall(distance: float, width: int = 80, height: int = 60) -> np.ndarray:
    return np.full((height, width), distance, np.float32)


def test_a_wall_seen_from_two_positions_agrees_where_the_views_overlap() -> None:
    # a fronto-parallel wall 2 m ahead; the second camera 0.4 m to the right: a wall pixel u
    # of the first lands at u - fx * 0.4 / 2 = u - 10 in the second, so the 10 leftmost
    # columns fall outside, and every landed depth is 2 m as the second view says
    first = DepthSample(_wall(2.0), K, np.eye(4))
    moved = np.eye(4)
    moved[0, 3] = 0.4
    second = DepthSample(_wall(2.0), K, moved)
    got = pair_agreement(first, second, first.pose, second.pose)
    assert got.points == 80 * 60
    assert got.overlap == pytest.approx(70 / 80)
    assert got.agree == 1.0
    np.testing.assert_allclose(got.residuals, 0.0, atol=1e-12)
    # the same pair with the second pose inverted: the second camera believed 0.4 m left,
    # so the pixels land 10 columns the other way; still the same depth (a wall ahead of a
    # camera that slid along it), the overlap shows the shift
    wrong = pair_agreement(first, second, first.pose, np.linalg.inv(moved))
    assert wrong.overlap == pytest.approx(70 / 80)
    # depth read twice as large: back-projected to 4 m, landed at 4 m against the second
    # view's 4 m: a pure slide along a wall cannot tell depth units (why pairs must turn
    # or move towards the surfaces too: see the real frames below)
    scaled = pair_agreement(first, second, first.pose, second.pose, depth_scale=2.0)
    assert scaled.agree == 1.0


def test_a_wall_approached_disagrees_in_proportion_to_the_depth_error() -> None:
    # the second camera 0.5 m closer: the wall is 1.5 m from it. With depth read 10 % too
    # large (2.2 m and 1.65 m), the first view's points land at 2.2 - 0.5 = 1.7 m, against
    # 1.65 m: a relative residual of 0.05 / 1.65
    first = DepthSample(_wall(2.0), K, np.eye(4))
    closer = np.eye(4)
    closer[2, 3] = 0.5
    second = DepthSample(_wall(1.5), K, closer)
    right = pair_agreement(first, second, first.pose, second.pose)
    assert right.agree == 1.0
    off = pair_agreement(first, second, first.pose, second.pose, depth_scale=1.1)
    np.testing.assert_allclose(off.residuals, 0.05 / 1.65, rtol=1e-9)


def test_subsampling_keeps_the_pixels_rays() -> None:
    depth = np.random.default_rng(0).uniform(1, 3, (480, 640)).astype(np.float32)
    full = np.array([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
    sample = subsample(depth, full, np.eye(4))
    assert sample.depth.shape == (60, 80)
    # grid pixel (u, v) is image pixel (8u, 8v): its ray through K_small equals the image's
    u, v = 13, 41
    ray_small = np.linalg.solve(sample.K, [u, v, 1.0])
    ray_full = np.linalg.solve(full, [8 * u, 8 * v, 1.0])
    np.testing.assert_allclose(ray_small, ray_full)
    assert sample.depth[v, u] == depth[8 * v, 8 * u]


def test_the_reordered_quaternion_reads_the_numbers_the_other_way() -> None:
    q = Rotation.random(random_state=3).as_quat()  # x y z w
    written = np.array([q[3], *q[:3]])  # w x y z in the file
    read_as = np.eye(4)
    read_as[:3, :3] = Rotation.from_quat(written).as_matrix()  # read as x y z w
    np.testing.assert_allclose(
        reorder_quaternion(read_as)[:3, :3], Rotation.from_quat(q).as_matrix(), atol=1e-12
    )


def test_depth_scale_candidates_are_the_datasets_ratios_and_powers_of_ten() -> None:
    scales = depth_scales()
    for s in (0.001, 1000.0, 5.0, 0.2, 6.5535, 4.0, 0.25):
        assert any(abs(s - x) < 1e-6 for x in scales)
    assert 1.0 not in scales


def _load(root: Path, every: int) -> list[DepthSample]:
    frames = load_livingroom(root, 211)[::every]
    return [subsample(f.depth_m, f.K, f.cam_to_world, f.stamp_ns) for f in frames]


def _focal(sample: DepthSample, f: float) -> DepthSample:
    K2 = sample.K.copy()
    K2[0, 0] *= f
    K2[1, 1] *= f
    return replace(sample, K=K2)


def _written_wxyz(pose: np.ndarray) -> np.ndarray:
    """A pose whose quaternion was written w x y z and read x y z w."""
    x, y, z, w = Rotation.from_matrix(pose[:3, :3]).as_quat()
    out = pose.copy()
    out[:3, :3] = Rotation.from_quat([w, x, y, z]).as_matrix()
    return out


MISTAKES = {
    # what was done to the right data -> the mistake that undoes it
    "poses world-to-camera": (lambda s: replace(s, pose=np.linalg.inv(s.pose)), Mistake.POSES_INVERTED),
    "quaternion w x y z": (lambda s: replace(s, pose=_written_wxyz(s.pose)), Mistake.QUATERNION_ORDER),
    "body axes read as optical": (
        lambda s: replace(s, pose=s.pose @ np.linalg.inv(BODY_FROM_OPTICAL)),
        Mistake.BODY_AXES,
    ),
    "depth x1000": (lambda s: replace(s, depth=s.depth * 1000), Mistake.DEPTH_SCALE),
    "depth x0.001": (lambda s: replace(s, depth=s.depth / 1000), Mistake.DEPTH_SCALE),
    "depth x5 (TUM read as mm)": (lambda s: replace(s, depth=s.depth * 5), Mistake.DEPTH_SCALE),
    "focal x2": (lambda s: _focal(s, 2.0), Mistake.FOCAL_LENGTH),
    "focal x0.6": (lambda s: _focal(s, 0.6), Mistake.FOCAL_LENGTH),
}  # fmt: skip
ALL = list(Mistake)


@pytest.fixture(scope="module")
def every5(livingroom_root) -> list[DepthSample]:
    return _load(livingroom_root, 5)


@pytest.fixture(scope="module")
def slambook(slambook_root) -> list[DepthSample]:
    return [subsample(f.depth_m, f.K, f.cam_to_world) for f in load_slambook(slambook_root)]


def test_right_recordings_agree(every5, slambook, livingroom_root) -> None:
    for samples in (every5, _load(livingroom_root, 1)[:60], slambook):
        verdict = judge(samples, ALL)
        assert verdict.status is Status.AGREE, verdict.as_json()


@pytest.mark.parametrize("done", list(MISTAKES))
def test_each_usual_mistake_is_found_and_undone(every5, slambook, done: str) -> None:
    make, mistake = MISTAKES[done]
    for samples in (every5, slambook):
        verdict = judge([make(s) for s in samples], ALL)
        assert verdict.status is Status.MISTAKE, (done, verdict.as_json())
        assert verdict.mistake is mistake
        assert verdict.better is not None
        assert verdict.better.agree >= 0.85


def test_the_fix_names_the_factor_that_was_made(every5) -> None:
    depth = judge([replace(s, depth=s.depth * 5) for s in every5], ALL)
    assert depth.hypothesis is not None
    assert depth.hypothesis.depth_scale == pytest.approx(0.2)
    focal = judge([_focal(s, 0.6) for s in every5], ALL)
    assert focal.hypothesis is not None
    assert focal.hypothesis.focal_scale == pytest.approx(1 / 0.6, rel=0.03)


def test_a_camera_that_stands_still_is_not_judged(every5) -> None:
    still = [replace(s, pose=every5[0].pose) for s in every5[:10]]
    assert pick_pairs(still, 48) == []
    verdict = judge(still, ALL)
    assert verdict.status is Status.UNJUDGED
    assert verdict.passed


def test_implausible_depth_is_a_depth_scale_mistake_even_without_motion(every5) -> None:
    still = [replace(s, pose=every5[0].pose, depth=s.depth * 1000) for s in every5[:10]]
    verdict = judge(still, ALL)
    assert not verdict.passed
    assert verdict.mistake in (None, Mistake.DEPTH_SCALE)


def test_views_that_agree_with_no_reading_disagree(every5) -> None:
    rng = np.random.default_rng(1)
    shuffled = [
        replace(s, pose=every5[int(k)].pose)
        for s, k in zip(every5, rng.permutation(len(every5)), strict=True)
    ]
    verdict = judge(shuffled, ALL)
    assert verdict.status is Status.DISAGREE, verdict.as_json()


def test_pairs_stay_inside_runs(every5) -> None:
    pairs = pick_pairs(every5[:12], 48, runs=[6, 6])
    assert pairs
    assert all((i < 6) == (j < 6) for i, j in pairs)


def test_agreement_is_symmetric_in_the_pair_order(every5) -> None:
    a = agreement(every5, [(0, 3)], Hypothesis("as given"))
    b = agreement(every5, [(3, 0)], Hypothesis("as given"))
    assert a == b


def test_the_floor_holds_the_cameras_only_in_the_right_units(every5) -> None:
    from care_maps.geometry.consistency import floor_support

    right = floor_support(every5)
    assert right["found"]
    assert right["plausible"]
    # the floor measured directly: a least-squares plane (SVD) through the lowest 5 % of the
    # world points along the cameras' mean up, and the cameras' distances to it
    points = []
    for s in every5:
        v, u = np.nonzero(s.depth > 0)
        z = s.depth[v, u].astype(np.float64)
        cam = np.stack([(u - s.K[0, 2]) * z / s.K[0, 0], (v - s.K[1, 2]) * z / s.K[1, 1], z], 1)
        points.append(cam @ s.pose[:3, :3].T + s.pose[:3, 3])
    cloud = np.concatenate(points)
    up = -np.mean([s.pose[:3, 1] for s in every5], axis=0)
    low = cloud[cloud @ up <= np.percentile(cloud @ up, 5)]
    centre = low.mean(axis=0)
    normal = np.linalg.svd(low - centre)[2][-1]
    normal *= np.sign(normal @ up)
    heights = np.array([(s.pose[:3, 3] - centre) @ normal for s in every5])
    assert right["camera_height_m"] == pytest.approx(np.median(heights), abs=0.1)
    wrong = floor_support([replace(s, depth=s.depth * 1000) for s in every5])
    assert not (wrong["found"] and wrong["plausible"])
