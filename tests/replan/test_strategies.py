"""Every rule of docs/method.md on hand-worked maps: sets, ties, fallbacks, random and oracle."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from care_maps.core.errors import QueryError, ReplanError
from care_maps.query.map import CandidateMap
from care_maps.replan import (
    STRATEGIES,
    Situation,
    candidate_set,
    expected_random_success,
    run_attempts,
)
from care_maps.replan.attempts import ReplanConfig, available_after, next_goal

# candidate:      0     1     2     3     4     5
CONF = np.array([[0.40, 0.20, 0.20, 0.10, 0.06, 0.04]])
COLUMNS = {
    "entropy": np.array([1.0, 3.0, 2.0, 3.0, 9.0, 0.5]),
    "stderr": np.array([0.3, 0.1, 0.1, 0.05, 0.01, np.inf]),
    "pwkl": np.array([0.3, 0.2, 0.4, np.inf, 0.1, 0.0]),
}
# rank of the target class among each candidate's classes (0 = its top class)
RANK = np.array([[0, 1, 5, 0, 2, 30]])
AFTER_FIRST = np.array([[False, True, True, True, True, True]])


def _choose(name: str, criterion: str = "confidence", k: int = 2, available=AFTER_FIRST, seed=0):
    cset = candidate_set(criterion, CONF, available, k, RANK)
    s = Situation(CONF, available, cset, COLUMNS, np.random.default_rng(seed))
    pick = STRATEGIES[name].rule(s)
    return int(pick.candidate[0]), bool(pick.fell_back[0]), float(pick.value[0])


def test_topk_confidence_is_ranks_2_to_k_plus_1_ties_by_lower_id() -> None:
    for k, expected in [(1, [1]), (2, [1, 2]), (3, [1, 2, 3]), (9, [1, 2, 3, 4, 5])]:
        got = np.flatnonzero(candidate_set("confidence", CONF, AFTER_FIRST, k)[0])
        assert got.tolist() == expected
    tied = np.array([[0.5, 0.1, 0.1, 0.1, 0.1, 0.1]])
    assert np.flatnonzero(candidate_set("confidence", tied, AFTER_FIRST, 2)[0]).tolist() == [1, 2]


def test_topk_category_is_rank_below_k_among_unvisited() -> None:
    assert np.flatnonzero(candidate_set("category", CONF, AFTER_FIRST, 1, RANK)[0]).tolist() == [3]
    assert np.flatnonzero(candidate_set("category", CONF, AFTER_FIRST, 3, RANK)[0]).tolist() == [
        1, 3, 4,
    ]  # fmt: skip
    with pytest.raises(ReplanError, match="unknown selection criterion"):
        candidate_set("colour", CONF, AFTER_FIRST, 2)
    with pytest.raises(ReplanError, match="k must be at least 1"):
        candidate_set("confidence", CONF, AFTER_FIRST, 0)


@pytest.mark.parametrize(
    ("name", "criterion", "k", "expected"),
    [
        ("max_confidence", "confidence", 2, 1),  # 1 and 2 tie at 0.20: lower id
        ("max_entropy", "confidence", 2, 1),  # H 3.0 > 2.0
        ("max_entropy", "confidence", 3, 1),  # 1 and 3 tie at H=3: higher confidence (1)
        ("max_entropy", "confidence", 9, 4),
        ("min_entropy", "confidence", 3, 2),
        ("min_stderr", "confidence", 2, 1),  # 0.1 tie, same confidence: lower id
        ("min_stderr", "confidence", 3, 3),
        ("min_stderr", "confidence", 4, 4),
        ("min_stderr", "confidence", 9, 4),  # +inf (one view) is the worst under min
        ("min_pwkl", "confidence", 3, 1),
        ("min_pwkl", "confidence", 9, 5),
        ("max_pwkl", "confidence", 3, 3),  # +inf is the best under max (the ablation)
        ("min_stderr", "category", 3, 4),  # set {1, 3, 4}
        ("max_entropy", "category", 1, 3),  # set {3}
        ("max_entropy", "category", 2, 1),  # set {1, 3}, H ties: higher confidence
    ],
)
def test_measure_rules(name, criterion, k, expected) -> None:
    cand, fell_back, value = _choose(name, criterion, k)
    assert (cand, fell_back) == (expected, False)
    measure = STRATEGIES[name].measure
    ref = CONF[0] if measure == "confidence" else COLUMNS[measure]
    assert value == ref[expected]


def test_tie_prefers_higher_confidence_over_lower_id() -> None:
    conf = np.array([[0.5, 0.1, 0.3, 0.1]])
    cols = {"entropy": np.array([0.0, 2.0, 2.0, 1.0]), "stderr": np.zeros(4), "pwkl": np.zeros(4)}
    avail = np.array([[False, True, True, True]])
    s = Situation(conf, avail, avail, cols)
    assert STRATEGIES["max_entropy"].rule(s).candidate[0] == 2


def test_empty_set_falls_back_to_max_confidence_and_says_so() -> None:
    avail = np.array([[False, True, True, False, False, True]])  # only 1, 2, 5 unvisited
    cand, fell_back, value = _choose("min_stderr", "category", 1, avail)  # set: rank<1 -> none
    assert (cand, fell_back, value) == (1, True, 0.20)
    cand, fell_back, _ = _choose("random_topk", "category", 1, avail)
    assert (cand, fell_back) == (1, True)
    nothing = np.zeros_like(AFTER_FIRST)
    for name in ("max_confidence", "min_pwkl", "random"):
        assert _choose(name, "confidence", 2, nothing)[0] == -1


def test_random_draws_only_unvisited_and_is_seeded() -> None:
    draws = [_choose("random", seed=s)[0] for s in range(200)]
    assert set(draws) == {1, 2, 3, 4, 5}
    assert draws == [_choose("random", seed=s)[0] for s in range(200)]
    top = {_choose("random_topk", "confidence", 3, seed=s)[0] for s in range(100)}
    assert top == {1, 2, 3}


def test_oracle_needs_truth_and_finds_any_success() -> None:
    with pytest.raises(ReplanError, match="oracle needs ground truth"):
        _choose("oracle")
    success = np.array([[False, False, False, False, True, True]])
    s = Situation(CONF, AFTER_FIRST, AFTER_FIRST, COLUMNS, success=success)
    assert STRATEGIES["oracle"].rule(s).candidate[0] == 4  # successful, higher confidence


def test_closed_form_random_expectation_hand_worked() -> None:
    success = np.array([[False, False, True, False, False, True]])
    # first attempt (0) fails; uniform over 5 unvisited with 2 successes
    p = expected_random_success("random", CONF, success)
    np.testing.assert_allclose(p, [2 / 5])
    # random from the top-3 confidence set {1, 2, 3}: one success
    np.testing.assert_allclose(expected_random_success("random_topk", CONF, success, k=3), [1 / 3])
    # three attempts, two draws without replacement: 1 - C(3,2)/C(5,2) = 1 - 3/10
    np.testing.assert_allclose(expected_random_success("random", CONF, success, attempts=3), [0.7])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 4), st.sampled_from([2, 4, 8]))
def test_oracle_bounds_every_strategy_and_seeds_meet_closed_form(seed, attempts, k) -> None:
    rng = np.random.default_rng(seed)
    n_q, n_c = 6, 12
    conf = rng.dirichlet(np.ones(n_c), size=n_q).round(2)  # rounding makes ties
    success = rng.random((n_q, n_c)) < 0.2
    rank = rng.integers(0, 10, size=(n_q, n_c))
    cols = {m: rng.random(n_c).round(1) for m in ("entropy", "stderr", "pwkl")}
    cols["stderr"][rng.random(n_c) < 0.3] = np.inf
    cols |= {"size": rng.integers(0, 9, n_c), "num_views": rng.integers(1, 6, n_c)}
    positions = rng.random((n_c, 3)) * 4
    kw = {"k": k, "attempts": attempts, "rank": rank, "positions": positions, "exclude_radius": 1.0}
    for criterion in ("confidence", "category"):
        oracle = run_attempts("oracle", conf, success, cols, criterion=criterion, **kw).solved
        if attempts >= 2:  # the oracle's second attempt finds any success left after the first
            first = run_attempts("no_replan", conf, success, cols, **kw)
            after = available_after(np.ones_like(success), first.candidate[:, 0], positions, 1.0)
            assert np.array_equal(oracle, first.solved | (success & after).any(axis=1))
        for name in STRATEGIES:
            res = run_attempts(name, conf, success, cols, criterion=criterion, rng=rng, **kw)
            assert not (res.solved & ~oracle).any(), name
            for row in res.candidate:
                made = row[row >= 0]
                assert len(set(made.tolist())) == len(made), (name, row)


def test_mean_over_seeds_converges_to_closed_form() -> None:
    rng = np.random.default_rng(7)
    n_q, n_c = 40, 15
    conf = rng.dirichlet(np.ones(n_c), size=n_q)
    success = rng.random((n_q, n_c)) < 0.25
    cols = {m: rng.random(n_c) for m in ("entropy", "stderr", "pwkl")}
    for name, kw in [("random", {}), ("random_topk", {"k": 4})]:
        expected = expected_random_success(name, conf, success, **kw).mean()
        seeds = [
            run_attempts(
                name, conf, success, cols, rng=np.random.default_rng(s), **kw
            ).solved.mean()
            for s in range(300)
        ]
        assert abs(np.mean(seeds) - expected) < 4 * np.std(seeds) / np.sqrt(len(seeds)) + 1e-9


def test_attempts_stop_at_success_and_grid_excludes_radius() -> None:
    conf = np.array([[0.5, 0.3, 0.1, 0.05, 0.05]])
    success = np.array([[False, False, False, True, False]])
    pos = np.array([[0, 0, 0], [0.5, 0, 0], [3, 0, 0], [6, 0, 0], [9, 0, 0]], float)
    cols = {m: np.zeros(5) for m in ("entropy", "stderr", "pwkl")}
    plain = run_attempts("max_confidence", conf, success, cols, attempts=4)
    assert plain.candidate.tolist() == [[0, 1, 2, 3]]
    assert plain.success.tolist() == [[False, False, False, True]]
    grid = run_attempts(
        "max_confidence", conf, success, cols, attempts=4, positions=pos, exclude_radius=1.0
    )
    assert grid.candidate.tolist() == [[0, 2, 3, -1]]  # 1 lies 0.5 m from the failed 0
    once = run_attempts("no_replan", conf, success, cols, attempts=4)
    assert once.candidate.tolist() == [[0, -1, -1, -1]]


def _tiny_map(kind: str = "grid") -> CandidateMap:
    text = np.eye(3, 4, dtype=np.float32)
    feats = np.array([[1, 0, 0, 0], [0.9, 0.1, 0, 0], [0.8, 0.6, 0, 0], [0, 0, 1, 0]], np.float32)
    feats /= np.linalg.norm(feats, axis=1, keepdims=True)
    logits = 10 * feats @ text.T
    log_norm = np.log(np.exp(logits).sum(1)).astype(np.float32)
    top = np.argsort(-logits, axis=1, kind="stable").astype(np.int16)
    return CandidateMap(
        kind=kind, vocabulary=("chair", "sofa", "bed"), text=text, logit_scale=10.0,
        features=feats, log_norm=log_norm, top_classes=top,
        entropy=np.zeros(4, np.float32), stderr=np.array([0.2, 0.3, 0.1, 0.0], np.float32),
        pwkl=np.zeros(4, np.float32), num_views=np.full(4, 3, np.int32),
        positions=np.array([[0, 0, 1], [0.4, 0, 1], [5, 0, 1], [9, 0, 1]], np.float32),
    )  # fmt: skip


def test_next_goal_live_api() -> None:
    cmap = _tiny_map()
    first = next_goal(cmap, "chair", [])
    assert (first.candidate, first.strategy, first.measure) == (0, "max_confidence", "confidence")
    # cell 1 lies within 1 m of the failed cell 0: excluded; the top-2 set is {2, 3}
    second = next_goal(cmap, "chair", [0], config=ReplanConfig(strategy="min_stderr", k=2))
    assert (second.candidate, second.strategy, second.value) == (3, "min_stderr", 0.0)
    second = next_goal(
        cmap, "chair", [0], config=ReplanConfig(strategy="min_stderr", k=2, exclude_radius=0)
    )
    assert second.candidate == 2
    assert second.set_size == 2
    inst = next_goal(
        _tiny_map("instances"), "chair", [0], config=ReplanConfig(strategy="min_stderr", k=1)
    )
    assert inst.candidate == 1
    fell = next_goal(
        cmap, "bed", [3], config=ReplanConfig(strategy="min_stderr", criterion="category", k=1)
    )
    assert fell.fell_back
    assert fell.strategy == "max_confidence"
    assert next_goal(cmap, 0, [0, 2, 3]).candidate == -1
    with pytest.raises(ReplanError, match="no further attempt"):
        next_goal(
            cmap, "chair", [0], config=ReplanConfig(strategy="no_replan")
        )  # its one attempt was made
    # free text resolves as in `care query`: an in-memory map has no store text side, so the
    # sentence model maps it to the nearest class
    assert next_goal(cmap, "couch", []) == next_goal(cmap, "sofa", [])
    with pytest.raises(QueryError, match="empty"):
        next_goal(cmap, "  ", [])
    with pytest.raises(ReplanError, match="unknown strategy 'best'"):  # checked once, made
        ReplanConfig(strategy="best")


def test_next_goal_travel_rules_take_the_distances() -> None:
    """``nearest_topk`` picks the set's nearest member by the distances given (here by hand);
    a travel rule without them is refused, not played as if every candidate were as far."""
    cmap = _tiny_map()
    # nothing excluded around the failed 0: the top-2 chair set is {1, 2}
    ask = {"config": ReplanConfig(strategy="nearest_topk", k=2, exclude_radius=0)}
    near = next_goal(cmap, "chair", [0], **ask, distance=[0.0, 9.0, 1.0, 2.0])
    assert (near.candidate, near.strategy, near.set_size) == (2, "nearest_topk", 2)
    assert next_goal(cmap, "chair", [0], **ask, distance=[0.0, 1.0, 9.0, 0.5]).candidate == 1
    first = next_goal(cmap, "chair", [], **ask)  # the first attempt needs no distance
    assert first.candidate == 0
    with pytest.raises(ReplanError, match="trades its measure against travel"):
        next_goal(cmap, "chair", [0], **ask)
    with pytest.raises(ReplanError, match="3 values for 4 candidates"):
        next_goal(cmap, "chair", [0], **ask, distance=[1.0, 2.0, 3.0])


def _best_reference(values, mask, conf, maximise):
    """Python loop: sort each row's members by (value, confidence, -id)."""
    out = []
    for q in range(mask.shape[0]):
        members = np.flatnonzero(mask[q])
        if len(members) == 0:
            out.append(-1)
            continue
        v = values if values.ndim == 1 else values[q]
        key = [
            (-np.inf if np.isnan(v[c]) else (v[c] if maximise else -v[c]), conf[q, c], -c)
            for c in members
        ]
        out.append(int(members[max(range(len(members)), key=key.__getitem__)]))
    return np.array(out)


