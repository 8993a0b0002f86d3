"""Paired comparison of two strategies over the same queries: difference in success with a
paired bootstrap interval, and the exact McNemar test. Pure functions of arrays, no I/O.

"Does CARe beat max confidence" is a paired question: both answer the same queries, and
most queries come out the same under both (in particular every query solved by the first
attempt, which all strategies share). Two separate intervals cannot see that; the interval
of the per-query difference can, and McNemar's test uses only the discordant queries.

Design for reuse: every function takes the per-query outcomes ``a`` and ``b`` (aligned
arrays, 1 = success; fractions where a random strategy is averaged over seeds) and an
optional ``groups`` array (the scene of each query): with it the interval treats scenes as
the units, by the scene-level sign-flip test of :mod:`care_maps.evaluate.scene_test`, which holds with
few scenes where a bootstrap over them does not (:func:`paired_interval`); every random draw
comes from the generator built by :func:`comparison_rng` from the base seed and the
comparison's own name, so an interval does not depend on what else was compared or in what
order. :func:`holm` adjusts a family of p-values.

A continuous paired measure (SPL, :mod:`care_maps.evaluate.spl`) gets :func:`compare_measure`: the same
paired bootstrap interval of the mean difference, and the Wilcoxon signed-rank test
(``scipy.stats.wilcoxon``) on the non-zero differences, as McNemar uses only the discordant
queries (every query both rules solve with the same walk ties at zero).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from care_maps.evaluate.scene_test import N_SIGN_FLIPS, SceneTest, scene_signflip

__all__ = [
    "PairedComparison",
    "PairedMeasure",
    "compare",
    "compare_measure",
    "comparison_rng",
    "holm",
    "mcnemar_exact",
    "paired_bootstrap_ci",
    "paired_interval",
    "wilcoxon_signed_rank",
]


def comparison_rng(seed: int, *name: object) -> np.random.Generator:
    """The generator of one comparison: a function of the base seed and the comparison's
    name alone (never shared between comparisons)."""
    key = zlib.crc32("\x1f".join(map(str, name)).encode())
    return np.random.default_rng(np.random.SeedSequence([int(seed), key]))


def mcnemar_exact(b: int, c: int) -> float:
    """Two-sided exact McNemar p-value from the discordant counts ``b`` (only the first
    succeeded) and ``c`` (only the second): a binomial test of ``min(b, c)`` in ``b + c``
    trials at 1/2, doubled and capped at 1 (1.0 when there is no discordant query)."""
    from scipy.stats import binom

    n = int(b) + int(c)
    if n == 0:
        return 1.0
    return float(min(1.0, 2.0 * binom.cdf(min(int(b), int(c)), n, 0.5)))


N_RESAMPLES = 10_000
"""Bootstrap resamples of a paired interval."""
CONFIDENCE = 0.95
"""Coverage of a paired interval."""


def paired_bootstrap_ci(
    a: np.ndarray,
    b: np.ndarray,
    *,
    rng: np.random.Generator,
    n_resamples: int = N_RESAMPLES,
    confidence: float = CONFIDENCE,
    groups: np.ndarray | None = None,
) -> tuple[float, float]:
    """Percentile bootstrap interval of ``mean(a - b)``, resampling queries as pairs.

    Without ``groups`` this is ``scipy.stats.bootstrap`` with ``paired=True``; with
    ``groups`` whole groups are resampled (a clustered bootstrap: queries of one scene are
    not independent). The percentile method keeps a degenerate sample (every difference
    the same, common when two strategies agree on every query) a point interval instead
    of BCa's NaN. ``(nan, nan)`` for fewer than two queries (or groups) or
    ``n_resamples <= 0``: one observation has no sampling distribution to estimate.
    """
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    n_units = len(a) if groups is None else len(np.unique(np.asarray(groups)))
    if n_units < 2 or n_resamples <= 0:
        return float("nan"), float("nan")
    if groups is None:
        from scipy.stats import bootstrap

        res = bootstrap(
            (a, b),
            lambda x, y, axis: np.mean(x - y, axis=axis),
            paired=True,
            vectorized=True,
            n_resamples=n_resamples,
            confidence_level=confidence,
            method="percentile",
            random_state=rng,
        )
        return float(res.confidence_interval.low), float(res.confidence_interval.high)
    _, group = np.unique(np.asarray(groups), return_inverse=True)
    n_groups = int(group.max()) + 1
    sums = np.bincount(group, weights=a - b, minlength=n_groups)
    counts = np.bincount(group, minlength=n_groups).astype(np.float64)
    draws = rng.integers(0, n_groups, (n_resamples, n_groups))
    stats = sums[draws].sum(axis=1) / counts[draws].sum(axis=1)
    alpha = (1 - confidence) / 2
    lo, hi = np.percentile(stats, [100 * alpha, 100 * (1 - alpha)])
    return float(lo), float(hi)


@dataclass(frozen=True)
class PairedComparison:
    """Strategy ``a`` against ``b`` over the same ``n`` queries."""

    n: int
    rate_a: float
    """Success of ``a`` (fraction of queries; seeds averaged for random strategies)."""
    rate_b: float
    diff: float
    """``rate_a - rate_b``: the mean per-query difference."""
    lo: float
    hi: float
    """95% interval of ``diff`` (:func:`paired_interval`); NaN where it does not hold (fewer
    than :data:`care_maps.evaluate.scene_test.MIN_SCENES` scenes)."""
    only_a: float
    """Queries only ``a`` solved (McNemar's b; fractional when a side is seed-averaged)."""
    only_b: float
    both: float
    neither: float
    first_ties: int
    """Queries both solved at the first attempt (they share it): ties by construction."""
    p_value: float
    """Exact McNemar p-value; NaN when a side is not 0/1 per query (seed-averaged)."""
    scene_p: float = float("nan")
    """Scene-level sign-flip p-value (:mod:`care_maps.evaluate.scene_test`); NaN without ``groups``."""
    scenes: int = 0
    """Scenes (groups) compared; 0 without ``groups``."""
    scene: SceneTest | None = None
    """The whole scene-level test (its smallest attainable p, Monte Carlo error, effective
    scenes and equivalence p-value); None without ``groups``."""


def compare(
    a: np.ndarray,
    b: np.ndarray,
    *,
    rng: np.random.Generator,
    first_a: np.ndarray | None = None,
    first_b: np.ndarray | None = None,
    n_resamples: int = N_RESAMPLES,
    confidence: float = CONFIDENCE,
    groups: np.ndarray | None = None,
) -> PairedComparison:
    """Everything the paired table reports for one comparison. ``first_a``/``first_b``:
    per-query success of each side's first attempt (for the tie count)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.shape != b.shape:
        msg = f"paired comparison needs aligned queries, got {a.shape} and {b.shape}"
        raise ValueError(msg)
    lo, hi, scene = _interval(
        a, b, rng=rng, n_resamples=n_resamples, confidence=confidence, groups=groups
    )
    binary = bool(np.isin(a, (0.0, 1.0)).all() and np.isin(b, (0.0, 1.0)).all())
    only_a = float(np.sum(a * (1 - b)))
    only_b = float(np.sum(b * (1 - a)))
    ties = 0
    if first_a is not None and first_b is not None:
        ties = int(np.sum(np.asarray(first_a, bool) & np.asarray(first_b, bool)))
    return PairedComparison(
        n=len(a),
        rate_a=float(a.mean()) if len(a) else float("nan"),
        rate_b=float(b.mean()) if len(b) else float("nan"),
        diff=float(np.mean(a - b)) if len(a) else float("nan"),
        lo=lo,
        hi=hi,
        only_a=only_a,
        only_b=only_b,
        both=float(np.sum(a * b)),
        neither=float(np.sum((1 - a) * (1 - b))),
        first_ties=ties,
        p_value=mcnemar_exact(round(only_a), round(only_b)) if binary else float("nan"),
        scene_p=float("nan") if scene is None else scene.p_value,
        scenes=0 if scene is None else scene.scenes,
        scene=scene,
    )


def paired_interval(
    a: np.ndarray,
    b: np.ndarray,
    *,
    rng: np.random.Generator,
    n_resamples: int = N_RESAMPLES,
    confidence: float = CONFIDENCE,
    groups: np.ndarray | None = None,
) -> tuple[float, float, float, int]:
    """``(lo, hi, scene_p, scenes)``: the interval of ``mean(a - b)`` a report prints.

    With ``groups`` (the scene of each query: queries of one scene share a map and are not
    independent) the scene-level sign-flip test and its inverted interval
    (:func:`care_maps.evaluate.scene_test.scene_signflip`), which hold with few scenes; below
    :data:`care_maps.evaluate.scene_test.MIN_SCENES` scenes the interval is ``(nan, nan)``, as the
    test cannot reject there. Without ``groups`` the queries are the units: the paired
    percentile bootstrap, no scene p-value (NaN) and 0 scenes. ``n_resamples``: bootstrap
    resamples (the scene test enumerates every sign pattern up to
    :data:`care_maps.evaluate.scene_test.EXACT_MAX_SCENES` scenes, else draws
    :data:`care_maps.evaluate.scene_test.N_SIGN_FLIPS`); 0: no interval.
    """
    lo, hi, scene = _interval(
        a, b, rng=rng, n_resamples=n_resamples, confidence=confidence, groups=groups
    )
    if scene is None:
        scenes = 0 if groups is None else len(np.unique(np.asarray(groups)))
        return lo, hi, float("nan"), scenes
    return lo, hi, scene.p_value, scene.scenes


def _interval(
    a: np.ndarray,
    b: np.ndarray,
    *,
    rng: np.random.Generator,
    n_resamples: int,
    confidence: float,
    groups: np.ndarray | None,
) -> tuple[float, float, SceneTest | None]:
    """:func:`paired_interval`'s interval and, with ``groups``, the whole scene test."""
    if groups is None:
        lo, hi = paired_bootstrap_ci(a, b, rng=rng, n_resamples=n_resamples, confidence=confidence)
        return lo, hi, None
    if n_resamples <= 0:
        return float("nan"), float("nan"), None
    test = scene_signflip(
        a, b, np.asarray(groups), rng=rng, alpha=1 - confidence, resamples=N_SIGN_FLIPS
    )
    if test.low is None or test.high is None:
        return float("nan"), float("nan"), test
    return float(test.low), float(test.high), test


def holm(p_values: np.ndarray) -> np.ndarray:
    """Holm-Bonferroni adjusted p-values of one family (NaN stays NaN and is not counted)."""
    p = np.asarray(p_values, np.float64)
    out = np.full(p.shape, np.nan)
    ok = np.flatnonzero(~np.isnan(p))
    order = ok[np.argsort(p[ok], kind="stable")]
    m = len(order)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return out


def wilcoxon_signed_rank(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sided Wilcoxon signed-rank p-value of ``a - b`` (``scipy.stats.wilcoxon`` with
    ``zero_method="wilcox"``: zero differences dropped; the exact null distribution where
    scipy uses it, the normal approximation with a tie correction otherwise); 1.0 when no
    difference is non-zero, NaN without a pair."""
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    d = d[~np.isnan(d)]
    if len(d) == 0:
        return float("nan")
    if not np.any(d != 0):
        return 1.0
    from scipy.stats import wilcoxon

    return float(wilcoxon(d, zero_method="wilcox", alternative="two-sided").pvalue)


@dataclass(frozen=True)
class PairedMeasure:
    """A continuous measure of rule ``a`` against ``b`` over the same ``n`` queries."""

    n: int
    mean_a: float
    mean_b: float
    diff: float
    """``mean_a - mean_b``: the mean per-query difference."""
    lo: float
    hi: float
    """95% interval of ``diff`` (:func:`paired_interval`)."""
    better: int
    """Queries where ``a`` scored higher."""
    worse: int
    p_value: float
    """Wilcoxon signed-rank p-value (:func:`wilcoxon_signed_rank`)."""
    scene_p: float = float("nan")
    """Scene-level sign-flip p-value; NaN without ``groups``."""
    scenes: int = 0


def compare_measure(
    a: np.ndarray,
    b: np.ndarray,
    *,
    rng: np.random.Generator,
    n_resamples: int = N_RESAMPLES,
    confidence: float = CONFIDENCE,
    groups: np.ndarray | None = None,
) -> PairedMeasure:
    """Everything a paired table reports for a continuous measure; pairs with a NaN side
    (no travel known) are left out."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.shape != b.shape:
        msg = f"paired comparison needs aligned queries, got {a.shape} and {b.shape}"
        raise ValueError(msg)
    keep = ~(np.isnan(a) | np.isnan(b))
    a, b = a[keep], b[keep]
    lo, hi, scene_p, scenes = paired_interval(
        a, b, rng=rng, n_resamples=n_resamples, confidence=confidence,
        groups=None if groups is None else np.asarray(groups)[keep],
    )  # fmt: skip
    empty = len(a) == 0
    return PairedMeasure(
        n=len(a),
        mean_a=float("nan") if empty else float(a.mean()),
        mean_b=float("nan") if empty else float(b.mean()),
        diff=float("nan") if empty else float(np.mean(a - b)),
        lo=lo,
        hi=hi,
        better=int(np.sum(a > b)),
        worse=int(np.sum(a < b)),
        p_value=wilcoxon_signed_rank(a, b),
        scene_p=scene_p,
        scenes=scenes,
    )
