"""A scene-level test of a paired difference that stays valid with few scenes: the sign-flip
(randomisation) test over scenes, and its interval by test inversion. Pure functions of
arrays, no I/O.

Queries of one scene are not independent (one map, one layout, one perception run), so the
unit of replication is the scene. The scene-clustered percentile bootstrap of
:func:`care_maps.evaluate.paired.paired_bootstrap_ci` treats the scenes as the population, but with a
handful of them its interval is far too narrow: in the null simulation of
``care_maps/research/coverage.py`` it leaves out zero in about 20% of runs with 4 scenes and 28% with
2, at a nominal 5%.
The sign-flip test needs only that each scene's summed difference be symmetric about zero
under the null, and is exact in finite samples: its level never exceeds ``alpha``, however
few the scenes (with too few it simply cannot reject).

Per scene ``g``: ``S_g`` is the sum over its queries of ``a - b`` (fractions allowed: a
strategy averaged over seeds) and ``n_g`` its query count. The estimate is
``delta_hat = sum S_g / sum n_g``, the query-weighted difference in success rate (the
figure the paired table prints). The test of ``H0: delta = d`` takes
``z_g = S_g - d * n_g`` and the statistic ``T = |sum z_g|``; under ``H0`` every sign pattern
``s`` of the scenes is as likely as the observed one, so ``T`` is compared with
``T*(s) = |sum s_g z_g|``:

- ``G <= EXACT_MAX_SCENES``: all ``2^G`` patterns, ``p = #{T* >= T} / 2^G`` (the observed
  pattern counted once, as one of the ``2^G``);
- otherwise ``B`` patterns drawn uniformly from the given generator and
  ``p = (1 + #{T* >= T}) / (1 + B)``, which keeps ``P(p <= alpha) <= alpha`` over the
  draws.

``>=`` has a tolerance (floating ties between patterns that are equal in exact arithmetic
count as ties). With ``G`` scenes the smallest exact p-value is ``2 / 2^G`` (the observed
pattern and its mirror image), so below :data:`MIN_SCENES` (6 at 0.05) the test cannot
reject at all and the report prints "too few scenes" instead of an interval. Scenes of very
unequal sizes count for less: the rule is on the Kish effective number of scenes,
``(sum n_g)^2 / sum n_g^2`` (:func:`effective_scenes`), as one scene of 200 queries beside
seven of 10 dominates every sign pattern's sum (its p-value is 1 whatever the others say).
The smallest attainable p-value is reported with every test (:attr:`SceneTest.min_p`), so a
family of comparisons too large for its scenes says that it cannot reject instead of
printing p-values that could never pass its correction. A Monte Carlo p-value comes with its
standard error (:attr:`SceneTest.mc_error`).

"Does as well" is a claim of its own: the two one-sided sign-flip tests (TOST) of
``delta <= -m`` and ``delta >= m`` at the margin ``m`` = :data:`EQUIVALENCE_MARGIN`, fixed
before any result; their larger p-value (:attr:`SceneTest.equivalence_p`) at or below
``alpha`` shows the difference lies within the margin. One-sided, the smallest exact
p-value is ``1 / 2^G``. Non-significance alone shows nothing of the kind.

The 95% interval is the set of ``d`` the test does not reject, within ``[-1, 1]`` (a
difference in success rates). It is computed exactly, not by bisection: for one pattern,
with ``P`` its scenes kept and ``M`` its scenes flipped, ``T*(s) >= T`` reads
``((S_s - S) - d (N_s - N)) ((S_s + S) - d (N_s + N)) >= 0`` (``S_s``, ``N_s`` the sums of
``s_g S_g`` and ``s_g n_g``; ``S``, ``N`` the plain ones), a concave quadratic in ``d``
(``|N_s| <= N``) whose roots are the pooled differences of the two halves, ``delta_P`` and
``delta_M``. So
pattern ``s`` counts exactly when ``d`` lies between ``delta_P`` and ``delta_M`` (the whole
line for the all-plus and all-minus patterns), an interval that always holds
``delta_hat`` (their weighted mean). Hence ``p(d)`` falls monotonically on each side of
``delta_hat``, the accepted set is one interval, and its ends are order statistics: the
upper end is the ``k``-th largest ``max(delta_P, delta_M)`` over the patterns, the lower the
``k``-th smallest ``min(delta_P, delta_M)``, where ``k`` is the fewest counted patterns
whose p-value exceeds ``alpha``. The same patterns serve every ``d``, so ``p(d)`` is one
consistent function; a bisection of :func:`signflip_p` finds the same ends (the tests check
it).

Coverage: where the scene-level ``z_g`` are independent and symmetric about 0 under
``H0: delta = d`` (exchangeable strategies within each scene, or a scene effect symmetric
about the common difference), the interval covers ``d`` with probability at least 95%,
conservatively so by the discreteness of the sign-flip distribution (ties, few scenes). The
test of zero (the p-value reported) is exact when the two strategies are exchangeable within
every scene. For a non-zero ``d`` and 0/1 outcomes the scene sums are symmetric about
``d * n_g`` only approximately (a binary difference with a non-zero mean is skewed), so the
interval's coverage away from zero is close to, not guaranteed at, 95%.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

__all__ = [
    "ALPHA",
    "EQUIVALENCE_MARGIN",
    "EXACT_MAX_SCENES",
    "MIN_SCENES",
    "N_SIGN_FLIPS",
    "SceneTest",
    "effective_scenes",
    "equivalence_p",
    "min_scenes",
    "scene_signflip",
    "scene_sums",
    "scenes_for_family",
    "sign_vectors",
    "signflip_interval",
    "signflip_p",
    "smallest_p",
]

ALPHA = 0.05
"""Level of the test; the interval is its inversion (``1 - ALPHA`` = 95%)."""
EXACT_MAX_SCENES = 20
"""Up to this many scenes every sign pattern is enumerated (2^20 = 1,048,576: a few tens of
milliseconds a comparison, by the doubling of :func:`_kept_sums`)."""
N_SIGN_FLIPS = 100_000
"""Random sign patterns drawn above :data:`EXACT_MAX_SCENES` scenes: the p-value's Monte
Carlo standard error is at most 0.0016, 0.0007 near 0.05."""
EQUIVALENCE_MARGIN = 0.03
"""The equivalence margin, in success rate (3 points), fixed before any result: a difference
shown to lie within +-3 points is "no difference that matters"; one not shown to is only
"not shown to differ"."""
TIE_TOLERANCE = 1e-9
"""``T* >= T - TIE_TOLERANCE * N`` (``N`` the query count, which bounds ``|T|``): a tie in
exact arithmetic stays a tie in floating point."""


def min_scenes(alpha: float = ALPHA) -> int:
    """The fewest scenes at which the exact sign-flip test can reject at ``alpha``: the
    smallest ``G`` with ``2 / 2^G <= alpha`` (the observed pattern and its mirror always
    reach the observed statistic)."""
    if not 0 < alpha < 1:
        msg = f"alpha must lie in (0, 1), got {alpha}"
        raise ValueError(msg)
    g = 1
    while 2.0 / 2.0**g > alpha:
        g += 1
    return g


MIN_SCENES = min_scenes()
"""Fewest effective scenes (:func:`effective_scenes`) at which the interval is reported at
:data:`ALPHA` (6 at 0.05)."""


def scenes_for_family(size: int, alpha: float = ALPHA) -> int:
    """The fewest scenes at which a family of ``size`` two-sided sign-flip tests can reject
    anything under Holm (or Bonferroni): the smallest ``G`` with ``2 / 2^G <= alpha / size``
    (6 for one test at 0.05, 11 for 45)."""
    return min_scenes(alpha / max(int(size), 1))


def effective_scenes(counts: np.ndarray) -> float:
    """Kish's effective number of scenes, ``(sum n_g)^2 / sum n_g^2``: the scene count for
    equal sizes, fewer the more one scene dominates (0 without a query)."""
    n = np.asarray(counts, np.float64)
    square = float(np.sum(n * n))
    return float(np.sum(n)) ** 2 / square if square > 0 else 0.0


def smallest_p(scenes: int, patterns: int, exact: bool, *, sided: int = 2) -> float:
    """The smallest p-value a sign-flip test over ``scenes`` scenes can give: ``2 / 2^G``
    two-sided (the observed pattern and its mirror), ``1 / 2^G`` one-sided; with ``patterns``
    random patterns no less than ``1 / (1 + patterns)`` either."""
    if scenes < 1:
        return 1.0
    floor = sided / 2.0**scenes
    return float(floor if exact else max(floor, 1.0 / (1 + patterns)))


@dataclass(frozen=True)
class SceneTest:
    """The sign-flip test of strategy ``a`` against ``b`` over ``scenes`` scenes."""

    estimate: float
    """``sum S_g / sum n_g``: the query-weighted difference in success (``mean(a - b)``)."""
    low: float | None
    high: float | None
    """The interval by test inversion (clipped to ``[-1, 1]``); None below
    :func:`min_scenes` scenes, where the test cannot reject and no interval is informative."""
    p_value: float
    """Two-sided p-value of ``delta = 0``."""
    scenes: int
    exact: bool
    """All ``2^G`` sign patterns enumerated (else ``resamples`` random ones)."""
    effective: float = 0.0
    """Kish's effective number of scenes (:func:`effective_scenes`), which the interval's
    rule counts."""
    min_p: float = 1.0
    """The smallest two-sided p-value this many scenes and patterns can give
    (:func:`smallest_p`)."""
    mc_error: float = 0.0
    """Monte Carlo standard error of ``p_value`` (0 when exact)."""
    equivalence_p: float = float("nan")
    """p-value of the equivalence test within +-:data:`EQUIVALENCE_MARGIN` (TOST, the larger
    of the two one-sided sign-flip p-values)."""


def scene_sums(a: np.ndarray, b: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per scene (in the sorted order of ``groups``): ``S_g``, the sum of ``a - b`` over its
    queries, and ``n_g``, its query count. Pairs with a NaN side are left out (no outcome
    known), as in :func:`care_maps.evaluate.paired.compare_measure`; outcomes must lie in ``[0, 1]``
    (success, or a success rate averaged over seeds)."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    groups = np.asarray(groups)
    if a.shape != b.shape or a.shape != groups.shape or a.ndim != 1:
        msg = f"scene test needs aligned 1-d queries, got {a.shape}, {b.shape}, {groups.shape}"
        raise ValueError(msg)
    keep = ~(np.isnan(a) | np.isnan(b))
    a, b, groups = a[keep], b[keep], groups[keep]
    if np.any((a < 0) | (a > 1) | (b < 0) | (b > 1)):
        msg = "scene test needs outcomes in [0, 1] (success or a rate over seeds)"
        raise ValueError(msg)
    if not len(a):
        return np.zeros(0), np.zeros(0)
    _, group = np.unique(groups, return_inverse=True)
    sums = np.bincount(group, weights=a - b)
    counts = np.bincount(group).astype(np.float64)
    return sums, counts


@functools.cache
def _all_patterns(scenes: int) -> np.ndarray:
    """Every sign pattern of ``scenes`` scenes, one per row: bit ``g`` of the row index set
    means scene ``g`` flipped (row 0 is all plus)."""
    bits = (np.arange(2**scenes)[:, None] >> np.arange(scenes)) & 1
    signs = (1 - 2 * bits).astype(np.int8)
    signs.setflags(write=False)
    return signs


def sign_vectors(
    scenes: int, *, rng: np.random.Generator, resamples: int = N_SIGN_FLIPS
) -> tuple[np.ndarray, bool]:
    """The sign patterns the test compares with, ``(signs, exact)``: ``signs`` is an int8
    array of +-1 with one row per pattern. All ``2^scenes`` of them (``exact``, ``rng``
    untouched) up to :data:`EXACT_MAX_SCENES` scenes, else ``resamples`` uniform draws."""
    if scenes <= EXACT_MAX_SCENES:
        return _all_patterns(scenes), True
    if resamples < 1:
        msg = f"need at least one random sign pattern, got {resamples}"
        raise ValueError(msg)
    # fair bits from random bytes (several times faster than rng.integers(0, 2));
    # laid out scene-major, so that :func:`_kept_sums` walks contiguous rows
    size = resamples * scenes
    bits = np.unpackbits(np.frombuffer(rng.bytes(-(-size // 8)), np.uint8), count=size)
    return (1 - 2 * bits.view(np.int8)).reshape(scenes, resamples).T, False


def _p_of_count(count: int | np.integer, patterns: int, exact: bool) -> float:
    """The p-value of ``count`` patterns reaching the observed statistic."""
    return float(count / patterns if exact else (1 + count) / (1 + patterns))


def _fewest_kept(patterns: int, exact: bool, alpha: float) -> int:
    """The fewest patterns reaching the statistic at which ``d`` is kept (p > alpha)."""
    count = max(int(alpha * patterns) if exact else int(alpha * (1 + patterns)) - 1, 0)
    while _p_of_count(count, patterns, exact) <= alpha:  # at most a step or two
        count += 1
    return count


def _kept_sums(
    signs: np.ndarray, sums: np.ndarray, counts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per pattern, the sum of ``S_g`` and the sum of ``n_g`` over its kept (plus) scenes;
    every signed sum follows (``sum s_g x_g = 2 kept - total``).

    No BLAS: a tall, two-column product runs slower on BLAS threads than on one core when
    the machine is busy. All ``2^G`` patterns (:func:`_all_patterns`) are built by doubling,
    ``O(2^G)``; other patterns by one pass per scene."""
    if len(sums) <= EXACT_MAX_SCENES and signs is _all_patterns(len(sums)):
        kept_s, kept_n = np.zeros(1), np.zeros(1)
        for s, n in zip(sums, counts, strict=True):  # bit g of the row index: scene g flipped
            kept_s = np.concatenate([kept_s + s, kept_s])
            kept_n = np.concatenate([kept_n + n, kept_n])
        return kept_s, kept_n
    plus = np.ascontiguousarray(np.asarray(signs).T > 0)
    kept_s, kept_n = np.zeros(plus.shape[1]), np.zeros(plus.shape[1])
    for row, s, n in zip(plus, sums, counts, strict=True):
        kept_s += row * s
        kept_n += row * n
    return kept_s, kept_n


