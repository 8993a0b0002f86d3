"""The pair counts of :mod:`care_maps.evaluate.discrimination` against sklearn's AUROC and a plain
double loop; ties, strata, sums, rule directions and the second attempt's set by hand."""

from __future__ import annotations

import math

import numpy as np
import pyarrow as pa
import pytest
from sklearn.metrics import roc_auc_score

import care_maps.evaluate.discrimination as discrimination_module
from care_maps.evaluate.discrimination import (
    LOG_CONFIDENCE_WIDTH,
    MATCH_CALIPER,
    Discrimination,
    PairCounts,
    auroc,
    confidence_strata,
    discrimination,
    log_odds,
    matched_pair_counts,
    pair_counts,
    rule_direction,
    rule_discrimination,
    scene_auroc,
    second_attempt_set,
)
from care_maps.evaluate.paired import comparison_rng
from care_maps.evaluate.scene_test import scene_signflip
from care_maps.replan.attempts import run_attempts
from care_maps.replan.strategies import STRATEGIES, candidate_set
from care_maps.research.discrimination import discrimination_markdown, reading


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


# --- matched pairs: confidence held equal by a caliper on log-odds --------------------------


def _odds_ref(lp: float) -> float:
    """log P - log(1 - P) from P itself (not the module's expm1 form)."""
    if lp == 0.0:
        return math.inf
    if lp == -math.inf:
        return -math.inf
    p = math.exp(lp)
    return math.log(p) - math.log1p(-p)


def _loop_matched(conf, success, member, values, prefer_high, caliper):
    """Reference: every (right, wrong) pair of one query within the caliper of log-odds, one
    by one; (measure's, confidence's own) counts."""
    meas = [0, 0, 0]
    own = [0, 0, 0]
    n_q, n_c = member.shape
    vals = np.broadcast_to(values, (n_q, n_c))
    for q in range(n_q):
        for i in range(n_c):
            for j in range(n_c):
                if not (member[q, i] and member[q, j] and success[q, i] and not success[q, j]):
                    continue
                xi, xj = _odds_ref(conf[q, i]), _odds_ref(conf[q, j])
                if not (xi == xj or abs(xi - xj) <= caliper):
                    continue
                a, b = vals[q, i], vals[q, j]
                if not prefer_high:
                    a, b = -a, -b
                a = -math.inf if math.isnan(a) else a
                b = -math.inf if math.isnan(b) else b
                meas[0 if a > b else 1 if a < b else 2] += 1
                ci, cj = conf[q, i], conf[q, j]
                own[0 if ci > cj else 1 if ci < cj else 2] += 1
    return PairCounts(*meas), PairCounts(*own)


def _conf_of_odds(x):
    """log-confidence whose log-odds is ``x``."""
    return -np.log1p(np.exp(-np.asarray(x, np.float64)))


def test_log_odds():
    lp = np.log([0.5, 0.9, 0.1])
    np.testing.assert_allclose(log_odds(lp), [0.0, math.log(9), -math.log(9)], atol=1e-12)
    # near-certain candidates stay apart where log P squeezes them together
    near = log_odds(np.array([-1e-9, -1e-6, 0.0, -np.inf]))
    np.testing.assert_allclose(near[:2], [-math.log(1e-9), -math.log(1e-6)], rtol=1e-6)
    assert near[2] == math.inf
    assert near[3] == -math.inf
    np.testing.assert_allclose(log_odds(_conf_of_odds([-3.0, 0.7, 12.0])), [-3.0, 0.7, 12.0])
    for bad in (np.nan, 0.1):
        with pytest.raises(ValueError, match="log-confidence"):
            log_odds(np.array([bad]))