@pytest.mark.parametrize("density", [0.02, 0.5])
@pytest.mark.parametrize("maximise", [True, False])
@pytest.mark.parametrize("per_query", [False, True])  # a measure column, or (Q, N) values
def test_best_of_sparse_and_dense_paths_match_a_loop(density, maximise, per_query) -> None:
    from care_maps.replan.strategies import best_of

    rng = np.random.default_rng(3)
    n_q, n_c = 40, 300
    shape = (n_q, n_c) if per_query else n_c
    values = rng.integers(0, 4, shape).astype(float)
    values[rng.random(shape) < 0.1] = np.inf
    values[rng.random(shape) < 0.05] = np.nan
    conf = rng.integers(0, 3, (n_q, n_c)) / 3.0
    mask = rng.random((n_q, n_c)) < density
    mask[0] = False
    cand, found = best_of(values, mask, conf, maximise=maximise)
    ref = _best_reference(values, mask, conf, maximise)
    np.testing.assert_array_equal(np.where(found, cand, -1), ref)


@pytest.mark.parametrize("seed", range(6))
def test_topk_confidence_matches_a_stable_sort(seed: int) -> None:
    """Against the definition: sort each row by (confidence desc, id asc), take k available."""
    rng = np.random.default_rng(seed)
    n_q, n = rng.integers(1, 12), rng.integers(1, 700)
    conf = rng.choice([0.1, 0.2, 0.5, 1.0], (n_q, n)) if seed % 2 else rng.random((n_q, n))
    available = rng.random((n_q, n)) < rng.choice([0.02, 0.5, 1.0])
    for k in (1, 2, 4, 8, 40, 100, n + 1):
        expected = np.zeros((n_q, n), bool)
        for q in range(n_q):
            ids = [c for c in np.argsort(-conf[q], kind="stable") if available[q, c]][:k]
            expected[q, ids] = True
        np.testing.assert_array_equal(candidate_set("confidence", conf, available, k), expected)


