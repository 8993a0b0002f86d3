"""The explore experiment's tables: each row's scene-level figures against a brute-force
reference (every sign pattern enumerated by hand, a search of the interval's ends), its Holm
p-values against statsmodels, and its reading from those."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from statsmodels.stats.multitest import multipletests

from care_maps.research.explore import PAIRS, Condition, comparison_lines, comparison_rows

MARGIN = 0.03
"""The equivalence margin the experiment is read at (3 points), written here, not imported."""


def _queries(scenes: int, seed: int) -> tuple[dict[Condition, np.ndarray], np.ndarray]:
    """Per-query success of the four conditions over ``scenes`` scenes of 3 to 9 queries each."""
    rng = np.random.default_rng(seed)
    sizes = rng.integers(3, 10, scenes)
    scene = np.repeat([f"scene_{g:03d}" for g in range(scenes)], sizes)
    rate = {Condition.BEFORE: 0.5, Condition.EXPLORE: 0.7, Condition.RANDOM: 0.55}
    rate[Condition.TOP_CONFIDENCE] = 0.6
    return {c: (rng.random(len(scene)) < r).astype(float) for c, r in rate.items()}, scene


def _sums(a: np.ndarray, b: np.ndarray, scene: np.ndarray) -> tuple[list[float], list[int]]:
    names = sorted(set(scene.tolist()))
    sums = [float(np.sum(a[scene == s] - b[scene == s])) for s in names]
    return sums, [int(np.sum(scene == s)) for s in names]


def _brute_p(sums: list[float], counts: list[int], d: float, side: int = 0) -> float:
    """Share of the 2^G sign patterns whose statistic reaches the observed one, testing
    ``delta = d``: two-sided (``side`` 0), against larger (+1) or smaller (-1)."""
    z = [s - d * n for s, n in zip(sums, counts, strict=True)]
    observed = sum(z)
    hits = 0
    patterns = list(itertools.product((1, -1), repeat=len(z)))
    for signs in patterns:
        t = sum(s * v for s, v in zip(signs, z, strict=True))
        if side == 0:
            hits += abs(t) >= abs(observed) - 1e-9
        elif side > 0:
            hits += t >= observed - 1e-9
        else:
            hits += t <= observed + 1e-9
    return hits / len(patterns)


def test_each_row_matches_every_sign_pattern_and_statsmodels_holm() -> None:
    outcomes, scene = _queries(8, seed=5)
    rows = comparison_rows(outcomes, scene, seed=3)
    assert [r["comparison"] for r in rows] == [f"{a} vs {b}" for a, b in PAIRS]
    scene_p, equivalence_p = [], []
    for row, (a, b) in zip(rows, PAIRS, strict=True):
        sums, counts = _sums(outcomes[a], outcomes[b], scene)
        assert row["rate_a"] == pytest.approx(100 * outcomes[a].mean())
        assert row["rate_b"] == pytest.approx(100 * outcomes[b].mean())
        assert row["diff"] == pytest.approx(100 * sum(sums) / sum(counts))
        assert row["scene_p"] == pytest.approx(_brute_p(sums, counts, 0.0))
        tost = max(_brute_p(sums, counts, -MARGIN, +1), _brute_p(sums, counts, MARGIN, -1))
        assert row["equivalence_p"] == pytest.approx(tost)
        # the interval: the d kept (p > 0.05) just inside each end, refused just outside
        lo, hi = row["lo"] / 100, row["hi"] / 100
        assert lo <= row["diff"] / 100 <= hi
        for inside, outside in ((lo + 1e-7, lo - 1e-7), (hi - 1e-7, hi + 1e-7)):
            assert _brute_p(sums, counts, inside) > 0.05
            if -1 < outside < 1:
                assert _brute_p(sums, counts, outside) <= 0.05
        scene_p.append(row["scene_p"])
        equivalence_p.append(row["equivalence_p"])
    holm_p = multipletests(scene_p, method="holm")[1]
    holm_equivalence = multipletests(equivalence_p, method="holm")[1]
    for row, p, q in zip(rows, holm_p, holm_equivalence, strict=True):
        assert row["holm_p"] == pytest.approx(p)
        assert row["holm_equivalence_p"] == pytest.approx(q)
        assert row["family_can_reject"]  # 2/256 <= 0.05/5
        if p <= 0.05:
            assert row["reading"] == ("better" if row["diff"] > 0 else "worse")
        elif q <= 0.05:
            assert row["reading"] == "within ±3 points"
        else:
            assert row["reading"] == "not shown to differ"


def test_a_difference_an_equivalence_and_neither_read_as_such() -> None:
    """Eight scenes of four queries: explore solves all, before none (every scene one way:
    p = 2/256); random equals before query for query (each one-sided test reached by the
    all-plus pattern alone: 1/256); top_confidence solves one query of one scene."""
    scene = np.repeat(np.arange(8), 4)
    before = np.zeros(32)
    top = before.copy()
    top[0] = 1.0
    outcomes = {
        Condition.BEFORE: before,
        Condition.EXPLORE: np.ones(32),
        Condition.RANDOM: before.copy(),
        Condition.TOP_CONFIDENCE: top,
    }
    pairs = ((Condition.EXPLORE, Condition.BEFORE), (Condition.RANDOM, Condition.BEFORE))
    pairs += ((Condition.TOP_CONFIDENCE, Condition.BEFORE),)
    rows = comparison_rows(outcomes, scene, seed=0, pairs=pairs)
    assert [r["scene_p"] for r in rows] == pytest.approx([2 / 256, 1.0, 1.0])
    assert rows[1]["equivalence_p"] == pytest.approx(1 / 256)
    # top_confidence +3.1 points: at the margin's far side, not shown equivalent
    assert rows[2]["diff"] == pytest.approx(100 / 32)
    assert [r["reading"] for r in rows] == ["better", "within ±3 points", "not shown to differ"]
    assert rows[0]["holm_p"] == pytest.approx(3 * 2 / 256)


def test_too_few_scenes_for_the_family_say_so() -> None:
    """Five scenes: the smallest two-sided p is 2/32 > 0.05/5, no interval below 6 scenes."""
    outcomes, scene = _queries(5, seed=1)
    rows = comparison_rows(outcomes, scene, seed=0)
    assert all(r["reading"] == "too few scenes for this family" for r in rows)
    assert all(np.isnan(r["lo"]) and np.isnan(r["hi"]) for r in rows)
    lines = comparison_lines(rows)
    assert len(lines) == 2 + len(PAIRS)
    assert lines[0].startswith("| comparison | A % | B % | A - B, points [95% CI] |")
    body = lines[2].split(" | ")
    assert "[no interval: 5 scenes" in body[3]
    assert body[6] == body[7] == "–"


def test_above_twenty_scenes_the_p_value_is_drawn_and_says_its_error() -> None:
    outcomes, scene = _queries(24, seed=2)
    rows = comparison_rows(outcomes, scene, seed=0, pairs=PAIRS[:1])
    assert rows[0]["scene_mc_error"] > 0 or rows[0]["scene_p"] < 1e-4
    again = comparison_rows(outcomes, scene, seed=0, pairs=PAIRS[:1])
    assert again[0]["scene_p"] == rows[0]["scene_p"]  # the comparison's own generator
    line = comparison_lines(rows)[2]
    assert line.startswith("| explore vs before | ")
    if rows[0]["scene_mc_error"] > 0:
        assert " ±" in line.split(" | ")[5]