def test_matched_hand_example():
    # One query, six candidates, all in the set; the rule prefers HIGH; caliper 0.25.
    #   id:        0     1     2     3     4     5
    #   right:     R     w     w     R     w     w
    #   log-odds: 0.0   0.2   0.3   2.0   2.1  -0.2
    #   value:     5     3     7     1     1     6
    # matched (|dx| <= 0.25): (0,1) 5>3 conc, (0,5) 5<6 disc, (3,4) 1=1 tie; (0,2) is 0.3 apart
    # confidence's own: (0,1) 0<0.2 disc, (0,5) 0>-0.2 conc, (3,4) 2<2.1 disc
    conf = _conf_of_odds([[0.0, 0.2, 0.3, 2.0, 2.1, -0.2]])
    success = np.array([[True, False, False, True, False, False]])
    member = np.ones((1, 6), bool)
    values = np.array([5.0, 3.0, 7.0, 1.0, 1.0, 6.0])
    meas, own = matched_pair_counts(conf, success, member, values, prefer_high=True)
    assert meas == PairCounts(1, 1, 1)
    assert meas.auroc == 0.5
    assert own == PairCounts(1, 2, 0)
    assert own.auroc == pytest.approx(1 / 3)
    d = discrimination(conf, success, member, values, prefer_high=True)
    assert (d.matched, d.matched_confidence) == (meas, own)
    # a wider caliper takes (0,2) in: 5 < 7, and 0 < 0.3 in confidence
    wide, wide_own = matched_pair_counts(
        conf, success, member, values, prefer_high=True, caliper=0.5
    )
    assert wide == PairCounts(1, 2, 1)
    assert wide_own == PairCounts(1, 3, 0)
    with pytest.raises(ValueError, match="caliper"):
        matched_pair_counts(conf, success, member, values, prefer_high=True, caliper=-1.0)


def test_matched_pairs_match_a_double_loop():
    rng = np.random.default_rng(11)
    n_q, n_c = 6, 45
    values = np.round(rng.normal(size=n_c), 1)  # rounded: ties
    values[[2, 9]] = np.nan
    values[4] = -np.inf
    x = rng.normal(0, 1.5, (n_q, n_c))  # unrounded: no pair on the caliper's edge
    x[:, 10:16] = x[:, 16:22]  # equal confidences: matched at any caliper, tied in confidence
    conf = _conf_of_odds(x)
    conf[0, :5] = 0.0  # P = 1 in floating point: log-odds +inf, matched only with each other
    conf[1, :4] = -np.inf  # P = 0
    conf[2, :6] = -np.array([1e-9, 2e-9, 1e-6, 1.1e-6, 1e-3, 5e-4])  # near-certain
    success = rng.random((n_q, n_c)) < 0.4
    member = rng.random((n_q, n_c)) < 0.8
    for caliper in (0.0, 0.1, MATCH_CALIPER, 1.0):
        for high in (True, False):
            got = matched_pair_counts(
                conf, success, member, values, prefer_high=high, caliper=caliper
            )
            assert got == _loop_matched(conf, success, member, values, high, caliper)
    # per-query values and a chunk smaller than one member's partners give the same counts
    tiled = np.broadcast_to(values, (n_q, n_c))
    ref = _loop_matched(conf, success, member, values, True, 1.0)
    assert matched_pair_counts(conf, success, member, tiled, prefer_high=True, caliper=1.0) == ref
    old = discrimination_module._PAIR_CHUNK
    try:
        discrimination_module._PAIR_CHUNK = 3
        assert (
            matched_pair_counts(conf, success, member, values, prefer_high=True, caliper=1.0) == ref
        )
    finally:
        discrimination_module._PAIR_CHUNK = old


def test_matched_auroc_matches_sklearn():
    # each right member against its own partners is one sklearn AUROC; the matched AUROC is
    # their pair-weighted mean
    rng = np.random.default_rng(12)
    n = 300
    x = rng.normal(0, 2, n)
    conf = _conf_of_odds(x)[None, :]
    success = (rng.random(n) < 1 / (1 + np.exp(-x)))[None, :]
    values = np.round(rng.normal(size=n) + 0.3 * success[0], 1)
    member = np.ones((1, n), bool)
    got, _ = matched_pair_counts(conf, success, member, values, prefer_high=False)
    total = weight = 0.0
    for r in np.flatnonzero(success[0]):
        partners = np.flatnonzero(~success[0] & (np.abs(x - x[r]) <= MATCH_CALIPER))
        if not len(partners):
            continue
        ids = np.r_[r, partners]
        total += len(partners) * roc_auc_score(success[0, ids], -values[ids])
        weight += len(partners)
    assert got.pairs == weight > 100
    assert got.auroc == pytest.approx(total / weight, abs=1e-12)