def _check(sums: np.ndarray, counts: np.ndarray, signs: np.ndarray) -> None:
    if sums.shape != counts.shape or signs.ndim != 2 or signs.shape[1] != len(sums):
        msg = (
            f"scene test needs one sum and count per scene and one column per scene, got "
            f"{sums.shape}, {counts.shape}, {signs.shape}"
        )
        raise ValueError(msg)


def _p_from_kept(
    kept: tuple[np.ndarray, np.ndarray],
    total_s: float,
    total_n: float,
    d: float,
    exact: bool,
    *,
    side: int = 0,
) -> float:
    """p-value of ``delta = d``: two-sided (``side`` 0, ``|T*| >= |T|``), or one-sided
    against ``delta > d`` (``side`` +1, ``T* >= T``) or ``delta < d`` (-1, ``T* <= T``)."""
    kept_s, kept_n = kept
    observed = total_s - d * total_n
    flipped = (2 * kept_s - total_s) - d * (2 * kept_n - total_n)
    if side == 0:
        observed, flipped = abs(observed), np.abs(flipped)
    elif side < 0:
        observed, flipped = -observed, -flipped
    hits = np.count_nonzero(flipped >= observed - TIE_TOLERANCE * max(total_n, 1.0))
    return _p_of_count(hits, len(kept_s), exact)


