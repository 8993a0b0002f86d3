"""How often a 95% interval of a paired difference in success covers zero when the two
strategies do not differ, by number of scenes: the scene sign-flip interval
(:func:`care_maps.evaluate.scene_test.scene_signflip`), the scene-clustered percentile bootstrap and
the query (unclustered) percentile bootstrap (:func:`care_maps.evaluate.paired.paired_bootstrap_ci`).

The null simulation (:func:`simulate_null`) has clustered, heterogeneous scenes: each scene
draws its query count (uniform in ``QUERIES``), its base success probability (a Beta), and
its discordance (the chance that exactly one strategy succeeds, a Beta share of what the base
rate allows). Within a scene the pair ``(a, b)`` is exchangeable, ``P(1, 0) = P(0, 1)``, so
the true difference is zero in every scene. A share of queries (``FRACTIONAL``) is
seed-averaged: both sides are means over ``SEEDS`` draws of the scene's pair. With
``effect_sd > 0`` each scene also gets its own difference ``e_g`` (normal, clipped
symmetrically to what its discordance allows), zero only on average over scenes: the case
where queries of one scene share a true difference, which only a scene-level method sees.

The sign-flip column's rejection is ``p(0) <= alpha``; its coverage is that of the printed
interval where one is printed (:data:`care_maps.evaluate.scene_test.MIN_SCENES` scenes or more) and of
the inverted set (``p(0) > alpha``) where not. A bootstrap interval rejects where it leaves
out zero. The bootstraps are slow, so they run on the first ``bootstrap_simulations`` data
sets only (the same data as the sign-flip column's first runs).

Where the sign-flip test can fail (:func:`scenario_table`, one row per scenario of
:data:`SCENARIOS` and scene count of :data:`SCENARIO_SCENES`). The test needs each scene's
summed difference to be symmetric about zero; exchangeable strategies make it so by
construction. In every scenario the population's query-weighted difference
``E[n_g e_g] / E[n_g]`` is zero (``n_g`` a scene's query count, ``e_g`` its true difference,
scenes drawn independently), so ``delta = 0`` is true and each rejection is a false one:

- ``exchangeable``: the null above (query counts uniform in :data:`QUERIES`, ``e_g = 0``);
- ``heterogeneous*``: ``e_g`` normal (sd :data:`EFFECT_SD`), clipped symmetrically to what the
  scene's discordance allows, so symmetric about zero, with equal sizes
  (:data:`EQUAL_QUERIES`), one large scene beside small ones (:data:`ONE_LARGE`) or
  log-normal sizes (:data:`LOGNORMAL_QUERIES`);
- ``size_tied*``: ``e_g = q_g t(n_g)``, a share of the scene's discordance ``q_g`` set by its
  size: ``-SMALL_EFFECT`` below :data:`SIZE_SPLIT` queries and, from there, the positive share
  that makes ``E[n t(n)] = 0`` under the size distribution (:func:`size_tied_shares`):
  larger scenes favour ``a``, smaller ones ``b``, and the query-weighted mean is zero, but a
  scene's sum is not symmetric about zero.

Per row: the rejection rate of ``delta = 0`` at :data:`ALPHA`; the coverage of the data
set's own query-weighted difference ``sum n_g e_g / sum n_g`` by the inverted set (the
printed interval where one is printed, as in the sign-flip column above); each with its
Monte Carlo standard error; the mean Kish effective number of scenes
(:func:`care_maps.evaluate.scene_test.effective_scenes`) and the share of data sets whose
interval is printed (:data:`MIN_SCENES` effective scenes or more).

Up to :data:`EXACT_MAX_SCENES` scenes the p-values count every sign pattern, as
:func:`care_maps.evaluate.scene_test.signflip_p` does, but for many data sets at once and by
halves (:func:`exact_p_values`): each pattern is a pattern of the first half of the scenes
beside one of the second (both from :func:`care_maps.evaluate.scene_test.sign_vectors`), so
sorting one half's signed sums and searching them for the other's counts the ``2^G``
patterns in ``O(2^(G/2) G)``. The first :data:`CHECKED` data sets of every cell also go
through the public functions (:func:`care_maps.evaluate.scene_test.scene_signflip`, or
``signflip_p`` and ``signflip_interval``), and any difference raises.

    python -m care_maps.research.coverage [--simulations 2000] [--bootstrap-simulations 400]
        [--scenario-simulations 4000] [--effect-sd 0] [--seed 0]
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from care_maps.evaluate.paired import paired_bootstrap_ci
from care_maps.evaluate.scene_test import (
    ALPHA,
    EXACT_MAX_SCENES,
    MIN_SCENES,
    N_SIGN_FLIPS,
    TIE_TOLERANCE,
    effective_scenes,
    scene_signflip,
    scene_sums,
    sign_vectors,
    signflip_interval,
    signflip_p,
)

__all__ = [
    "SCENARIOS",
    "Scenario",
    "coverage_markdown",
    "coverage_table",
    "exact_p_values",
    "scenario_markdown",
    "scenario_table",
    "scene_parameters",
    "simulate_null",
    "simulate_scenario",
    "size_distribution",
    "size_tied_shares",
]

QUERIES = (10, 40)
"""Queries per scene: uniform integers in this closed range."""
BASE_BETA = (2.0, 2.0)
"""Beta parameters of a scene's base success probability."""
DISCORDANCE_BETA = (1.0, 3.0)
"""Beta parameters of a scene's discordance, as a share of the most its base rate allows."""
FRACTIONAL = 0.2
"""Share of queries whose outcomes are averaged over seeds (a random strategy)."""
SEEDS = 4
"""Seeds averaged for a fractional query."""
SCENES = (2, 4, 6, 8, 12, 20, 30)
"""Scene counts of the table."""
SIMULATIONS = 2000
"""Null data sets per scene count (sign-flip column)."""
BOOTSTRAP_SIMULATIONS = 400
"""Null data sets per scene count for the bootstrap columns (the first ones)."""
BOOTSTRAP_RESAMPLES = 2000
"""Resamples of each simulated bootstrap interval (the report uses 10,000; the percentile
interval's coverage hardly moves with more)."""
METHODS = {
    "signflip": "scene sign-flip (test inversion)",
    "cluster_bootstrap": "scene-clustered percentile bootstrap",
    "query_bootstrap": "query percentile bootstrap (unclustered)",
}
"""Method key: its name in the table."""
CHECKED = 3
"""Data sets of each cell whose fast exact p-values are checked against the public functions
of :mod:`care_maps.evaluate.scene_test`."""
BATCH = 500
"""Data sets drawn at once by :func:`scenario_table` (bounds the per-query arrays)."""

