"""The replan strategies of ``docs/method.md``, each a small rule over precomputed columns.

Every rule works on a batch of Q queries over the N candidates of one map at once: it sees the
(Q, N) confidence, which candidates are still *available* (unvisited and not excluded), the
*candidate set* of the selection criterion, and the per-candidate measure columns, and returns
one candidate per query. Ties break by higher confidence, then lower id. A rule over an empty
candidate set falls back to the max-confidence rule and says so (``Pick.fell_back``).

Selection criteria (:data:`CRITERIA`), among available candidates:

- ``confidence``: the k candidates of highest confidence. After a failed first attempt this is
  ranks 2..k+1, as in the authors' code;
- ``category``: every candidate whose k highest classes contain the target class.

Travel (:attr:`Situation.distance`, metres from where the robot stands to each candidate's
goal) adds a non-CARe baseline and a distance-aware variant of each CARe rule:

- ``nearest_topk``: the nearest reachable candidate of the set (what a roboticist tries first);
- ``max_entropy_near``, ``min_stderr_near``, ``min_pwkl_near``: the CARe rule traded against
  travel by one rule (:func:`travel_score`): each set member scores
  ``rank / (|S| - 1) + TRAVEL_WEIGHT * d / d_max``, its rank under the CARe rule (0: the
  rule's own pick) and its distance over the farthest reachable member's; the lowest wins.

An unreachable candidate (``inf``) is chosen only where no member of the set is reachable
(then by confidence; that attempt cannot be walked). Without distances (``None``: an
evaluated scene with no free space) every distance counts the same: ``nearest_topk`` is the
most confident member of the set and each ``*_near`` rule its CARe rule. ``care replan``
gives them the distances from ``--from`` (:func:`care_maps.replan.attempts.next_goal` refuses a travel
rule without them), and a batch, which walks no attempt, does not list them.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from typing import cast

import numpy as np

from care_maps.core.errors import ReplanError

__all__ = [
    "CRITERIA",
    "STRATEGIES",
    "TRAVEL_WEIGHT",
    "Criterion",
    "Pick",
    "Situation",
    "Strategy",
    "StrategyName",
    "best_of",
    "candidate_set",
    "get_strategy",
    "topk_category",
    "topk_confidence",
    "travel_score",
    "uniform_of",
]

TRAVEL_WEIGHT = 1.0
"""Weight of travel in the distance-aware rules (:func:`travel_score`): at 1 the rule's own
pick at the farthest reachable distance ties with its last-ranked member next to the robot."""


class StrategyName(StrEnum):
    """The registered replan strategies (:data:`STRATEGIES` has one :class:`Strategy` each,
    in the paper's row order). A new strategy is a member here and an entry there."""

    NO_REPLAN = "no_replan"
    ORACLE = "oracle"
    MAX_CONFIDENCE = "max_confidence"
    RANDOM = "random"
    RANDOM_TOPK = "random_topk"
    MAX_ENTROPY = "max_entropy"
    MIN_STDERR = "min_stderr"
    MIN_PWKL = "min_pwkl"
    MIN_ENTROPY = "min_entropy"
    MAX_PWKL = "max_pwkl"
    LARGEST = "largest"
    MOST_VIEWS = "most_views"
    NEAREST_TOPK = "nearest_topk"
    MAX_ENTROPY_NEAR = "max_entropy_near"
    MIN_STDERR_NEAR = "min_stderr_near"
    MIN_PWKL_NEAR = "min_pwkl_near"


class Criterion(StrEnum):
    """Selection criteria of the candidate set (:data:`CRITERIA` has one function each)."""

    CONFIDENCE = "confidence"
    """The k candidates of highest confidence."""
    CATEGORY = "category"
    """Every candidate whose k highest classes contain the target class."""


@dataclass(frozen=True)
class Situation:
    """What a strategy sees at one attempt, for Q queries over N candidates."""

    confidence: np.ndarray
    """(Q, N) P_c[y] of each query's target class."""
    available: np.ndarray
    """(Q, N) bool: not visited and not excluded by a failed attempt nearby."""
    candidate_set: np.ndarray
    """(Q, N) bool: the selection criterion's set (a subset of ``available``)."""
    columns: Mapping[str, np.ndarray]
    """(N,) measure columns by name: ``entropy``, ``stderr``, ``pwkl``."""
    rng: np.random.Generator | None = None
    """Source of the random strategies' draws (seeded by the caller)."""
    success: np.ndarray | None = None
    """(Q, N) bool ground truth; only the oracle reads it."""
    distance: np.ndarray | None = None
    """(Q, N) metres from where each query's robot stands to each candidate's goal (inf:
    unreachable); None: unknown, every distance counts the same. Only travel rules read it."""


@dataclass(frozen=True)
class Pick:
    """One chosen candidate per query (``-1`` where nothing is available)."""

    candidate: np.ndarray
    """(Q,) int64 candidate ids."""
    value: np.ndarray
    """(Q,) float64 the value of the measure that chose it (NaN for random draws)."""
    fell_back: np.ndarray
    """(Q,) bool: the candidate set was empty and max confidence chose instead."""


def best_of(
    values: np.ndarray, mask: np.ndarray, confidence: np.ndarray, *, maximise: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Row-wise best of ``values`` within ``mask``; ties by higher confidence, then lower id.

    Returns ``(candidate (Q,), found (Q,))``; NaN values count as the worst. Infinite values
    are legitimate (a one-view candidate has stderr = +inf, the worst under *min*). Rows
    with a tie are resolved apart, so the common case costs a few passes over (Q, N).
    """
    if values is confidence and maximise:
        # max confidence: the confidence tie-break is moot, argmax's first maximum is the lower id
        if mask.all():
            return confidence.argmax(axis=1), np.full(len(mask), mask.shape[1] > 0)
        best = np.where(mask, confidence, -np.inf).argmax(axis=1)
        return best, cast(np.ndarray, mask.any(axis=1))
    values = np.asarray(values)
    if np.isnan(values).any():
        values = np.where(np.isnan(values), -np.inf if maximise else np.inf, values)
    if np.count_nonzero(mask) * 8 < mask.size:
        return _best_of_sparse(values, mask, confidence, maximise=maximise)
    score = np.where(mask, values if maximise else -values, -np.inf)
    best = score.max(axis=1, keepdims=True) if score.shape[1] else score[:, :1]
    tie = score == best
    found = cast(np.ndarray, mask.any(axis=1))  # (Q,) bool: an axis reduction of a 2-d mask
    if score.shape[1] == 0:
        return np.zeros(len(score), np.int64), found
    n_tie = tie.sum(axis=1)
    multi = np.flatnonzero((n_tie > 1) | ~np.isfinite(best[:, 0]))
    if len(multi):
        sub = tie[multi] & mask[multi]
        conf = np.where(sub, np.broadcast_to(confidence, mask.shape)[multi], -np.inf)
        sub &= conf == conf.max(axis=1, keepdims=True)
        tie[multi] = sub
    return tie.argmax(axis=1), found


def _best_of_sparse(
    values: np.ndarray, mask: np.ndarray, confidence: np.ndarray, *, maximise: bool
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`best_of` for a sparse mask (a top-k set), over its (row, id) pairs in row-major
    order: per-row maxima by ``reduceat``, so the cost follows the set, not Q x N."""
    n_q, n_c = mask.shape
    rows, cols = np.divmod(np.flatnonzero(mask), n_c)
    out, found = np.zeros(n_q, np.int64), np.zeros(n_q, bool)
    if len(rows) == 0:
        return out, found
    vals = values[cols] if values.ndim == 1 else values[rows, cols]
    score = np.where(np.isnan(vals), -np.inf, vals if maximise else -vals)
    conf = np.broadcast_to(confidence, mask.shape)[rows, cols]
    starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
    sizes = np.diff(np.r_[starts, len(rows)])
    tie = score == np.repeat(np.maximum.reduceat(score, starts), sizes)
    tied_conf = np.where(tie, conf, -np.inf)
    tie &= tied_conf == np.repeat(np.maximum.reduceat(tied_conf, starts), sizes)
    idx = np.flatnonzero(tie)  # ids ascend within a row: the first tie is the lower id
    first = idx[np.r_[True, rows[idx][1:] != rows[idx][:-1]]]
    out[rows[first]] = cols[first]
    found[rows[first]] = True
    return out, found


def uniform_of(mask: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One candidate drawn uniformly from each row's ``mask``: ``(candidate, found)``."""
    draw = rng.random(mask.shape)
    return np.where(mask, draw, -1.0).argmax(axis=1), cast(np.ndarray, mask.any(axis=1))


def topk_confidence(
    confidence: np.ndarray, available: np.ndarray, k: int, rank: np.ndarray | None = None
) -> np.ndarray:
    """(Q, N) bool: the k available candidates of highest confidence (ties: lower id).

    A row's k-th largest value is at least the k-th largest of its block maxima (k blocks
    each hold a value that large), so one pass for the block maxima and one comparison
    leave a few candidates per row, ranked exactly by (confidence desc, id asc). That is
    two passes over (Q, N) where k row-wise argmaxes or a partition take k or more.
    """
    dtype = np.result_type(confidence, np.float32)
    key = np.array(np.broadcast_to(confidence, available.shape), dtype=dtype)
    np.copyto(key, -np.inf, where=~available)  # a third faster than np.where here
    n_q, n_cand = key.shape
    if k >= n_cand:
        return available.copy()
    n_blocks = max(k, min(64, n_cand // 8))
    size = -(-n_cand // n_blocks)
    full = n_cand // size
    maxima = key[:, : full * size].reshape(n_q, full, size).max(axis=2)
    if full * size < n_cand:
        maxima = np.concatenate([maxima, key[:, full * size :].max(axis=1, keepdims=True)], 1)
    if maxima.shape[1] < k:  # too few blocks to bound the k-th value: no pruning
        bound = np.full((n_q, 1), -np.inf, key.dtype)
    else:
        bound = -np.partition(-maxima, k - 1, axis=1)[:, k - 1 : k]
    rows, cols = np.divmod(np.flatnonzero(key >= bound), n_cand)  # 2-D nonzero is ~10x slower
    order = np.lexsort((cols, -key[rows, cols], rows))
    rows, cols = rows[order], cols[order]
    starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
    within = np.arange(len(rows)) - np.repeat(starts, np.diff(np.r_[starts, len(rows)]))
    keep = within < k
    out = np.zeros(key.shape, bool)
    out[rows[keep], cols[keep]] = True
    return out & available


def topk_category(
    confidence: np.ndarray, available: np.ndarray, k: int, rank: np.ndarray | None = None
) -> np.ndarray:
    """(Q, N) bool: available candidates whose k highest classes contain the target class.

    ``rank`` is :meth:`care_maps.query.map.CandidateMap.class_rank` of the query classes.
    """
    if rank is None:
        msg = "the category criterion needs the class ranks of the candidates"
        raise ReplanError(msg)
    return available & (rank < k)


# keyed by the Criterion members, looked up by plain strings too (a StrEnum member is its str)
CRITERIA: dict[str, Callable[..., np.ndarray]] = {
    Criterion.CONFIDENCE: topk_confidence,
    Criterion.CATEGORY: topk_category,
}
"""Selection criterion name -> ``f(confidence, available, k, rank) -> (Q, N) bool``."""


def candidate_set(
    criterion: str,
    confidence: np.ndarray,
    available: np.ndarray,
    k: int,
    rank: np.ndarray | None = None,
) -> np.ndarray:
    """The candidate set of ``criterion`` with parameter ``k`` among available candidates."""
    if criterion not in CRITERIA:
        msg = f"unknown selection criterion {criterion!r}; choose one of {', '.join(CRITERIA)}"
        raise ReplanError(msg)
    if k < 1:
        msg = f"k must be at least 1, got {k}"
        raise ReplanError(msg)
    return CRITERIA[criterion](confidence, available, k, rank)


def _pick(
    s: Situation, candidate: np.ndarray, found: np.ndarray, values: np.ndarray | None
) -> Pick:
    """Complete a rule's choice: max confidence where its set was empty, -1 where nothing is."""
    candidate = np.where(found, candidate, -1)
    fell_back = np.zeros(len(candidate), bool)
    empty = np.flatnonzero(~found)
    if len(empty):  # max confidence where the rule's set was empty
        conf = s.confidence[empty]
        fallback, any_left = best_of(conf, s.available[empty], conf, maximise=True)
        candidate[empty] = np.where(any_left, fallback, -1)
        fell_back[empty] = any_left
    rows = np.arange(len(candidate))
    safe = np.maximum(candidate, 0)
    if values is None:
        value = np.full(len(candidate), np.nan)
    else:
        value = np.broadcast_to(values, s.available.shape)[rows, safe].astype(np.float64)
    value = np.where(fell_back, s.confidence[rows, safe], value)
    return Pick(candidate.astype(np.int64), np.where(candidate >= 0, value, np.nan), fell_back)


def _max_confidence(s: Situation) -> Pick:
    cand, found = best_of(s.confidence, s.available, s.confidence, maximise=True)
    return _pick(s, cand, found, s.confidence)


def _uniform_pick(s: Situation, mask: np.ndarray) -> Pick:
    """A seeded uniform draw from each row's ``mask`` (the random strategies)."""
    if s.rng is None:
        msg = "the random strategies need a seeded generator (Situation.rng)"
        raise ReplanError(msg)
    cand, found = uniform_of(mask, s.rng)
    return _pick(s, cand, found, None)


def _random(s: Situation) -> Pick:
    return _uniform_pick(s, s.available)


def _random_topk(s: Situation) -> Pick:
    return _uniform_pick(s, s.candidate_set)


def _by_measure(column: str, maximise: bool) -> Callable[[Situation], Pick]:
    def rule(s: Situation) -> Pick:
        values = s.columns[column]
        cand, found = best_of(values, s.candidate_set, s.confidence, maximise=maximise)
        return _pick(s, cand, found, values)

    rule.__name__ = f"{'max' if maximise else 'min'}_{column}"
    return rule


def _column(s: Situation, name: str) -> np.ndarray:
    if name not in s.columns:
        msg = f"this strategy chooses by the {name!r} column, which the map did not give"
        raise ReplanError(msg)
    return np.asarray(s.columns[name], np.float64)


def _largest(s: Situation) -> Pick:
    """Non-CARe baseline: the available candidate with the largest mask (scene points)."""
    values = _column(s, "size")
    cand, found = best_of(values, s.available, s.confidence, maximise=True)
    return _pick(s, cand, found, values)


def _most_views(s: Situation) -> Pick:
    """Non-CARe baseline: the available candidate seen in the most views."""
    values = _column(s, "num_views")
    cand, found = best_of(values, s.available, s.confidence, maximise=True)
    return _pick(s, cand, found, values)


def _distance(s: Situation) -> np.ndarray:
    """(Q, N) metres to each candidate's goal; zeros where distances are unknown."""
    if s.distance is None:
        return np.zeros(s.available.shape)
    return np.broadcast_to(np.asarray(s.distance, np.float64), s.available.shape)


def _nearest_topk(s: Situation) -> Pick:
    """Non-CARe baseline: the nearest candidate of the set (ties: higher confidence)."""
    values = _distance(s)
    cand, found = best_of(values, s.candidate_set, s.confidence, maximise=False)
    return _pick(s, cand, found, values)


def _rule_rank(
    values: np.ndarray, mask: np.ndarray, confidence: np.ndarray, *, maximise: bool
) -> np.ndarray:
    """(Q, N) rank of each member of ``mask`` under a measure rule's order (0: its pick; by
    value, then higher confidence, then lower id, as :func:`best_of`); -1 off the mask."""
    n_c = mask.shape[1]
    rows, cols = np.divmod(np.flatnonzero(mask), n_c)
    rank = np.full(mask.shape, -1, np.int64)
    if len(rows) == 0:
        return rank
    vals = np.asarray(values, np.float64)
    vals = vals[cols] if vals.ndim == 1 else vals[rows, cols]
    key = np.where(np.isnan(vals), np.inf, -vals if maximise else vals)
    conf = np.broadcast_to(confidence, mask.shape)[rows, cols]
    order = np.lexsort((cols, -conf, key, rows))
    rows, cols = rows[order], cols[order]
    starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
    rank[rows, cols] = np.arange(len(rows)) - np.repeat(starts, np.diff(np.r_[starts, len(rows)]))
    return rank


def travel_score(
    rank: np.ndarray, distance: np.ndarray, weight: float = TRAVEL_WEIGHT
) -> np.ndarray:
    """(Q, N) the distance-aware rules' score of each member of a candidate set (lower wins):
    ``rank / (|S| - 1) + weight * d / d_max``.

    ``rank`` is the member's rank under the CARe rule (:func:`_rule_rank`: 0 its own pick,
    -1 off the set), ``d`` its distance and ``d_max`` the farthest reachable member's. Both
    terms run from 0 to 1 within a set whatever its size or the floor's, so one weight fits
    every k and map; an unreachable member scores inf, off the set NaN.
    """
    member = rank >= 0
    size = member.sum(axis=1, keepdims=True)
    dist = np.where(member, distance, np.nan)
    reach = member & np.isfinite(dist)
    far = np.where(reach, dist, 0.0).max(axis=1, keepdims=True)
    scaled = np.where(far > 0, np.where(reach, dist, 0.0) / np.where(far > 0, far, 1.0), 0.0)
    score = rank / np.maximum(size - 1, 1) + weight * scaled
    score = np.where(member & ~np.isfinite(dist), np.inf, score)
    return np.where(member, score, np.nan)


def _near(column: str, maximise: bool) -> Callable[[Situation], Pick]:
    """The distance-aware variant of the CARe rule over ``column`` (:func:`travel_score`)."""

    def rule(s: Situation) -> Pick:
        rank = _rule_rank(s.columns[column], s.candidate_set, s.confidence, maximise=maximise)
        score = travel_score(rank, _distance(s))
        cand, found = best_of(score, s.candidate_set, s.confidence, maximise=False)
        return _pick(s, cand, found, score)

    rule.__name__ = f"{'max' if maximise else 'min'}_{column}_near"
    return rule


def _oracle(s: Situation) -> Pick:
    if s.success is None:
        msg = "the oracle needs ground truth; it exists only in evaluation (`care eval`)"
        raise ReplanError(msg)
    cand, found = best_of(s.confidence, s.available & s.success, s.confidence, maximise=True)
    return _pick(s, cand, found, s.confidence)


@dataclass(frozen=True)
class Strategy:
    """A named replan rule and how the evaluation treats it."""

    name: StrategyName
    label: str
    """Row label of the paper's tables."""
    rule: Callable[[Situation], Pick] | None
    """The rule for the second and later attempts; ``None``: no further attempt."""
    measure: str | None = None
    """Column the rule chooses by (``confidence``, ``entropy``, ``stderr``, ``pwkl``)."""
    uses_set: bool = False
    """Chooses within the candidate set of a criterion and k (else k does not matter)."""
    random: bool = False
    needs_truth: bool = False
    ablation: bool = False
    travel: bool = False
    """Chooses by the distance from the robot's place too (:attr:`Situation.distance`)."""


# keyed by the StrategyName members, looked up by plain strings too (options, table values)
STRATEGIES: dict[str, Strategy] = {
    s.name: s
    for s in (
        Strategy(StrategyName.NO_REPLAN, "No replan (top1 acc)", None),
        Strategy(StrategyName.ORACLE, "Oracle", _oracle, "confidence", needs_truth=True),
        Strategy(
            StrategyName.MAX_CONFIDENCE, "Max confidence (top2 acc)", _max_confidence, "confidence"
        ),
        Strategy(StrategyName.RANDOM, "Random replan", _random, random=True),
        Strategy(
            StrategyName.RANDOM_TOPK, "Random from top-k", _random_topk, uses_set=True, random=True
        ),
        Strategy(
            StrategyName.MAX_ENTROPY, "Max entropy", _by_measure("entropy", True), "entropy", True
        ),
        Strategy(
            StrategyName.MIN_STDERR, "Min stderr", _by_measure("stderr", False), "stderr", True
        ),
        Strategy(StrategyName.MIN_PWKL, "Min pwKL", _by_measure("pwkl", False), "pwkl", True),
        Strategy(
            StrategyName.MIN_ENTROPY,
            "Min entropy (ablation)",
            _by_measure("entropy", False),
            "entropy",
            uses_set=True,
            ablation=True,
        ),
        Strategy(
            StrategyName.MAX_PWKL,
            "Max pwKL (ablation)",
            _by_measure("pwkl", True),
            "pwkl",
            uses_set=True,
            ablation=True,
        ),
        Strategy(StrategyName.LARGEST, "Largest candidate (baseline)", _largest, "size"),
        Strategy(StrategyName.MOST_VIEWS, "Most views (baseline)", _most_views, "num_views"),
        Strategy(
            StrategyName.NEAREST_TOPK,
            "Nearest of top-k (baseline)",
            _nearest_topk,
            "distance",
            uses_set=True,
            travel=True,
        ),
        Strategy(
            StrategyName.MAX_ENTROPY_NEAR,
            "Max entropy, travel-aware",
            _near("entropy", True),
            "entropy",
            uses_set=True,
            travel=True,
        ),
        Strategy(
            StrategyName.MIN_STDERR_NEAR,
            "Min stderr, travel-aware",
            _near("stderr", False),
            "stderr",
            uses_set=True,
            travel=True,
        ),
        Strategy(
            StrategyName.MIN_PWKL_NEAR,
            "Min pwKL, travel-aware",
            _near("pwkl", False),
            "pwkl",
            uses_set=True,
            travel=True,
        ),
    )
}
"""Strategy name -> :class:`Strategy`, in the paper's row order; the CLI's choices."""


def get_strategy(name: str) -> Strategy:
    """The registered strategy ``name`` or a ReplanError listing the choices."""
    if name not in STRATEGIES:
        msg = f"unknown replan strategy {name!r}; choose one of {', '.join(STRATEGIES)}"
        raise ReplanError(msg)
    return STRATEGIES[name]