def _equivalence_from_kept(
    kept: tuple[np.ndarray, np.ndarray],
    total_s: float,
    total_n: float,
    exact: bool,
    margin: float,
) -> float:
    """TOST: the larger of the one-sided p-values of ``delta <= -margin`` (against larger)
    and ``delta >= margin`` (against smaller)."""
    above = _p_from_kept(kept, total_s, total_n, -margin, exact, side=1)
    below = _p_from_kept(kept, total_s, total_n, margin, exact, side=-1)
    return max(above, below)


def _prepared(
    sums: np.ndarray, counts: np.ndarray, signs: np.ndarray
) -> tuple[tuple[np.ndarray, np.ndarray], float, float] | None:
    """The kept pattern sums and the observed totals of checked scene ``sums`` and
    ``counts``; None without a scene."""
    sums = np.asarray(sums, np.float64)
    counts = np.asarray(counts, np.float64)
    _check(sums, counts, signs)
    if not len(sums):
        return None
    return _kept_sums(signs, sums, counts), float(sums.sum()), float(counts.sum())


def equivalence_p(
    sums: np.ndarray,
    counts: np.ndarray,
    margin: float = EQUIVALENCE_MARGIN,
    *,
    signs: np.ndarray,
    exact: bool,
) -> float:
    """p-value of the equivalence test ``|delta| < margin`` (two one-sided sign-flip tests,
    the larger p); NaN without a scene."""
    ready = _prepared(sums, counts, signs)
    return float("nan") if ready is None else _equivalence_from_kept(*ready, exact, margin)


