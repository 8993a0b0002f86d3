"""The pair counts of :mod:`care_maps.evaluate.discrimination` against sklearn's AUROC and a plain
double loop; ties, strata, sums, rule directions and the second attempt's set by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sklearn.metrics import roc_auc_score

from care_maps.evaluate.discrimination import (
    LOG_CONFIDENCE_WIDTH,
    Discrimination,
    PairCounts,
    auroc,
    confidence_strata,
    discrimination,
    pair_counts,
    rule_direction,
    rule_discrimination,
    second_attempt_set,
)
from care_maps.replan.attempts import run_attempts
from care_maps.replan.strategies import STRATEGIES, candidate_set


def _loop_counts(success, member, values, prefer_high, strata=None) -> tuple[int, int, int]:
    """Reference: every (right, wrong) pair of one query's set, one stratum, one by one."""
    conc = disc = tied = 0
    n_q, n_c = member.shape
    for q in range(n_q):
        for i in range(n_c):
            for j in range(n_c):
                if not (member[q, i] and member[q, j] and success[q, i] and not success[q, j]):
                    continue
                if strata is not None and strata[q, i] != strata[q, j]:
                    continue
                a, b = values[i], values[j]
                if not prefer_high:
                    a, b = -a, -b
                a = -math.inf if math.isnan(a) else a
                b = -math.inf if math.isnan(b) else b
                if a > b:
                    conc += 1
                elif a < b:
                    disc += 1
                else:
                    tied += 1
    return conc, disc, tied


def test_hand_example_five_candidates():
    # One query, five candidates, all in the set; right: 0 and 3; the rule prefers HIGH.
    #   id:      0    1    2    3    4
    #   right:   R    w    w    R    w
    #   value:   5    3    5    1    2
    #   logP:  -0.1 -0.5 -1.5 -1.2 -0.9  -> strata (1 nat, ceil): 0, 0, -1, -1, 0
    # (right, wrong) pairs: (0,1) 5>3 conc, (0,2) 5=5 tie, (0,4) 5>2 conc,
    #                       (3,1) 1<3 disc, (3,2) 1<5 disc, (3,4) 1<2 disc
    # unstratified: 2 concordant, 3 discordant, 1 tied -> AUROC (2 + 0.5) / 6
    # same stratum only: (0,1) conc, (0,4) conc [stratum 0]; (3,2) disc [stratum -1]
    #   -> 2 concordant, 1 discordant -> AUROC 2/3
    success = np.array([[True, False, False, True, False]])
    member = np.ones((1, 5), bool)
    values = np.array([5.0, 3.0, 5.0, 1.0, 2.0])
    conf = np.array([[-0.1, -0.5, -1.5, -1.2, -0.9]])
    np.testing.assert_array_equal(confidence_strata(conf), [[0, 0, -1, -1, 0]])
    d = discrimination(conf, success, member, values, prefer_high=True)
    assert d.unstratified == PairCounts(2, 3, 1)
    assert d.unstratified.auroc == pytest.approx(2.5 / 6)
    assert d.stratified == PairCounts(2, 1, 0)
    assert d.stratified.auroc == pytest.approx(2 / 3)
    # the opposite direction swaps concordant and discordant, ties stay
    low = discrimination(conf, success, member, values, prefer_high=False)
    assert low.unstratified == PairCounts(3, 2, 1)
    assert low.stratified == PairCounts(1, 2, 0)


def test_ties_count_one_half():
    # right 0 and wrong 1 tie; right 0 beats wrong 2 -> (1 + 0.5) / 2
    success = np.array([[True, False, False]])
    counts = pair_counts(
        success, np.ones((1, 3), bool), np.array([2.0, 2.0, 1.0]), prefer_high=True
    )
    assert counts == PairCounts(1, 0, 1)
    assert counts.auroc == 0.75
    # NaN is the worst value under either direction: it ties with NaN and with the worst inf
    nan = np.array([np.nan, np.nan, np.inf])
    assert pair_counts(success, np.ones((1, 3), bool), nan, prefer_high=False) == PairCounts(
        0, 0, 2
    )


