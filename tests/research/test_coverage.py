"""The null scenarios of ``care_maps/research/coverage.py`` against independent references: the
scenes' true differences average to zero as specified (the query-weighted mean for size-tied
effects, checked by a hand sum and by scipy's log-normal), the queries' pairs realise them,
and the fast exact p-values equal :func:`care_maps.evaluate.scene_test.signflip_p`. In the
slow tier: symmetric heterogeneous scene effects do not push the sign-flip test above its
level."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from care_maps.evaluate.scene_test import ALPHA, sign_vectors, signflip_p
from care_maps.research.coverage import (
    EFFECT_SD,
    EQUAL_QUERIES,
    LOGNORMAL_QUERIES,
    ONE_LARGE,
    SCENARIOS,
    SIZE_SPLIT,
    SMALL_EFFECT,
    exact_p_values,
    scenario_markdown,
    scenario_table,
    scene_parameters,
    simulate_scenario,
    size_distribution,
    size_tied_shares,
)


def test_uniform_size_tied_shares_match_a_hand_sum() -> None:
    """Sizes 10..40 equally likely: sum n over 10..24 is 255, over 25..40 is 520, so the large
    scenes' share is 0.5 * 255 / 520 and sum n t(n) is zero."""
    small, large = size_tied_shares(*size_distribution("uniform", 6))
    assert small == -SMALL_EFFECT
    assert large == pytest.approx(SMALL_EFFECT * 255 / 520)
    assert sum(n * (small if n < SIZE_SPLIT else large) for n in range(10, 41)) == pytest.approx(0)


def test_lognormal_sizes_follow_scipys_lognormal() -> None:
    """P(n = k) is the log-normal's mass between k - 0.5 and k + 0.5 (all below 1.5 on 1)."""
    values, probs = size_distribution("lognormal", 6)
    median, sigma = LOGNORMAL_QUERIES
    law = stats.lognorm(s=sigma, scale=median)
    expected = law.cdf(values + 0.5) - law.cdf(np.where(values == 1, 0.0, values - 0.5))
    np.testing.assert_allclose(probs, expected, rtol=1e-6, atol=1e-12)  # truncated at 5000
    assert probs.sum() == pytest.approx(1.0)
    assert np.sum(values * probs) == pytest.approx(law.mean(), rel=1e-3)


def test_size_tied_effects_have_a_query_weighted_mean_of_zero() -> None:
    """Over many scenes the query-weighted mean difference sum n e / sum n is zero within its
    sampling error (the scene-level n e are independent), and the scenes' sign follows their
    size; one large scene with fixed sizes: zero in expectation over the discordances."""
    for key in ("size_tied", "size_tied_lognormal"):
        counts, _, discord, effect = scene_parameters(
            np.random.default_rng(11), SCENARIOS[key], 20, 2000
        )
        weighted = (counts * effect).ravel()
        assert stats.ttest_1samp(weighted, 0.0).pvalue > 1e-3, key
        assert np.all((effect < 0) == ((counts < SIZE_SPLIT) & (discord > 0)))
        assert np.all(np.abs(effect) <= discord)
    counts, _, discord, effect = scene_parameters(
        np.random.default_rng(12), SCENARIOS["size_tied_one_large"], 8, 4000
    )
    assert np.all(counts[:, 0] == ONE_LARGE[0])
    assert np.all(counts[:, 1:] == ONE_LARGE[1])
    shares = effect / discord
    large = SMALL_EFFECT * ONE_LARGE[1] * 7 / ONE_LARGE[0]
    np.testing.assert_allclose(shares[:, 0], large)
    np.testing.assert_allclose(shares[:, 1:], -SMALL_EFFECT)
    assert stats.ttest_1samp((counts * effect).sum(axis=1), 0.0).pvalue > 1e-3


def test_symmetric_effects_are_symmetric_about_zero() -> None:
    counts, _, discord, effect = scene_parameters(
        np.random.default_rng(13), SCENARIOS["heterogeneous"], 20, 2000
    )
    assert np.all(counts == EQUAL_QUERIES)
    assert np.all(np.abs(effect) <= discord)
    e = effect.ravel()
    assert stats.ttest_1samp(e, 0.0).pvalue > 1e-3
    assert stats.ks_2samp(e, -e).pvalue > 1e-3
    assert 0 < e.std() < EFFECT_SD


def test_the_queries_realise_the_scene_effects() -> None:
    """E[S_g] = n_g e_g: the scene sums less their expectation average zero (a t-test over
    40,000 independent scenes), and a scene's mean difference follows its effect with slope 1
    (least squares, standard error about 0.005)."""
    sums, counts, effect = simulate_scenario(
        np.random.default_rng(14), SCENARIOS["size_tied"], 20, 2000
    )
    assert sums.shape == counts.shape == effect.shape == (2000, 20)
    residual = (sums - counts * effect).ravel()
    assert stats.ttest_1samp(residual, 0.0).pvalue > 1e-3
    fit = stats.linregress(effect.ravel(), (sums / counts).ravel())
    assert fit.slope == pytest.approx(1.0, abs=0.03)
    assert fit.intercept == pytest.approx(0.0, abs=0.005)


@pytest.mark.parametrize("scenes", [1, 2, 3, 6, 9, 12])
def test_exact_p_values_equal_signflip_p(scenes: int) -> None:
    """Quarter-step sums (ties between patterns), all-zero and all-equal scenes, d zero, one
    value, and one a row: the same p-value as the public function, to the bit."""
    rng = np.random.default_rng(scenes)
    sums = rng.integers(-8, 9, (40, scenes)) / 4.0
    counts = rng.integers(1, 30, (40, scenes)).astype(np.float64)
    sums[:4] = 0.0
    sums[4:8] = 1.0
    signs, exact = sign_vectors(scenes, rng=rng)
    assert exact
    for d in (0.0, 0.25, rng.uniform(-0.3, 0.3, 40)):
        ds = np.broadcast_to(d, (40,))
        expected = [
            signflip_p(s, n, float(x), signs=signs, exact=exact)
            for s, n, x in zip(sums, counts, ds, strict=True)
        ]
        np.testing.assert_array_equal(exact_p_values(sums, counts, d), expected)


def test_scenario_table_smoke() -> None:
    rows = scenario_table(("heterogeneous_one_large", "size_tied"), (6, 8), simulations=30)
    assert [(r["scenario"], r["scenes"]) for r in rows] == [
        (k, g) for k in ("heterogeneous_one_large", "size_tied") for g in (6, 8)
    ]
    one_large = rows[0]
    assert one_large["effective"] == pytest.approx(250**2 / (200**2 + 5 * 10**2))
    assert one_large["printed"] == 0.0
    text = scenario_markdown(rows)
    assert text.count("\n") == len(rows) + 3
    assert "30 null data sets a row" in text


@pytest.mark.slow
def test_symmetric_heterogeneous_effects_keep_the_level() -> None:
    """Each scene its own true difference, symmetric about zero, equal sizes: each scene's sum
    is symmetric about zero, so the test of zero keeps its level (at most 0.05 within three
    Monte Carlo standard errors of it, 1000 data sets a scene count) and its interval covers
    the data set's own difference at least as often."""
    simulations = 1000
    slack = 3 * math.sqrt(ALPHA * (1 - ALPHA) / simulations)
    for row in scenario_table(("heterogeneous",), (6, 8, 12, 20), simulations=simulations, seed=1):
        assert row["rejection"] <= ALPHA + slack, row
        assert row["coverage"] >= 1 - ALPHA - slack, row
        assert row["effective"] == row["scenes"]