def signflip_p(
    sums: np.ndarray, counts: np.ndarray, d: float = 0.0, *, signs: np.ndarray, exact: bool
) -> float:
    """Two-sided sign-flip p-value of ``H0: delta = d`` from the per-scene ``sums`` and
    ``counts`` (:func:`scene_sums`) against the patterns ``signs`` (:func:`sign_vectors`):
    ``#{T* >= T} / 2^G`` when ``exact``, else ``(1 + #{T* >= T}) / (1 + B)``. NaN without a
    scene."""
    ready = _prepared(sums, counts, signs)
    return float("nan") if ready is None else _p_from_kept(*ready, d, exact)


def _interval_from_kept(
    kept: tuple[np.ndarray, np.ndarray], total_s: float, total_n: float, exact: bool, alpha: float
) -> tuple[float, float]:
    kept_s, kept_n = kept
    k = _fewest_kept(len(kept_s), exact, alpha)
    if k == 0:
        return -1.0, 1.0
    flip_n = total_n - kept_n
    whole = (kept_n == 0) | (flip_n == 0)  # all plus or all minus: T* = T for every d
    with np.errstate(divide="ignore", invalid="ignore"):
        d_kept = kept_s / kept_n
        d_flip = (total_s - kept_s) / flip_n
    upper = np.maximum(d_kept, d_flip)
    lower = np.minimum(d_kept, d_flip)
    upper[whole] = np.inf
    lower[whole] = -np.inf
    high = -np.partition(-upper, k - 1)[k - 1]
    low = np.partition(lower, k - 1)[k - 1]
    estimate = total_s / total_n  # inside every pattern's range; guards rounding
    return float(max(min(low, estimate), -1.0)), float(min(max(high, estimate), 1.0))