EFFECT_SD = 0.1
"""Standard deviation of a scene's symmetric true difference (before clipping)."""
EQUAL_QUERIES = 25
"""Queries per scene with equal sizes."""
ONE_LARGE = (200, 10)
"""One scene of this many queries, every other of that many."""
LOGNORMAL_QUERIES = (25.0, 1.0)
"""Median and log standard deviation of log-normal query counts (rounded, at least 1)."""
LOGNORMAL_MAX = 5000
"""Log-normal query counts are truncated here (the mass above is below 1e-7)."""
SIZE_SPLIT = 25
"""Scenes of this many queries or more are "large" for size-tied effects."""
SMALL_EFFECT = 0.5
"""A small scene's size-tied difference, as a share of its discordance, in favour of ``b``."""
SCENARIO_SCENES = (6, 8, 12, 20)
"""Scene counts of the scenario table."""
SCENARIO_SIMULATIONS = 4000
"""Null data sets per scenario and scene count."""

SizeKind = Literal["uniform", "equal", "one_large", "lognormal"]
EffectKind = Literal["none", "symmetric", "size_tied"]


@dataclass(frozen=True)
class Scenario:
    """A null scenario of :func:`scenario_table`: how the scenes' query counts are drawn
    (:func:`size_distribution`) and how their true differences are set
    (:func:`scene_parameters`)."""

    label: str
    sizes: SizeKind
    effect: EffectKind


