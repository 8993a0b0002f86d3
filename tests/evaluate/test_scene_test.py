"""The scene sign-flip test against independent references (a plain enumeration of every sign
pattern, ``scipy.stats.permutation_test``, a hand-worked example, a plain bisection of the
p-value for the interval) and its coverage of a true zero in a null simulation of clustered,
heterogeneous scenes."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.stats import permutation_test

from care_maps.evaluate.scene_test import (
    ALPHA,
    EQUIVALENCE_MARGIN,
    EXACT_MAX_SCENES,
    MIN_SCENES,
    effective_scenes,
    equivalence_p,
    min_scenes,
    scene_signflip,
    scene_sums,
    sign_vectors,
    signflip_interval,
    signflip_p,
    smallest_p,
)
from care_maps.research.coverage import coverage_markdown, coverage_table, simulate_null


def _brute_p(sums, counts, d=0.0):
    """Every sign pattern, one at a time: the share whose |sum s_g z_g| reaches |sum z_g|."""
    z = [s - d * n for s, n in zip(sums, counts, strict=True)]
    observed = abs(sum(z))
    hits = 0
    for signs in itertools.product((1, -1), repeat=len(z)):
        if abs(sum(s * x for s, x in zip(signs, z, strict=True))) >= observed - 1e-9:
            hits += 1
    return hits / 2 ** len(z)


def _outcomes(sums, count):
    """Binary ``a``, ``b`` and scenes of ``count`` queries per scene with the given sums of
    ``a - b`` (a succeeds alone on ``S_g`` queries, or b alone on ``-S_g``)."""
    a, b, groups = [], [], []
    for g, s in enumerate(sums):
        a += [1.0] * max(s, 0) + [0.0] * (count - max(s, 0))
        b += [1.0] * max(-s, 0) + [0.0] * (count - max(-s, 0))
        groups += [g] * count
    return np.array(a), np.array(b), np.array(groups)


def _bisect(p, inside, outside):
    """The last ``d`` from ``inside`` towards ``outside`` whose ``p(d)`` exceeds ALPHA."""
    if p(outside) > ALPHA:
        return outside
    for _ in range(100):
        mid = (inside + outside) / 2
        if p(mid) > ALPHA:
            inside = mid
        else:
            outside = mid
    return inside


def test_min_scenes_is_computed_from_alpha() -> None:
    assert MIN_SCENES == min_scenes(0.05) == 6  # 2/64 <= 0.05 < 2/32
    assert min_scenes(0.01) == 8  # 2/256 <= 0.01 < 2/128
    assert min_scenes(0.5) == 2
    assert min_scenes(0.1) == 5
    with pytest.raises(ValueError, match="alpha"):
        min_scenes(0.0)


def test_hand_worked_example() -> None:
    # Six scenes of 10 queries, S_g = (3, 2, 2, 1, 1, -1): estimate 8 / 60.
    # p at 0: T = 8. Flipping a set F of scenes of the magnitudes x = (3, 2, 2, 1, 1, 1)
    # gives |10 - 2 x(F)| >= 8 iff x(F) <= 1 (F empty or one of the three 1s: 4 patterns)
    # or x(F) >= 9 (their complements: 4): p = 8 / 64 = 0.125.
    # Interval: p > 0.05 needs at least 4 of the 64 patterns (0.05 * 64 = 3.2).
    # At d = 0.3, z = S - 3 = (0, -1, -1, -2, -2, -4): T = 10 = sum |z_g|, reached by the
    # two aligned patterns times the free sign of the zero scene: p = 4/64 = 0.0625, kept.
    # Just above 0.3 the first z_g is negative too: 2 patterns, p = 2/64 = 0.031, rejected.
    # At d = -0.1, z = S + 1 = (4, 3, 3, 2, 2, 0): the same, so the interval is [-0.1, 0.3].
    a, b, groups = _outcomes([3, 2, 2, 1, 1, -1], 10)
    res = scene_signflip(a, b, groups, rng=np.random.default_rng(0))
    assert res.exact
    assert res.scenes == 6
    assert res.estimate == pytest.approx(8 / 60)
    assert res.p_value == pytest.approx(8 / 64)
    assert res.low == pytest.approx(-0.1)
    assert res.high == pytest.approx(0.3)
    sums, counts = scene_sums(a, b, groups)
    signs, exact = sign_vectors(6, rng=np.random.default_rng(0))
    p = lambda d: signflip_p(sums, counts, d, signs=signs, exact=exact)  # noqa: E731
    assert p(0.3) == pytest.approx(4 / 64)
    assert p(0.3 + 1e-6) == pytest.approx(2 / 64)
    assert p(-0.1) == pytest.approx(4 / 64)
    assert p(-0.1 - 1e-6) == pytest.approx(2 / 64)


@pytest.mark.parametrize("scenes", [1, 2, 3, 5, 6, 8, 10])
def test_p_value_matches_a_plain_enumeration(scenes: int) -> None:
    rng = np.random.default_rng(scenes)
    counts = rng.integers(3, 15, scenes).astype(float)
    for fractions in (False, True):
        # binary differences, or seed averages in quarters (exact ties in floating point)
        step = 4 if fractions else 1
        sums = rng.integers(-step * counts, step * counts + 1) / step
        signs, exact = sign_vectors(scenes, rng=rng)
        assert exact
        assert len(signs) == 2**scenes
        for d in (0.0, 0.1, -0.25, sums.sum() / counts.sum(), 1.0):
            assert signflip_p(sums, counts, d, signs=signs, exact=exact) == pytest.approx(
                _brute_p(sums, counts, d), abs=1e-12
            )


def _z(scenes: int, seed: int) -> np.ndarray:
    a, b, groups = simulate_null(np.random.default_rng(seed), scenes)
    sums, counts = scene_sums(a, b, groups)
    return sums, counts


def _scipy_p(z, rng, resamples):
    """One-sample ``permutation_type='samples'``: scipy flips the sign of each observation."""
    return permutation_test(
        (z,),
        lambda x, axis: np.abs(np.sum(x, axis=axis)),
        permutation_type="samples",
        vectorized=True,
        n_resamples=resamples,
        alternative="greater",
        rng=rng,
    ).pvalue


def test_exact_p_value_matches_scipy_exact() -> None:
    sums, counts = _z(12, 3)
    signs, exact = sign_vectors(12, rng=np.random.default_rng(0))
    for d in (0.0, 0.05, -0.1):
        ours = signflip_p(sums, counts, d, signs=signs, exact=exact)
        theirs = _scipy_p(sums - d * counts, np.random.default_rng(0), np.inf)  # all 2^12
        assert ours == pytest.approx(theirs, abs=1e-12)


@pytest.mark.parametrize(("scenes", "seed"), [(21, 1), (30, 2), (45, 3)])
def test_random_p_value_matches_scipy_within_monte_carlo_error(scenes: int, seed: int) -> None:
    sums, counts = _z(scenes, seed)
    delta = sums.sum() / counts.sum()
    resamples = 20_000
    signs, exact = sign_vectors(scenes, rng=np.random.default_rng(seed), resamples=resamples)
    assert not exact
    assert signs.shape == (resamples, scenes)
    for d in (0.0, delta - 0.03, delta + 0.05):
        ours = signflip_p(sums, counts, d, signs=signs, exact=exact)
        theirs = _scipy_p(sums - d * counts, np.random.default_rng(seed + 100), resamples)
        # two independent Monte Carlo p-values: sd of the difference <= sqrt(2/4/20000) = 0.005
        assert ours == pytest.approx(theirs, abs=0.025)


def test_random_p_value_counts_the_observed_pattern() -> None:
    """``(1 + hits) / (1 + B)``: never zero, and one when every pattern ties."""
    sums = np.full(21, 2.0)
    counts = np.full(21, 10.0)
    signs, _ = sign_vectors(21, rng=np.random.default_rng(0), resamples=999)
    assert signflip_p(sums, counts, 0.0, signs=signs, exact=False) == pytest.approx(1 / 1000)
    assert signflip_p(sums, counts, 0.2, signs=signs, exact=False) == 1.0


@pytest.mark.parametrize(("scenes", "seed"), [(6, 0), (7, 1), (11, 2), (16, 3), (25, 4)])
def test_interval_is_the_inverted_test(scenes: int, seed: int) -> None:
    """The interval's ends are where a plain bisection of p(d) puts them (the same sign
    patterns for every d), p(d) exceeds alpha inside and not just outside."""
    sums, counts = _z(scenes, seed)
    signs, exact = sign_vectors(scenes, rng=np.random.default_rng(seed), resamples=5000)
    low, high = signflip_interval(sums, counts, signs=signs, exact=exact)
    delta = sums.sum() / counts.sum()
    p = lambda d: signflip_p(sums, counts, d, signs=signs, exact=exact)  # noqa: E731
    assert p(delta) == 1.0
    # the p-value's tie tolerance (1e-9 of the query count) reaches a few 1e-9 past an end
    assert low == pytest.approx(_bisect(p, delta, -1.0), abs=1e-7)
    assert high == pytest.approx(_bisect(p, delta, 1.0), abs=1e-7)
    assert low < delta < high
    assert p(low) > ALPHA
    assert p(high) > ALPHA
    if low > -1:
        assert p(low - 1e-6) <= ALPHA
    if high < 1:
        assert p(high + 1e-6) <= ALPHA
    for d in np.linspace(low, high, 41):  # one interval: no rejection inside
        assert p(d) > ALPHA


def test_no_interval_below_min_scenes() -> None:
    rng = np.random.default_rng(7)
    for scenes in range(1, MIN_SCENES):
        a, b, groups = _outcomes([5] * scenes, 10)  # as lopsided as it gets
        res = scene_signflip(a, b, groups, rng=rng)
        assert res.low is None
        assert res.high is None
        assert res.p_value == pytest.approx(min(1.0, 2 / 2**scenes))
    a, b, groups = _outcomes([5] * MIN_SCENES, 10)
    res = scene_signflip(a, b, groups, rng=rng)
    assert res.p_value == pytest.approx(2 / 2**MIN_SCENES)
    assert res.p_value <= ALPHA
    assert 0 < res.low <= res.estimate == 0.5 <= res.high
    # a laxer alpha lowers the bar
    a, b, groups = _outcomes([5] * 5, 10)
    assert scene_signflip(a, b, groups, rng=rng, alpha=0.1).low is not None


def test_fractions_estimate_and_missing_pairs() -> None:
    a = np.array([0.25, 1.0, 0.5, np.nan, 0.0, 0.75, 1.0, 0.0])
    b = np.array([0.0, 0.5, 0.5, 1.0, 1.0, 0.25, 0.0, np.nan])
    groups = np.array(["x", "x", "y", "y", "z", "z", "w", "w"])
    sums, counts = scene_sums(a, b, groups)
    np.testing.assert_allclose(sums, [1.0, 0.75, 0.0, -0.5])  # w, x, y, z (sorted)
    np.testing.assert_allclose(counts, [1, 2, 1, 2])
    res = scene_signflip(a, b, groups, rng=np.random.default_rng(0))
    keep = ~np.isnan(a) & ~np.isnan(b)
    assert res.estimate == pytest.approx(np.mean(a[keep] - b[keep]))
    assert res.scenes == 4
    assert res.p_value == pytest.approx(_brute_p(sums, counts))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        scene_signflip(a * 2, b, groups, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="aligned"):
        scene_signflip(a[:-1], b, groups, rng=np.random.default_rng(0))
    empty = scene_signflip([], [], [], rng=np.random.default_rng(0))
    assert empty.scenes == 0
    assert np.isnan(empty.estimate)
    assert empty.low is None


def test_seeded_and_exact_cases_leave_the_generator_alone() -> None:
    a, b, groups = simulate_null(np.random.default_rng(5), 24)
    one = scene_signflip(a, b, groups, rng=np.random.default_rng(11))
    two = scene_signflip(a, b, groups, rng=np.random.default_rng(11))
    assert one == two
    assert not one.exact
    rng = np.random.default_rng(3)
    state = rng.bit_generator.state
    a, b, groups = simulate_null(np.random.default_rng(5), EXACT_MAX_SCENES)
    assert scene_signflip(a, b, groups, rng=rng).exact
    assert rng.bit_generator.state == state


def _null_runs(scenes: int, simulations: int, seed: int, **kwargs):
    results = []
    for i in range(simulations):
        a, b, groups = simulate_null(np.random.default_rng([seed, scenes, i]), scenes, **kwargs)
        results.append(scene_signflip(a, b, groups, rng=np.random.default_rng([seed, i])))
    return results


@pytest.mark.slow
def test_null_coverage_of_zero() -> None:
    """No true difference, clustered heterogeneous scenes (query counts 10..40, Beta base
    rates and discordances, a fifth of queries seed-averaged): the 95% interval covers zero
    in 93-97% of 2000 data sets at 20 scenes (Monte Carlo s.e. 0.005). Covering zero is
    ``p(0) > alpha``, checked on every run. So it does when each scene has its own true
    difference, zero only on average over scenes (1000 data sets; there the query bootstrap
    covers about 80%, care_maps/research/coverage.py). At 4 scenes the test cannot reject and no
    interval is given."""
    for effect_sd, simulations in ((0.0, 2000), (0.1, 1000)):
        runs = _null_runs(20, simulations, seed=2024, effect_sd=effect_sd)
        covered = np.array([r.low <= 0 <= r.high for r in runs])
        np.testing.assert_array_equal(covered, [r.p_value > ALPHA for r in runs])
        coverage = covered.mean()
        assert 0.93 <= coverage <= 0.97, (effect_sd, coverage)
    few = _null_runs(4, 300, seed=2024)
    assert all(r.low is None and r.high is None for r in few)
    assert min(r.p_value for r in few) >= 2 / 2**4  # coverage of the inverted set: 1
    assert np.mean([r.p_value > ALPHA for r in few]) == 1.0


def test_coverage_table_smoke() -> None:
    rows = coverage_table((4, 6), simulations=12, bootstrap_simulations=3, bootstrap_resamples=50)
    assert [(r["scenes"], r["method"]) for r in rows] == [
        (g, m) for g in (4, 6) for m in ("signflip", "cluster_bootstrap", "query_bootstrap")
    ]
    assert [r["printed"] for r in rows if r["method"] == "signflip"] == [False, True]
    assert rows[0]["coverage"] == 1.0
    assert rows[1]["simulations"] == 3
    text = coverage_markdown(rows)
    assert text.count("\n") == len(rows) + 1
    assert "too few scenes" in text


def _brute_one_sided(sums, counts, d, side):
    """Every sign pattern: the share whose signed sum reaches the observed one in the
    direction ``side`` (+1: at least as large, -1: at most as large)."""
    z = [s - d * n for s, n in zip(sums, counts, strict=True)]
    observed = side * sum(z)
    hits = sum(
        side * sum(s * x for s, x in zip(signs, z, strict=True)) >= observed - 1e-9
        for signs in itertools.product((1, -1), repeat=len(z))
    )
    return hits / 2 ** len(z)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_equivalence_p_is_the_larger_one_sided_brute_force_p(seed: int) -> None:
    """TOST: ``max(p(delta <= -m), p(delta >= m))``, each one-sided p by plain enumeration."""
    rng = np.random.default_rng(seed)
    counts = rng.integers(5, 30, 9).astype(float)
    sums = np.round(rng.uniform(-0.1, 0.1, 9) * counts)
    signs, exact = sign_vectors(9, rng=rng)
    m = EQUIVALENCE_MARGIN
    expected = max(_brute_one_sided(sums, counts, -m, +1), _brute_one_sided(sums, counts, m, -1))
    assert equivalence_p(sums, counts, signs=signs, exact=exact) == pytest.approx(expected)


def test_equivalence_needs_a_small_and_precise_difference() -> None:
    """Twelve scenes agreeing on a zero difference are shown equivalent within 3 points; the
    same with a 5-point difference, or with three scenes, are not."""
    counts = np.full(12, 20.0)
    same = np.array([1, -1, 0, 0, 1, -1, 0, 0, 1, -1, 0, 0], float)
    signs, exact = sign_vectors(12, rng=np.random.default_rng(0))
    assert equivalence_p(same, counts, signs=signs, exact=exact) <= ALPHA
    assert equivalence_p(same + 1, counts, signs=signs, exact=exact) > ALPHA
    signs3, exact3 = sign_vectors(3, rng=np.random.default_rng(0))
    # one-sided, three scenes cannot go below 1/8
    assert equivalence_p(same[:3], counts[:3], signs=signs3, exact=exact3) >= 1 / 8


def test_effective_scenes_is_kish() -> None:
    """Hand-worked: equal sizes give the count; one scene of 200 and seven of 10 give
    270^2 / (200^2 + 7 * 10^2) = 1.79."""
    assert effective_scenes(np.full(8, 13.0)) == pytest.approx(8)
    assert effective_scenes(np.array([200.0] + [10.0] * 7)) == pytest.approx(72900 / 40700)
    assert effective_scenes(np.zeros(0)) == 0.0


def test_one_dominant_scene_gets_no_interval() -> None:
    """One scene of 200 queries beside seven of 10. Eight scenes, but
    1.8 effective ones: no interval (its p-value is 1 whatever the small scenes say)."""
    a, b, groups = _outcomes([0] + [3] * 7, 10)
    big_a = np.concatenate([a[10:], np.zeros(200)])
    big_b = np.concatenate([b[10:], np.zeros(200)])
    big_groups = np.concatenate([groups[10:], np.full(200, 99)])
    big_a[-5:] = 1.0  # the big scene: +5 of 200
    big_b[-105:-5] = 1.0  # and -100 of 200 (net -95)
    res = scene_signflip(big_a, big_b, big_groups, rng=np.random.default_rng(0))
    assert res.scenes == 8
    assert res.effective == pytest.approx(effective_scenes(np.array([200.0] + [10.0] * 7)))
    assert res.low is None
    assert res.p_value == pytest.approx(_brute_p(*scene_sums(big_a, big_b, big_groups)))


def test_smallest_attainable_p_and_monte_carlo_error() -> None:
    assert smallest_p(6, 64, exact=True) == pytest.approx(2 / 64)
    assert smallest_p(6, 64, exact=True, sided=1) == pytest.approx(1 / 64)
    assert smallest_p(40, 999, exact=False) == pytest.approx(1 / 1000)
    a, b, groups = _outcomes([1, 2, 0, 3, 1, 2, 1, 0], 10)
    res = scene_signflip(a, b, groups, rng=np.random.default_rng(0))
    assert res.exact
    assert res.min_p == pytest.approx(2 / 2**8)
    assert res.mc_error == 0.0
    a, b, groups = simulate_null(np.random.default_rng(5), EXACT_MAX_SCENES + 4)
    res = scene_signflip(a, b, groups, rng=np.random.default_rng(1), resamples=4000)
    assert not res.exact
    assert res.mc_error == pytest.approx(np.sqrt(res.p_value * (1 - res.p_value) / 4000))