def test_caliper_holds_confidence_equal_where_bins_do_not():
    # Confidence strongly predictive (calibrated: a candidate is right with probability P),
    # a third of the candidates near-certain (log P within 1e-3 of 0: one 1-nat bin), and a
    # measure that only tracks confidence. Every pair and the 1-nat bins credit the measure;
    # the matched pairs, where confidence's own AUROC is ~0.5, do not.
    rng = np.random.default_rng(13)
    n_q, n_c = 40, 300
    x = np.where(rng.random((n_q, n_c)) < 1 / 3, rng.normal(9, 2, (n_q, n_c)),
                 rng.normal(-2, 2, (n_q, n_c)))  # fmt: skip
    conf = _conf_of_odds(x)
    success = rng.random((n_q, n_c)) < np.exp(conf)
    values = x + rng.normal(0, 0.05, (n_q, n_c))  # what confidence says, no more
    member = np.ones((n_q, n_c), bool)
    d = discrimination(conf, success, member, values, prefer_high=True)
    own_all = pair_counts(success, member, conf, prefer_high=True).auroc
    assert own_all > 0.85
    assert d.unstratified.auroc > 0.85
    assert d.stratified_confidence.auroc > 0.65
    assert d.stratified.auroc > 0.65
    assert d.matched.pairs > 10_000
    assert abs(d.matched_confidence.auroc - 0.5) < 0.05
    assert abs(d.matched.auroc - 0.5) < 0.05
    # a finer caliper: fewer pairs, confidence's own AUROC within noise of 0.5
    fine = discrimination(conf, success, member, values, prefer_high=True, caliper=0.02)
    assert 0 < fine.matched.pairs < d.matched.pairs / 5
    assert abs(fine.matched_confidence.auroc - 0.5) < 3 * math.sqrt(0.25 / fine.matched.pairs)


# --- scenes as units ----------------------------------------------------------------------


def _scene_counts(rng, aurocs, pairs):
    """Per-scene counts of pairs whose measure is concordant with probability ``auroc``."""
    conc = rng.binomial(pairs, aurocs)
    return [PairCounts(int(c), int(n - c), 0) for c, n in zip(conc, pairs, strict=True)]


def test_scene_auroc_is_the_sign_flip_test_of_the_pairs():
    rng = np.random.default_rng(21)
    counts = [PairCounts(int(c), int(d), int(t)) for c, d, t in rng.integers(0, 40, (9, 3))]
    got = scene_auroc(counts, rng=comparison_rng(0, "x"))
    # the same test on per-pair outcomes: a = 1 (concordant), 1/2 (tied), 0 (discordant)
    a, groups = [], []
    for g, c in enumerate(counts):
        a += [1.0] * c.concordant + [0.5] * c.tied + [0.0] * c.discordant
        groups += [g] * c.pairs
    a = np.array(a)
    ref = scene_signflip(a, 1 - a, np.array(groups), rng=comparison_rng(0, "x"))
    assert got.auroc == pytest.approx(sum(counts, PairCounts()).auroc)
    assert got.auroc == pytest.approx((1 + ref.estimate) / 2)
    assert got.p_value == pytest.approx(ref.p_value)
    assert got.low == pytest.approx((1 + ref.low) / 2)
    assert got.high == pytest.approx((1 + ref.high) / 2)
    assert (got.scenes, got.effective) == (9, pytest.approx(ref.effective))