@pytest.mark.parametrize("attempts", [3, 4, 7])
def test_expected_random_success_is_the_hypergeometric_tail(attempts: int) -> None:
    """Against scipy.stats.hypergeom: after a failed first attempt, A - 1 draws without
    replacement from the U unvisited candidates, S of them successes."""
    from scipy.stats import hypergeom

    rng = np.random.default_rng(attempts)
    conf = rng.random((200, 12))
    success = rng.random((200, 12)) < 0.15
    got = expected_random_success("random", conf, success, attempts=attempts)
    first = conf.argmax(axis=1)
    first_ok = success[np.arange(200), first]
    rest = success.sum(axis=1) - first_ok
    miss = hypergeom(11, rest, attempts - 1).pmf(0)
    np.testing.assert_allclose(got, np.where(first_ok, 1.0, 1.0 - miss), rtol=1e-12)


def test_mismatched_episode_inputs_are_one_clear_error() -> None:
    from care_maps.replan.attempts import run_attempts

    conf = np.array([[0.5, 0.3, 0.2]])
    with pytest.raises(ReplanError, match=r"success \(1, 2\)"):
        run_attempts("random", conf, np.zeros((1, 2), bool), {})
    with pytest.raises(ReplanError, match="no 'stderr' column"):
        run_attempts("min_stderr", conf, np.zeros((1, 3), bool), {})


