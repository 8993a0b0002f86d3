"""The pre-registered tables from attempt rows, against independent references: the
difference by hand, statsmodels' McNemar and Holm, a plain scene-resampling loop."""

from __future__ import annotations

import itertools

import numpy as np
import pyarrow as pa
import pyarrow.compute
import pytest
from statsmodels.stats.contingency_tables import mcnemar
from statsmodels.stats.multitest import multipletests

from care_maps.evaluate.report.preregistered import (
    PAPER_SETTINGS,
    Reading,
    best_of_k_table,
    by_class_table,
    headline_table,
    query_breakdown,
)

SCENES, PER_SCENE = 8, 12
RULES = [
    ("no_replan", "-", 0),
    ("oracle", "-", 0),
    ("max_confidence", "-", 0),
    ("largest", "-", 0),
    ("most_views", "-", 0),
    *PAPER_SETTINGS["instances"],
    ("max_entropy", "category", 2),
]


def _attempts(seed: int = 3) -> tuple[pa.Table, dict]:
    """Attempt rows of one map and protocol: a shared first attempt, then each rule's second;
    returns the table and the per-query outcome of each rule."""
    rng = np.random.default_rng(seed)
    rows, solved = [], {r: {} for r in RULES}
    for s in range(SCENES):
        for q in range(PER_SCENE):
            key = (f"s{s}", f"q{q}")
            target = f"class{q % 4}"
            first = bool(rng.random() < 0.3)
            any_ok = first or bool(rng.random() < 0.7)
            for rule in RULES:
                second = False
                if not first and rule[0] not in ("no_replan",):
                    second = any_ok if rule[0] == "oracle" else bool(any_ok and rng.random() < 0.5)
                solved[rule][key] = float(first or second)
                base = {"scene": key[0], "map": "instances", "protocol": "instance", "unit": "room",
                        "query": key[1], "target": target, "strategy": rule[0],
                        "criterion": rule[1], "k": rule[2], "seed": -1, "expected": np.nan}  # fmt: skip
                rows.append({**base, "attempt": 1, "success": first})
                if not first and rule[0] != "no_replan":
                    rows.append({**base, "attempt": 2, "success": second})
    table = pa.Table.from_pylist(rows)
    table = table.set_column(
        table.schema.get_field_index("k"), "k", pa.array(table.column("k").to_pylist(), pa.int16())
    )
    return table, solved


def _signflip_p(a: np.ndarray, b: np.ndarray, scenes: np.ndarray, d: float) -> float:
    """The scene sign-flip p-value of ``H0: difference = d``, every pattern written out."""
    names = np.unique(scenes)
    z = [((a - b)[scenes == g] - d).sum() for g in names]
    observed = abs(sum(z))
    patterns = list(itertools.product((1, -1), repeat=len(z)))
    return sum(abs(np.dot(s, z)) >= observed - 1e-9 for s in patterns) / len(patterns)


def test_headline_against_statsmodels_and_a_resampling_loop() -> None:
    attempts, solved = _attempts()
    table = headline_table(attempts, bootstrap=300).to_pylist()
    vs_max = [r for r in table if r["baseline"].startswith("Max confidence")]
    assert {(r["strategy"], r["criterion"], r["k"]) for r in vs_max} == {
        *PAPER_SETTINGS["instances"], ("largest", "-", 0), ("most_views", "-", 0)
    }  # fmt: skip
    queries = sorted(solved[RULES[0]])
    scenes = np.array([q[0] for q in queries])
    b = np.array([solved["max_confidence", "-", 0][q] for q in queries])
    for r in vs_max:
        rule = (r["strategy"], r["criterion"], r["k"])
        a = np.array([solved[rule][q] for q in queries])
        assert r["diff"] == pytest.approx(100 * (a - b).mean())
        table2 = [
            [np.sum(a * b), np.sum(a * (1 - b))],
            [np.sum(b * (1 - a)), np.sum((1 - a) * (1 - b))],
        ]
        assert r["mcnemar_p"] == pytest.approx(mcnemar(table2, exact=True).pvalue)
        # the interval is the set of differences the scene sign-flip test keeps: just inside
        # each end it keeps, just outside it rejects
        assert r["scene_p"] == pytest.approx(_signflip_p(a, b, scenes, 0.0))
        lo, hi = r["lo"] / 100, r["hi"] / 100
        assert lo <= r["diff"] / 100 <= hi
        for end, outward in ((lo, -1e-6), (hi, 1e-6)):
            assert _signflip_p(a, b, scenes, end - outward) > 0.05
            assert _signflip_p(a, b, scenes, end + outward) <= 0.05
    family = [r for r in vs_max if r["family"] == "pre-registered"]
    # Holm over the scene-level p-values, not the query-level McNemar ones
    expected = multipletests([r["scene_p"] for r in family], method="holm")[1]
    np.testing.assert_allclose([r["holm_p"] for r in family], expected)
    # 8 scenes: the smallest scene p is 2/256, below 0.05/3, so the family can reject
    assert all(r["family_can_reject"] for r in family)
    assert family[0]["family_min_p"] == pytest.approx(2 / 2**SCENES)