def test_pairs_in_different_strata_are_not_counted():
    # right 0 (stratum 0) vs wrong 1 (stratum -1): a pair without strata, none with them
    success = np.array([[True, False]])
    member = np.ones((1, 2), bool)
    values = np.array([1.0, 0.0])
    conf = np.array([[-0.5, -1.5]])
    d = discrimination(conf, success, member, values, prefer_high=True)
    assert d.unstratified == PairCounts(1, 0, 0)
    assert d.stratified == PairCounts()
    assert math.isnan(d.stratified.auroc)
    # explicit strata are honoured; stratum -b is (-(b+1), -b] nats: -1 and -1.0001 share one
    same = pair_counts(success, member, values, prefer_high=True, strata=np.zeros((1, 2), int))
    assert same == PairCounts(1, 0, 0)
    np.testing.assert_array_equal(
        confidence_strata(np.array([[0.0, -0.0, -1e-9, -1.0, -1.0001, -2.0001, -np.inf]])),
        [[0, 0, 0, -1, -1, -2, -(10**15)]],
    )


def test_pairs_never_cross_queries():
    # query 0 has only a right member, query 1 only a wrong one: no pair at all
    success = np.array([[True, False], [True, False]])
    member = np.array([[True, False], [False, True]])
    assert pair_counts(success, member, np.array([1.0, 0.0]), prefer_high=True) == PairCounts()


def test_one_query_matches_sklearn():
    rng = np.random.default_rng(0)
    n = 60
    values = np.round(rng.normal(size=n), 1)  # rounded: some ties
    success = rng.random((1, n)) < 0.3
    member = rng.random((1, n)) < 0.7
    on = member[0]
    for high in (True, False):
        got = pair_counts(success, member, values, prefer_high=high)
        score = values[on] if high else -values[on]
        assert got.auroc == pytest.approx(roc_auc_score(success[0, on], score), abs=1e-12)
        assert got.pairs == success[0, on].sum() * (~success[0, on]).sum()


def test_many_queries_match_a_double_loop():
    rng = np.random.default_rng(1)
    n_q, n_c = 7, 40
    values = np.round(rng.normal(size=n_c), 1)
    values[[3, 11]] = np.nan
    values[5] = np.inf
    conf = np.log(rng.random((n_q, n_c)))
    success = rng.random((n_q, n_c)) < 0.35
    member = rng.random((n_q, n_c)) < 0.5
    strata = confidence_strata(conf)
    for high in (True, False):
        d = discrimination(conf, success, member, values, prefer_high=high)
        ref_all = _loop_counts(success, member, values, high)
        ref_strat = _loop_counts(success, member, values, high, strata)
        assert d.unstratified == PairCounts(*ref_all)
        assert d.stratified == PairCounts(*ref_strat)
        assert d.stratified.pairs < d.unstratified.pairs
    # per-query values (Q, N) work like broadcast (N,) ones
    tiled = np.broadcast_to(values, (n_q, n_c))
    assert pair_counts(success, member, tiled, prefer_high=True) == PairCounts(
        *_loop_counts(success, member, values, True)
    )


def test_counts_add_across_calls():
    rng = np.random.default_rng(2)
    values = rng.normal(size=30)
    conf = np.log(rng.random((6, 30)))
    success = rng.random((6, 30)) < 0.4
    member = rng.random((6, 30)) < 0.6
    whole = discrimination(conf, success, member, values, prefer_high=False)
    parts = [
        discrimination(conf[s], success[s], member[s], values, prefer_high=False)
        for s in (slice(0, 2), slice(2, 5), slice(5, 6))
    ]
    assert parts[0] + parts[1] + parts[2] == whole
    assert sum(parts) == whole
    assert sum([p.stratified for p in parts]) == whole.stratified
    assert Discrimination() + whole == whole
    assert auroc(*(3, 1, 2)) == PairCounts(3, 1, 2).auroc == pytest.approx(4 / 6)
    assert math.isnan(auroc(0, 0, 0))