@pytest.mark.parametrize("kind", ["grid", "instances"])
def test_visited_positions_count_the_candidates_around_them(kind: str) -> None:
    from scipy.spatial import cKDTree

    from care_maps.replan.attempts import candidates_near

    cmap = _tiny_map(kind)
    places = np.array([[0.3, 0.5], [8.5, 0.2]])
    tree = cKDTree(cmap.positions[:, :2].astype(np.float64))
    expected = sorted({i for hits in tree.query_ball_point(places, r=1.0) for i in hits})
    np.testing.assert_array_equal(candidates_near(cmap, places, 1.0), expected)
    by_place = next_goal(
        cmap, "chair", config=ReplanConfig(strategy="min_stderr", k=2), visited_at=places
    )
    # the places exclude what lies within the radius of them, not again around each candidate
    by_id = next_goal(
        cmap, "chair", expected, config=ReplanConfig(strategy="min_stderr", k=2, exclude_radius=0)
    )
    assert by_place == by_id
    assert by_place.strategy == "min_stderr"  # a replan, not a first attempt
    # a place beyond the radius of every candidate's box was given in another frame
    lo, hi = cmap.positions[:, :2].min(0), cmap.positions[:, :2].max(0)
    edge = (float(hi[0]) + 0.9, float(lo[1]))
    at_edge = next_goal(
        cmap, "chair", config=ReplanConfig(strategy="min_stderr", k=2), visited_at=[edge]
    )
    assert at_edge.strategy == "min_stderr"  # the robot looked somewhere: not a first attempt
    with pytest.raises(ReplanError, match=r"visited position 50,50 lies outside the map"):
        next_goal(
            cmap,
            "chair",
            config=ReplanConfig(strategy="min_stderr", k=2),
            visited_at=[(50.0, 50.0)],
        )
    with pytest.raises(ReplanError, match="finite"):
        next_goal(cmap, "chair", visited_at=[(np.nan, 0.0)])