def test_scene_auroc_holds_its_level_when_scenes_differ():
    # AUROC 0.5 overall, but each scene leans one way or the other (0.3 or 0.7) over many
    # pairs: a pair-level interval leaves out 0.5 almost always, the scene-level one about
    # 5% of the time at most
    rng = np.random.default_rng(22)
    runs, scene_rejects, pair_rejects = 300, 0, 0
    for _ in range(runs):
        aurocs = 0.5 + 0.2 * rng.choice([-1, 1], 8)
        counts = _scene_counts(rng, aurocs, rng.integers(100, 300, 8))
        got = scene_auroc(counts, rng=rng)
        scene_rejects += not got.low <= 0.5 <= got.high
        total = sum(counts, PairCounts())
        se = math.sqrt(0.25 / total.pairs)
        pair_rejects += abs(total.auroc - 0.5) > 1.96 * se
    assert scene_rejects / runs <= 0.05 + 3 * math.sqrt(0.05 * 0.95 / runs)
    assert pair_rejects / runs > 0.5


def test_scene_auroc_finds_an_effect_and_needs_scenes():
    rng = np.random.default_rng(23)
    strong = scene_auroc(_scene_counts(rng, np.full(10, 0.8), np.full(10, 50)), rng=rng)
    assert 0.5 < strong.low <= strong.auroc <= strong.high <= 1.0
    assert strong.p_value == pytest.approx(2 / 2**10)  # every scene leans the same way
    # the interval is [0, 1]-valued in the other direction too
    weak = scene_auroc(_scene_counts(rng, np.full(10, 0.2), np.full(10, 50)), rng=rng)
    assert 0.0 <= weak.low <= weak.auroc <= weak.high < 0.5
    # too few scenes: no interval, only the p-value (at least 2 / 2^4); empty scenes dropped
    few = _scene_counts(rng, np.full(4, 0.8), np.full(4, 50)) + [PairCounts()] * 5
    small = scene_auroc(few, rng=rng)
    assert small.low is None
    assert small.high is None
    assert small.scenes == 4
    assert small.p_value >= 2 / 2**4
    # one scene holding nearly every pair leaves too few effective scenes
    lopsided = _scene_counts(rng, np.full(8, 0.8), np.array([5000] + [5] * 7))
    assert scene_auroc(lopsided, rng=rng).low is None
    none = scene_auroc([PairCounts()] * 3, rng=rng)
    assert math.isnan(none.auroc)
    assert math.isnan(none.p_value)
    assert none.scenes == 0


def test_markdown_reads_a_direction_only_outside_the_interval():
    assert reading(0.455, 0.39, 0.53, 0.45, 0.56) == "not shown to differ from 0.5"
    assert reading(0.40, 0.33, 0.47, 0.45, 0.56) == "prefers the wrong candidate"
    assert reading(0.66, 0.58, 0.74, 0.45, 0.56) == "prefers the right candidate"
    assert reading(0.66, 0.58, 0.74, 0.31, 0.44) == "confidence not held equal"
    assert reading(0.66, None, None, None, None) == "too few scenes for an interval"
    assert reading(float("nan"), None, None, None, None) == "no matched pair"
    row = {
        "map": "instances", "protocol": "instance", "strategy": "max_entropy",
        "criterion": "confidence", "k": 8, "caliper": MATCH_CALIPER,
        "pairs_matched": 120, "auroc_matched": 0.455, "auroc_matched_low": 0.39,
        "auroc_matched_high": 0.53, "p_matched": 0.2, "confidence_auroc_matched": 0.51,
        "confidence_auroc_matched_low": 0.45, "confidence_auroc_matched_high": 0.56,
        "scenes_matched": 20, "effective_scenes_matched": 17.0, "pairs": 300, "auroc": 0.449,
        "confidence_auroc": 0.42, "pairs_all": 4000, "auroc_all": 0.462,
    }  # fmt: skip
    text = discrimination_markdown(
        pa.Table.from_pylist([row]), {"instances": (("max_entropy", "confidence", 8),)}
    )
    assert "| 120 (20) | 0.51 [0.45, 0.56] | 0.46 [0.39, 0.53] | not shown to differ" in text
    assert "wrong way" not in text
    assert "neither a necessary nor a sufficient" in text