def signflip_interval(
    sums: np.ndarray,
    counts: np.ndarray,
    *,
    signs: np.ndarray,
    exact: bool,
    alpha: float = ALPHA,
) -> tuple[float, float]:
    """The set of ``d`` in ``[-1, 1]`` whose :func:`signflip_p` (same ``signs``) exceeds
    ``alpha``, as ``(low, high)``: exact order statistics of the patterns' half-sample
    differences (module docstring), not a search. ``(-1, 1)`` where no p-value can reach
    ``alpha`` (too few scenes or patterns); ``(nan, nan)`` without a scene."""
    ready = _prepared(sums, counts, signs)
    return (
        (float("nan"), float("nan")) if ready is None else _interval_from_kept(*ready, exact, alpha)
    )


def scene_signflip(
    a: np.ndarray,
    b: np.ndarray,
    groups: np.ndarray,
    *,
    rng: np.random.Generator,
    alpha: float = ALPHA,
    resamples: int = N_SIGN_FLIPS,
) -> SceneTest:
    """The scene-level sign-flip test of ``mean(a - b) = 0`` and its ``1 - alpha`` interval.

    ``a``, ``b``: per-query outcomes in ``[0, 1]`` (aligned; fractions where a strategy is
    averaged over seeds); ``groups``: the scene of each query; ``rng``: the comparison's
    generator (:func:`care_maps.evaluate.paired.comparison_rng`), drawn from only above
    :data:`EXACT_MAX_SCENES` scenes. The interval is None below :func:`min_scenes` effective
    scenes (``alpha``'s, :data:`MIN_SCENES` at 0.05; :func:`effective_scenes`); the p-value
    is always given, with the smallest one attainable and, drawn at random, its Monte Carlo
    error; so is the equivalence test's within :data:`EQUIVALENCE_MARGIN`. Without a query:
    NaN estimate and p-values, no interval.
    """
    sums, counts = scene_sums(a, b, groups)
    scenes = len(sums)
    if not scenes:
        return SceneTest(float("nan"), None, None, float("nan"), 0, True)
    signs, exact = sign_vectors(scenes, rng=rng, resamples=resamples)
    kept = _kept_sums(signs, sums, counts)
    total_s, total_n = float(sums.sum()), float(counts.sum())
    p_value = _p_from_kept(kept, total_s, total_n, 0.0, exact)
    effective = effective_scenes(counts)
    low = high = None
    if effective >= min_scenes(alpha) - TIE_TOLERANCE:
        low, high = _interval_from_kept(kept, total_s, total_n, exact, alpha)
    patterns = len(kept[0])
    return SceneTest(
        estimate=total_s / total_n,
        low=low,
        high=high,
        p_value=p_value,
        scenes=scenes,
        exact=exact,
        effective=effective,
        min_p=smallest_p(scenes, patterns, exact),
        mc_error=0.0 if exact else float(np.sqrt(p_value * (1 - p_value) / patterns)),
        equivalence_p=_equivalence_from_kept(kept, total_s, total_n, exact, EQUIVALENCE_MARGIN),
    )
