"""View selection on a hand-worked occlusion case.

A 10 x 10 pixel camera with f = 10, principal point (5, 5). A wall of depth 4 m fills the
image; a board at depth 2 m covers the left half (u < 5). The mask is a 10 x 10 grid of
points on the wall plane z = 4, one per pixel (pixel u, v -> x = (u - 5) * 0.4,
y = (v - 5) * 0.4). So, by hand:

- view 0 (this camera): the board hides columns u = 0..4 -> 50 of 100 points visible;
- view 1 (same pose, no board): all 100 visible;
- view 2 (turned round, looking away): 0 visible (behind the camera);
- view 3 (moved 1 m back, no board): the points land on the central 8 x 8 pixels... but
  the depth image there is the wall at 5 m, so all 100 are visible, 2 or more per pixel.
Ranked: 1 and 3 (100 each, lower id first), then 0 (50); view 2 is not a view.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from care_maps.core.frames import Frame
from care_maps.core.store import EncoderInfo, Store, StoreWriter
from care_maps.fuse.views import select_views, visible_hits
from care_maps.runtime.execution import Execution

QUIET = Execution(progress=False)

K = np.array([[10.0, 0, 5], [0, 10.0, 5], [0, 0, 1]])
u, v = np.meshgrid(np.arange(10), np.arange(10))
WALL = np.stack([(u - 5) * 0.4, (v - 5) * 0.4, np.full(u.shape, 4.0)], -1).reshape(-1, 3)


def _depth(board: bool, wall: float = 4.0) -> np.ndarray:
    d = np.full((10, 10), wall, np.float32)
    if board:
        d[:, :5] = 2.0
    return d


def _poses() -> list[np.ndarray]:
    turned = np.diag([-1.0, 1.0, -1.0, 1.0])  # 180 degrees about y: looks along -z
    back = np.eye(4)
    back[2, 3] = -1.0
    return [np.eye(4), np.eye(4), turned, back]


def _depths() -> list[np.ndarray]:
    return [_depth(True), _depth(False), _depth(False), _depth(False, 5.0)]


def test_visible_hits_hand_worked() -> None:
    hits = visible_hits(
        WALL, np.stack(_depths()), np.stack([K] * 4), np.stack(_poses()), depth_tolerance=0.05
    )
    counts = np.bincount(hits.view, minlength=4)
    assert counts.tolist() == [50, 100, 0, 100]
    in_view0 = hits.point[hits.view == 0]
    assert set(in_view0.tolist()) == set(np.nonzero(u.ravel() >= 5)[0].tolist())
    # a point lands on the pixel it came from in the unmoved view
    one = hits.view == 1
    np.testing.assert_array_equal(hits.u[one], u.ravel()[hits.point[one]])
    np.testing.assert_array_equal(hits.v[one], v.ravel()[hits.point[one]])


def test_tolerance_decides_occlusion() -> None:
    depth = _depth(False, 4.2)[None]
    few = visible_hits(WALL, depth, K[None], np.eye(4)[None], depth_tolerance=0.1)
    many = visible_hits(WALL, depth, K[None], np.eye(4)[None], depth_tolerance=0.3)
    assert len(few.point) == 0
    assert len(many.point) == 100


@pytest.fixture
def store(tmp_path: Path) -> Path:
    # features: the left half of each map (fw = 2) is e0, the right half e1, per view scaled
    feats = np.zeros((2, 2, 4), np.float32)
    feats[:, 0, 0] = 1.0
    feats[:, 1, 1] = 1.0
    with StoreWriter(tmp_path / "s", EncoderInfo("t", "1", 4)) as writer:
        for i, (pose, depth) in enumerate(zip(_poses(), _depths(), strict=True)):
            rgb = np.full((10, 10, 3), 10 * i, np.uint8)
            writer.add(Frame(i, rgb, depth, K, pose), feats)
        writer.commit({})
    return tmp_path / "s"


def test_select_views_ranks_and_pools(store: Path) -> None:
    wall_mask = np.arange(100)
    left = np.nonzero(u.ravel() < 5)[0]  # only visible where the board is absent
    sel = select_views(
        Store(store),
        WALL,
        [wall_mask, left],
        top_k=3,
        depth_tolerance=0.05,
        min_visible_points=5,
        run=QUIET,
    )
    assert sel.view_ids.tolist() == [[1, 3, 0], [1, 3, -1]]
    assert sel.visible.tolist() == [[100, 100, 50], [50, 50, 0]]
    assert sel.num_views.tolist() == [3, 2]
    assert sel.bboxes[0, 0].tolist() == [0, 0, 10, 10]
    assert sel.bboxes[0, 2].tolist() == [5, 0, 10, 10]  # only the right half seen
    assert sel.bboxes[0, 1].tolist() == [1, 1, 9, 9]  # moved back: central 8 x 8 pixels
    # pooled features: view 1 sees 50 points on each half -> (e0 + e1) / sqrt 2;
    # view 0 sees only the right half -> e1; the left mask in view 1 -> e0
    np.testing.assert_allclose(sel.features[0, 0], [2**-0.5, 2**-0.5, 0, 0], atol=1e-6)
    np.testing.assert_allclose(sel.features[0, 2], [0, 1, 0, 0], atol=1e-6)
    np.testing.assert_allclose(sel.features[1, 0], [1, 0, 0, 0], atol=1e-6)
    np.testing.assert_array_equal(sel.features[1, 2], 0)


def test_min_visible_points_and_more_slots_than_views(store: Path) -> None:
    sel = select_views(
        Store(store),
        WALL,
        [np.arange(100)],
        top_k=6,
        depth_tolerance=0.05,
        min_visible_points=60,
        run=QUIET,
    )
    assert sel.view_ids.tolist() == [[1, 3, -1, -1, -1, -1]]


def test_batches_do_not_change_the_result(store: Path) -> None:
    args = {"top_k": 3, "depth_tolerance": 0.05, "min_visible_points": 5}
    one = Execution(batch_size=1, progress=False)
    a = select_views(Store(store), WALL, [np.arange(100)], run=one, **args)
    b = select_views(Store(store), WALL, [np.arange(100)], run=QUIET, **args)
    np.testing.assert_array_equal(a.view_ids, b.view_ids)
    np.testing.assert_allclose(a.features, b.features)
