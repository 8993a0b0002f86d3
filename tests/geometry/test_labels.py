"""Labels that do not pile up: the greedy choice against a brute-force check of its two
promises on random scenes, and a hand-worked crowd (eight boxes of one wall and a chair)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from care_maps.geometry.labels import LABEL_GAP, LABELS_ACROSS, label_gap, spread_labels


def test_a_crowd_keeps_the_largest_label_of_each_place() -> None:
    wall = np.array([[0.0, 0.1 * i, 1.0] for i in range(8)])  # eight segments within 0.7 m
    chair = np.array([[3.0, 0.0, 0.5]])
    sizes = np.array([10, 50, 20, 5, 40, 30, 15, 25, 7])
    shown = spread_labels(np.vstack([wall, chair]), sizes, gap=0.5)
    # segment 1 (50 points) hides 0..6 (within 0.5 m of y = 0.1), segment 7 at y = 0.7 is
    # 0.6 m away and stays; the chair is alone
    assert np.flatnonzero(shown).tolist() == [1, 7, 8]


@pytest.mark.parametrize("seed", range(5))
def test_drawn_labels_are_apart_and_every_hidden_one_has_a_drawn_neighbour(seed: int) -> None:
    rng = np.random.default_rng(seed)
    anchors = rng.uniform(0, 4, (60, 3))
    priority = rng.integers(0, 5, 60)  # ties broken by index
    gap = 0.6
    shown = spread_labels(anchors, priority, gap)
    flat = anchors[:, :2]  # distances on the floor plane
    d = np.linalg.norm(flat[:, None] - flat[None], axis=-1)
    for i, j in itertools.combinations(np.flatnonzero(shown), 2):
        assert d[i, j] > gap
    for i in np.flatnonzero(~shown):
        above = [
            j for j in np.flatnonzero(shown)
            if d[i, j] <= gap and (priority[j], -j) > (priority[i], -i)
        ]  # fmt: skip
        assert above, i


def test_the_gap_grows_with_the_scene() -> None:
    room = np.array([[0.0, 0.0, 1.0], [4.0, 3.0, 0.5]])
    house = np.array([[0.0, 0.0, 1.0], [24.0, 6.0, 0.5]])
    assert label_gap(room) == LABEL_GAP  # 4 m / 12 is below the least gap
    assert label_gap(house) == pytest.approx(24.0 / LABELS_ACROSS)
    assert label_gap(room[:1]) == LABEL_GAP


def test_labels_stacked_in_height_count_as_one_place() -> None:
    shelf = np.array([[1.0, 1.0, 0.3], [1.0, 1.0, 1.2], [1.0, 1.0, 1.9]])
    assert spread_labels(shelf, np.array([1, 3, 2]), gap=0.5).tolist() == [False, True, False]