def test_best_of_k_corrects_over_every_setting_tried() -> None:
    attempts, _ = _attempts()
    rows = best_of_k_table(attempts, bootstrap=50).to_pylist()
    assert len(rows) == 4
    assert {r["settings_tried"] for r in rows} == {4}
    expected = multipletests([r["scene_p"] for r in rows], method="holm")[1]
    np.testing.assert_allclose([r["holm_p"] for r in rows], expected)
    best = [r for r in rows if r["best"] and r["strategy"] == "max_entropy"]
    assert len(best) == 1
    assert best[0]["rate"] == max(r["rate"] for r in rows if r["strategy"] == "max_entropy")


def test_by_class_and_the_query_breakdown_count_queries() -> None:
    attempts, solved = _attempts()
    by_class = by_class_table(attempts).to_pylist()
    rows = [r for r in by_class if r["strategy"] == "min_stderr"]
    assert sum(r["n_queries"] for r in rows) == SCENES * PER_SCENE
    wins = sum(
        solved["min_stderr", "category", 2][q] * (1 - solved["max_confidence", "-", 0][q])
        for q in solved["min_stderr", "category", 2]
    )
    assert sum(r["wins"] for r in rows) == wins
    (br,) = query_breakdown(attempts).to_pylist()
    assert br["queries"] == SCENES * PER_SCENE
    assert br["unsolvable"] == sum(v == 0 for v in solved["oracle", "-", 0].values())
    assert br["first_attempt_solved"] == sum(solved["no_replan", "-", 0].values())


def test_a_family_its_scenes_cannot_reject_says_so() -> None:
    """Five scenes: the smallest two-sided sign-flip p is 2/32 = 0.0625 > 0.05, so no row
    of any family can pass Holm: the rows say so instead of reading as a finding."""
    attempts, _ = _attempts()
    keep = pa.compute.is_in(attempts.column("scene"), pa.array([f"s{i}" for i in range(5)]))
    rows = headline_table(attempts.filter(keep), bootstrap=50).to_pylist()
    assert rows
    for r in rows:
        assert not r["family_can_reject"]
        assert r["family_min_p"] == pytest.approx(min(1.0, 2 / 2**5 * r["baseline_choices"]))
        assert r["reading"] == Reading.CANNOT_REJECT


def test_a_baseline_chosen_as_the_best_of_several_is_corrected() -> None:
    """Against the best random top-k, chosen from every random setting run, each scene p
    enters Holm multiplied by their number (Bonferroni for the choice)."""
    attempts, _ = _attempts()
    extra = []
    for k in (2, 4):
        rows = attempts.filter(pa.compute.equal(attempts.column("strategy"), "max_confidence"))
        extra += [
            {**r, "strategy": "random_topk", "criterion": "confidence", "k": k}
            for r in rows.to_pylist()
        ]
    table = pa.concat_tables([attempts, pa.Table.from_pylist(extra, schema=attempts.schema)])
    rows = headline_table(table, bootstrap=50).to_pylist()
    vs_random = [r for r in rows if r["baseline_choices"] > 1 and r["family"] == "pre-registered"]
    assert vs_random
    assert {r["baseline_choices"] for r in vs_random} == {2}
    expected = multipletests([min(1.0, 2 * r["scene_p"]) for r in vs_random], method="holm")[1]
    np.testing.assert_allclose([r["holm_p"] for r in vs_random], expected)