SCENARIOS: dict[str, Scenario] = {
    "exchangeable": Scenario("exchangeable, sizes 10-40", "uniform", "none"),
    "heterogeneous": Scenario("symmetric scene effects, equal sizes", "equal", "symmetric"),
    "heterogeneous_one_large": Scenario(
        "symmetric scene effects, one scene of 200 queries, the others 10",
        "one_large",
        "symmetric",
    ),
    "heterogeneous_lognormal": Scenario(
        "symmetric scene effects, log-normal sizes", "lognormal", "symmetric"
    ),
    "size_tied": Scenario("size-tied effects, sizes 10-40", "uniform", "size_tied"),
    "size_tied_lognormal": Scenario(
        "size-tied effects, log-normal sizes", "lognormal", "size_tied"
    ),
    "size_tied_one_large": Scenario(
        "size-tied effects, one scene of 200 queries, the others 10", "one_large", "size_tied"
    ),
}
"""Scenario key: the scenario (its label is its name in the table)."""


def simulate_null(
    rng: np.random.Generator,
    scenes: int,
    *,
    fractional: float = FRACTIONAL,
    seeds: int = SEEDS,
    effect_sd: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One null data set of ``scenes`` scenes: per-query ``(a, b, groups)``.

    Scene ``g``: ``n_g`` queries (uniform in :data:`QUERIES`), base success ``p_g`` (Beta
    :data:`BASE_BETA`), discordance ``q_g = u_g * 2 min(p_g, 1 - p_g)`` with ``u_g`` from Beta
    :data:`DISCORDANCE_BETA`, and the joint of one query's ``(a, b)``:
    ``P(1, 0) = (q_g + e_g) / 2``, ``P(0, 1) = (q_g - e_g) / 2``, ``P(1, 1) = p_g - q_g / 2``,
    ``P(0, 0) = 1 - p_g - q_g / 2``, with ``e_g = 0`` unless ``effect_sd > 0`` (then normal,
    clipped to ``[-q_g, q_g]``: symmetric about 0). Each query is, with probability
    ``fractional``, the mean over ``seeds`` independent draws of that joint (both sides), else
    one draw.
    """
    lo, hi = QUERIES
    counts = rng.integers(lo, hi + 1, scenes)
    base = rng.beta(*BASE_BETA, scenes)
    discord = rng.beta(*DISCORDANCE_BETA, scenes) * 2 * np.minimum(base, 1 - base)
    effect = np.zeros(scenes)
    if effect_sd > 0:
        effect = np.clip(rng.normal(0.0, effect_sd, scenes), -discord, discord)
    groups = np.repeat(np.arange(scenes), counts)
    a, b = _draw_pairs(rng, _cumulative(base, discord, effect), groups, fractional, seeds)
    return a, b, groups


def _cumulative(base: np.ndarray, discord: np.ndarray, effect: np.ndarray) -> np.ndarray:
    """Per scene (the last axis), the cumulative P of ``(1, 0)``, ``(0, 1)``, ``(1, 1)``;
    ``(0, 0)`` is the rest (the joint of :func:`simulate_null`)."""
    return np.cumsum(
        np.stack([(discord + effect) / 2, (discord - effect) / 2, base - discord / 2], axis=-1),
        axis=-1,
    )


def _draw_pairs(
    rng: np.random.Generator, cum: np.ndarray, groups: np.ndarray, fractional: float, seeds: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per query ``(a, b)``: one draw of its scene's joint (row ``groups`` of ``cum``, from
    :func:`_cumulative`), or with probability ``fractional`` the mean of ``seeds`` draws."""
    u = rng.random((len(groups), seeds))
    c = cum[groups][:, None, :]
    one_zero = u < c[..., 0]
    zero_one = (u >= c[..., 0]) & (u < c[..., 1])
    both = (u >= c[..., 1]) & (u < c[..., 2])
    a_draws = (one_zero | both).astype(np.float64)
    b_draws = (zero_one | both).astype(np.float64)
    averaged = rng.random(len(groups)) < fractional
    a = np.where(averaged, a_draws.mean(axis=1), a_draws[:, 0])
    b = np.where(averaged, b_draws.mean(axis=1), b_draws[:, 0])
    return a, b


def size_distribution(sizes: SizeKind, scenes: int) -> tuple[np.ndarray, np.ndarray]:
    """A scene's query count under ``sizes``, as ``(values, probabilities)``: uniform in
    :data:`QUERIES`; :data:`EQUAL_QUERIES`; log-normal (median and log standard deviation
    :data:`LOGNORMAL_QUERIES`) rounded to the nearest integer, at least 1 and truncated at
    :data:`LOGNORMAL_MAX`; or, for one large scene (a fixed layout of ``scenes`` scenes, not
    independent draws), its two sizes :data:`ONE_LARGE` as shares of the scenes."""
    if sizes == "uniform":
        lo, hi = QUERIES
        values = np.arange(lo, hi + 1)
        return values, np.full(len(values), 1.0 / len(values))
    if sizes == "equal":
        return np.array([EQUAL_QUERIES]), np.ones(1)
    if sizes == "one_large":
        large, small = ONE_LARGE
        return np.array([large, small]), np.array([1.0, scenes - 1.0]) / max(scenes, 1)
    if sizes == "lognormal":
        from scipy.special import ndtr

        median, sigma = LOGNORMAL_QUERIES
        values = np.arange(1, LOGNORMAL_MAX + 1)
        below = ndtr((np.log(values + 0.5) - math.log(median)) / sigma)  # P(round(x) <= k)
        probs = np.diff(below, prepend=0.0)
        return values, probs / probs.sum()
    msg = f"unknown scene sizes {sizes!r}"
    raise ValueError(msg)


def size_tied_shares(values: np.ndarray, probs: np.ndarray) -> tuple[float, float]:
    """The size-tied difference as a share of a scene's discordance, ``(small, large)``:
    ``-SMALL_EFFECT`` below :data:`SIZE_SPLIT` queries, and from there the share that makes the
    query-weighted mean ``E[n t(n)]`` zero under the size distribution ``(values, probs)``."""
    values = np.asarray(values, np.float64)
    probs = np.asarray(probs, np.float64)
    small = values < SIZE_SPLIT
    small_mass = float(np.sum(values * probs * small))
    large_mass = float(np.sum(values * probs * ~small))
    if small_mass <= 0 or large_mass <= 0:
        msg = f"size-tied differences need scenes on both sides of {SIZE_SPLIT} queries"
        raise ValueError(msg)
    return -SMALL_EFFECT, SMALL_EFFECT * small_mass / large_mass


def scene_parameters(
    rng: np.random.Generator, scenario: Scenario, scenes: int, datasets: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(counts, base, discord, effect)`` of ``datasets`` data sets of ``scenes`` scenes,
    each ``(datasets, scenes)``: query counts (:func:`size_distribution`), base success and
    discordance as in :func:`simulate_null`, and the true difference ``e_g``: zero; normal
    (sd :data:`EFFECT_SD`) clipped to ``[-q_g, q_g]`` (``symmetric``); or ``q_g`` times
    :func:`size_tied_shares`' share for the scene's size (``size_tied``)."""
    shape = (datasets, scenes)
    values, probs = size_distribution(scenario.sizes, scenes)
    if scenario.sizes == "one_large":
        counts = np.full(shape, ONE_LARGE[1])
        counts[:, :1] = ONE_LARGE[0]
    else:
        counts = rng.choice(values, size=shape, p=probs)
    base = rng.beta(*BASE_BETA, shape)
    discord = rng.beta(*DISCORDANCE_BETA, shape) * 2 * np.minimum(base, 1 - base)
    if scenario.effect == "symmetric":
        effect = np.clip(rng.normal(0.0, EFFECT_SD, shape), -discord, discord)
    elif scenario.effect == "size_tied":
        small, large = size_tied_shares(values, probs)
        effect = discord * np.where(counts < SIZE_SPLIT, small, large)
    else:
        effect = np.zeros(shape)
    return counts, base, discord, effect


def simulate_scenario(
    rng: np.random.Generator,
    scenario: Scenario,
    scenes: int,
    datasets: int,
    *,
    fractional: float = FRACTIONAL,
    seeds: int = SEEDS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``datasets`` null data sets of ``scenes`` scenes under ``scenario``, as per-scene
    ``(sums, counts, effect)``, each ``(datasets, scenes)``: the queries' pairs drawn as in
    :func:`simulate_null` from :func:`scene_parameters`, summed by
    :func:`care_maps.evaluate.scene_test.scene_sums`."""
    counts, base, discord, effect = scene_parameters(rng, scenario, scenes, datasets)
    groups = np.repeat(np.arange(counts.size), counts.ravel())
    cum = _cumulative(base, discord, effect).reshape(-1, 3)
    a, b = _draw_pairs(rng, cum, groups, fractional, seeds)
    sums, n = scene_sums(a, b, groups)
    return sums.reshape(counts.shape), n.reshape(counts.shape), effect


def exact_p_values(sums: np.ndarray, counts: np.ndarray, d: float | np.ndarray = 0.0) -> np.ndarray:
    """:func:`care_maps.evaluate.scene_test.signflip_p` of ``delta = d`` for each row (a data
    set) of ``sums`` and ``counts`` (``(datasets, scenes)``, ``scenes`` at most
    :data:`EXACT_MAX_SCENES`: every pattern), ``d`` one value or one a row.

    A pattern is a pattern of the first ``h = G // 2`` scenes beside one of the rest, so with
    ``L`` and ``R`` their signed sums of ``z_g = S_g - d n_g`` it counts where
    ``|L_i + R_j| >= |sum z_g| - TIE_TOLERANCE * N``: for each ``L_i``, a binary search of the
    sorted ``R``."""
    sums = np.atleast_2d(np.asarray(sums, np.float64))
    counts = np.atleast_2d(np.asarray(counts, np.float64))
    rows, scenes = sums.shape
    if counts.shape != sums.shape or not 1 <= scenes <= EXACT_MAX_SCENES:
        msg = f"need (datasets, 1..{EXACT_MAX_SCENES} scenes) sums and counts, got {sums.shape}"
        raise ValueError(msg)
    z = sums - np.broadcast_to(np.asarray(d, np.float64), (rows,))[:, None] * counts
    half = scenes // 2
    unused = np.random.default_rng(0)  # every pattern: the generator is not drawn from
    first, _ = sign_vectors(half, rng=unused)
    second, _ = sign_vectors(scenes - half, rng=unused)
    left = z[:, :half] @ first.T.astype(np.float64)
    right = np.sort(z[:, half:] @ second.T.astype(np.float64), axis=1)
    bar = np.abs(z.sum(axis=1)) - TIE_TOLERANCE * np.maximum(counts.sum(axis=1), 1.0)
    patterns = 2**scenes
    hits = np.full(rows, patterns, np.int64)
    for r in np.flatnonzero(bar > 0):  # else every pattern reaches it
        above = right.shape[1] - np.searchsorted(right[r], bar[r] - left[r])
        below = np.searchsorted(right[r], -bar[r] - left[r], side="right")
        hits[r] = int(above.sum() + below.sum())
    return hits / float(patterns)


def _rate_row(scenes: int, method: str, rejected: np.ndarray, covered: np.ndarray) -> dict:
    n = len(rejected)
    coverage = float(np.mean(covered))
    return {
        "scenes": scenes,
        "method": method,
        "simulations": n,
        "coverage": coverage,
        "rejection": float(np.mean(rejected)),
        "se": math.sqrt(ALPHA * (1 - ALPHA) / n),
        "printed": method != "signflip" or scenes >= MIN_SCENES,
    }


def coverage_table(
    scenes: Sequence[int] = SCENES,
    *,
    simulations: int = SIMULATIONS,
    bootstrap_simulations: int = BOOTSTRAP_SIMULATIONS,
    seed: int = 0,
    resamples: int = N_SIGN_FLIPS,
    bootstrap_resamples: int = BOOTSTRAP_RESAMPLES,
    effect_sd: float = 0.0,
) -> list[dict]:
    """Coverage of zero by each method's 95% interval, and its rejection rate of zero, per
    scene count: one row per (scene count, method) with keys ``scenes``, ``method`` (a key
    of :data:`METHODS`), ``simulations``, ``coverage``, ``rejection``, ``se`` (the Monte Carlo
    standard error of a coverage of ``1 - ALPHA``: the yardstick of a deviation) and
    ``printed`` (whether a report prints the interval: the sign-flip one from
    :data:`MIN_SCENES` scenes).

    Data set ``i`` of ``G`` scenes comes from the generator of ``(seed, G, i)`` and the
    draws of method ``k`` (its place in :data:`METHODS`) from ``(seed, G, i, k)``:
    deterministic, and the methods see the same data sets. Up to :data:`EXACT_MAX_SCENES`
    scenes the sign-flip p-values of all data sets are counted at once
    (:func:`exact_p_values`; covering zero is ``p(0) > alpha``), the first :data:`CHECKED`
    also by :func:`care_maps.evaluate.scene_test.scene_signflip`, which must agree."""
    rows = []
    for g in scenes:
        rejected = np.zeros(simulations, bool)
        covered = np.zeros(simulations, bool)
        bootstraps = {"cluster_bootstrap": True, "query_bootstrap": False}  # clustered?
        boot = {m: np.zeros((min(bootstrap_simulations, simulations), 2), bool) for m in bootstraps}
        exact = g <= EXACT_MAX_SCENES
        sums, counts = np.zeros((simulations, g)), np.zeros((simulations, g))
        checked: list[float] = []
        for i in range(simulations):
            a, b, groups = simulate_null(
                np.random.default_rng([seed, g, i]), g, effect_sd=effect_sd
            )
            if exact:
                sums[i], counts[i] = scene_sums(a, b, groups)
            if not exact or i < CHECKED:
                test = scene_signflip(
                    a, b, groups, rng=np.random.default_rng([seed, g, i, 0]), resamples=resamples
                )
                rejected[i] = test.p_value <= ALPHA
                if test.low is None or test.high is None:  # both None together (too few scenes)
                    covered[i] = not rejected[i]
                else:
                    covered[i] = test.low <= 0 <= test.high
                checked.append(test.p_value)
            if i >= bootstrap_simulations:
                continue
            for k, (method, clustered) in enumerate(bootstraps.items(), start=1):
                lo, hi = paired_bootstrap_ci(
                    a, b, rng=np.random.default_rng([seed, g, i, k]),
                    n_resamples=bootstrap_resamples, confidence=1 - ALPHA,
                    groups=groups if clustered else None,
                )  # fmt: skip
                boot[method][i] = (not lo <= 0 <= hi, lo <= 0 <= hi)
        if exact and simulations:
            p_zero = exact_p_values(sums, counts)
            n = len(checked)
            same_p = np.array_equal(p_zero[:n], checked)
            if not (same_p and np.array_equal(covered[:n], p_zero[:n] > ALPHA)):
                msg = f"fast p-values differ from scene_signflip at {g} scenes: {p_zero[:n]}, {checked}"
                raise RuntimeError(msg)
            rejected = p_zero <= ALPHA
            covered = ~rejected
        rows.append(_rate_row(g, "signflip", rejected, covered))
        rows.extend(_rate_row(g, m, boot[m][:, 0], boot[m][:, 1]) for m in bootstraps)
    return rows


def coverage_markdown(rows: list[dict]) -> str:
    """The rows of :func:`coverage_table` as a markdown table (one line per scene count and
    method)."""
    lines = [
        "| scenes | method | simulations | coverage of 0 | rejects 0 | interval printed |",
        "|---:|---|---:|---:|---:|---|",
    ]
    lines.extend(
        f"| {row['scenes']} | {METHODS[row['method']]} | {row['simulations']} "
        f"| {row['coverage']:.3f} ± {row['se']:.3f} | {row['rejection']:.3f} "
        f"| {'yes' if row['printed'] else 'no (too few scenes)'} |"
        for row in rows
    )
    return "\n".join(lines)


def _scenario_p_values(
    sums: np.ndarray, counts: np.ndarray, truth: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``(p(0), p(truth))`` per data set: counted at once up to :data:`EXACT_MAX_SCENES`
    scenes (the first :data:`CHECKED` data sets checked against ``signflip_p`` and
    ``signflip_interval``), else by ``signflip_p`` over one draw of random patterns a data
    set."""
    scenes = sums.shape[1]
    if scenes > EXACT_MAX_SCENES:
        p_zero, p_truth = np.empty(len(sums)), np.empty(len(sums))
        for i, (s, n, d) in enumerate(zip(sums, counts, truth, strict=True)):
            signs, exact = sign_vectors(scenes, rng=rng)
            p_zero[i] = signflip_p(s, n, 0.0, signs=signs, exact=exact)
            p_truth[i] = signflip_p(s, n, float(d), signs=signs, exact=exact)
        return p_zero, p_truth
    p_zero, p_truth = exact_p_values(sums, counts), exact_p_values(sums, counts, truth)
    signs, exact = sign_vectors(scenes, rng=rng)
    for i in range(min(CHECKED, len(sums))):
        s, n, d = sums[i], counts[i], float(truth[i])
        low, high = signflip_interval(s, n, signs=signs, exact=exact)
        public = tuple(signflip_p(s, n, x, signs=signs, exact=exact) for x in (0.0, d))
        if public != (p_zero[i], p_truth[i]) or (low <= d <= high) != (p_truth[i] > ALPHA):
            msg = (
                f"fast p-values differ from scene_test's at {scenes} scenes: "
                f"{p_zero[i]}, {p_truth[i]} against {public}, interval {low}, {high} of {d}"
            )
            raise RuntimeError(msg)
    return p_zero, p_truth


def scenario_table(
    scenarios: Sequence[str] = tuple(SCENARIOS),
    scenes: Sequence[int] = SCENARIO_SCENES,
    *,
    simulations: int = SCENARIO_SIMULATIONS,
    seed: int = 0,
) -> list[dict]:
    """The sign-flip test where it can fail: one row per scenario (a key of
    :data:`SCENARIOS`) and scene count, over ``simulations`` null data sets, with keys
    ``scenario``, ``scenes``, ``simulations``, ``effective`` (the mean Kish effective number
    of scenes), ``printed`` (the share of data sets with :data:`MIN_SCENES` effective scenes
    or more, whose interval a report prints), ``rejection`` (of ``delta = 0`` at
    :data:`ALPHA`: every rejection is false), ``coverage`` (of the data set's own
    query-weighted difference ``sum n_g e_g / sum n_g`` by the inverted set, ``p > alpha``:
    the printed interval where one is printed) and their Monte Carlo standard errors
    ``rejection_se`` and ``coverage_se``.

    Batch ``j`` (:data:`BATCH` data sets) of scenario ``k`` (its place in :data:`SCENARIOS`)
    at ``G`` scenes comes from the generator of ``(seed, k, G, j)``; random sign patterns
    (above :data:`EXACT_MAX_SCENES` scenes) from ``(seed, k, G, -1)``."""
    rows = []
    for key in scenarios:
        scenario, index = SCENARIOS[key], list(SCENARIOS).index(key)
        for g in scenes:
            parts = [
                simulate_scenario(
                    np.random.default_rng([seed, index, g, j]),
                    scenario,
                    g,
                    min(BATCH, simulations - start),
                )
                for j, start in enumerate(range(0, simulations, BATCH))
            ]
            sums, counts, effect = (np.concatenate(arrays) for arrays in zip(*parts, strict=True))
            truth = (counts * effect).sum(axis=1) / counts.sum(axis=1)
            rng = np.random.default_rng([seed, index, g, 2**32 - 1])
            p_zero, p_truth = _scenario_p_values(sums, counts, truth, rng)
            effective = np.array([effective_scenes(n) for n in counts])
            rejection = float(np.mean(p_zero <= ALPHA))
            coverage = float(np.mean(p_truth > ALPHA))
            rows.append(
                {
                    "scenario": key,
                    "scenes": g,
                    "simulations": simulations,
                    "effective": float(effective.mean()),
                    "printed": float(np.mean(effective >= MIN_SCENES - TIE_TOLERANCE)),
                    "rejection": rejection,
                    "rejection_se": math.sqrt(rejection * (1 - rejection) / simulations),
                    "coverage": coverage,
                    "coverage_se": math.sqrt(coverage * (1 - coverage) / simulations),
                }
            )
    return rows


def scenario_markdown(rows: list[dict]) -> str:
    """The rows of :func:`scenario_table` as a markdown table (one line per scenario and scene
    count), with a line on how many data sets a row holds."""
    lines = [
        "| scenario | scenes | effective scenes | rejects 0 [MC s.e.] "
        "| covers the true difference [MC s.e.] | interval printed |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    lines.extend(
        f"| {SCENARIOS[row['scenario']].label} | {row['scenes']} | {row['effective']:.1f} "
        f"| {row['rejection']:.3f} [{row['rejection_se']:.3f}] "
        f"| {row['coverage']:.3f} [{row['coverage_se']:.3f}] | {row['printed']:.0%} |"
        for row in rows
    )
    simulations = sorted({row["simulations"] for row in rows})
    lines.append(
        f"\n{' or '.join(map(str, simulations))} null data sets a row; nominal: rejects 0 at "
        f"most {ALPHA} of the time, covers at least {1 - ALPHA:.0%}; effective scenes: the "
        f"mean Kish count, (sum n)^2 / sum n^2; an interval is printed from {MIN_SCENES}."
    )
    return "\n".join(lines)


def main() -> None:
    """The command line: ``python -m care_maps.research.coverage``."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--simulations", type=int, default=SIMULATIONS)
    parser.add_argument("--bootstrap-simulations", type=int, default=BOOTSTRAP_SIMULATIONS)
    parser.add_argument("--effect-sd", type=float, default=0.0, help="scene effect (0: none)")
    parser.add_argument(
        "--scenario-simulations", type=int, default=SCENARIO_SIMULATIONS,
        help="data sets a row of the scenario table (0: no scenario table)",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    start = time.perf_counter()
    rows = coverage_table(
        simulations=args.simulations,
        bootstrap_simulations=args.bootstrap_simulations,
        seed=args.seed,
        effect_sd=args.effect_sd,
    )
    print(coverage_markdown(rows))
    print(
        f"\nnominal 95% (alpha {ALPHA}); sign-flip from {MIN_SCENES} scenes; "
        f"effect_sd {args.effect_sd}; ± one Monte Carlo s.e. of a 95% coverage; "
        f"{time.perf_counter() - start:.0f} s"
    )
    if args.scenario_simulations > 0:
        start = time.perf_counter()
        table = scenario_table(simulations=args.scenario_simulations, seed=args.seed)
        print("\n" + scenario_markdown(table))
        print(f"\n{time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