def test_rule_directions_come_from_the_rules():
    assert rule_direction("max_entropy") == ("entropy", True)
    assert rule_direction("min_stderr") == ("stderr", False)
    assert rule_direction("min_pwkl") == ("pwkl", False)
    assert rule_direction(STRATEGIES["min_entropy"]) == ("entropy", False)
    assert rule_direction("max_pwkl") == ("pwkl", True)
    for name in ("max_confidence", "random_topk", "no_replan", "min_pwkl_near"):
        with pytest.raises(ValueError, match="does not choose"):
            rule_direction(name)
    success = np.array([[True, False]])
    member = np.ones((1, 2), bool)
    columns = {"stderr": np.array([0.1, 0.2]), "entropy": np.array([0.1, 0.2])}
    conf = np.zeros((1, 2))
    assert rule_discrimination("min_stderr", conf, success, member, columns).stratified == (
        PairCounts(1, 0, 0)
    )
    assert rule_discrimination("max_entropy", conf, success, member, columns).stratified == (
        PairCounts(0, 1, 0)
    )


def test_second_attempt_set_is_the_evaluations():
    # ids by confidence: 2 > 0 > 4 > 1 > 3; first attempt 2; top-2 after it: {0, 4}
    conf = np.log(np.array([[0.8, 0.3, 0.9, 0.1, 0.5]]))
    member = second_attempt_set(conf, "confidence", 2)
    np.testing.assert_array_equal(member, [[True, False, False, False, True]])
    # a query solved by its first attempt makes no second one
    solved = np.array([[False, False, True, False, False]])
    assert not second_attempt_set(conf, "confidence", 2, success=solved).any()
    # grid exclusion: cell 0 lies within 1 m of the first attempt (cell 2)
    pos = np.array([[0.5, 0, 0], [5, 0, 0], [0, 0, 0], [9, 0, 0], [7, 0, 0]], float)
    near = second_attempt_set(conf, "confidence", 2, positions=pos, exclude_radius=1.0)
    np.testing.assert_array_equal(near, [[False, True, False, False, True]])
    # category criterion: rank < k among the remaining candidates
    rank = np.array([[0, 3, 0, 1, 2]])
    cat = second_attempt_set(conf, "category", 2, rank=rank)
    np.testing.assert_array_equal(cat, [[True, False, False, True, False]])


def test_second_attempt_set_matches_the_rule_played():
    # the rule's second attempt, played by run_attempts, is the best member of the set
    rng = np.random.default_rng(3)
    n_q, n_c, k = 20, 200, 8
    conf = np.log(rng.random((n_q, n_c)))
    success = rng.random((n_q, n_c)) < 0.05
    columns = {"entropy": rng.random(n_c), "stderr": rng.random(n_c), "pwkl": rng.random(n_c)}
    member = second_attempt_set(conf, "confidence", k, success=success)
    played = run_attempts("min_pwkl", conf, success, columns, k=k)
    failed = ~played.success[:, 0]
    np.testing.assert_array_equal(member.any(axis=1), failed)
    np.testing.assert_array_equal(member.sum(axis=1), played.set_size[:, 1])
    best = np.where(member, columns["pwkl"], np.inf).argmin(axis=1)
    np.testing.assert_array_equal(best[failed], played.candidate[failed, 1])
    first = conf.argmax(axis=1)
    available = np.ones_like(member)
    available[np.arange(n_q), first] = False
    np.testing.assert_array_equal(
        member[failed], candidate_set("confidence", conf, available, k)[failed]
    )


def test_width_is_one_nat():
    assert LOG_CONFIDENCE_WIDTH == 1.0
    np.testing.assert_array_equal(confidence_strata(np.array([[-2.5]]), width=0.5), [[-5]])
    with pytest.raises(ValueError, match="width"):
        confidence_strata(np.zeros((1, 1)), width=0.0)
