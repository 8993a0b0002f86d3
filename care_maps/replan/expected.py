"""Closed-form expected success of the random strategies (the mean the seeds estimate).

After a failed first attempt, a uniform draw from a set of U candidates of which S succeed
succeeds with probability S / U. With more attempts and nothing else excluded (instances, or a
grid without radius exclusion), uniform draws without replacement from all unvisited
candidates succeed within A - 1 draws with probability 1 - C(U - S, A - 1) / C(U, A - 1)
(the hypergeometric tail). Where the set changes with every failed draw (random top-k, or
grid exclusion around each failure) there is no such simple form and NaN is returned.
"""

from __future__ import annotations

import numpy as np

from care_maps.replan.attempts import DEFAULT_ATTEMPTS, DEFAULT_K, available_after
from care_maps.replan.strategies import Criterion, Strategy, best_of, candidate_set, get_strategy

__all__ = ["expected_random_success"]


def expected_random_success(
    strategy: Strategy | str,
    conf: np.ndarray,
    success: np.ndarray,
    *,
    criterion: Criterion | str = Criterion.CONFIDENCE,
    k: int = DEFAULT_K,
    attempts: int = DEFAULT_ATTEMPTS,
    rank: np.ndarray | None = None,
    positions: np.ndarray | None = None,
    exclude_radius: float = 0.0,
) -> np.ndarray:
    """(Q,) probability that ``random`` / ``random_topk`` succeeds within ``attempts``."""
    strategy = get_strategy(strategy) if isinstance(strategy, str) else strategy
    available = np.ones_like(success, dtype=bool)
    first, found = best_of(conf, available, conf, maximise=True)
    rows = np.arange(len(conf))
    first_ok = found & success[rows, first]
    if attempts < 2:
        return first_ok.astype(np.float64)
    available = available_after(available, np.where(found, first, -1), positions, exclude_radius)
    cset = candidate_set(criterion, conf, available, k, rank) if strategy.uses_set else available
    size = cset.sum(axis=1)
    hits = (cset & success).sum(axis=1)
    fallback, any_left = best_of(conf, available, conf, maximise=True)
    fallback_ok = any_left & success[rows, fallback]
    draws = attempts - 1
    if draws == 1:
        p_second = np.where(size > 0, hits / np.maximum(size, 1), fallback_ok)
    elif not strategy.uses_set and (positions is None or exclude_radius <= 0):
        p_second = np.where(size > 0, 1.0 - _miss_all(size, hits, draws), 0.0)
    else:
        p_second = np.full(len(conf), np.nan)
    return np.where(first_ok, 1.0, p_second)


def _miss_all(size: np.ndarray, hits: np.ndarray, draws: int) -> np.ndarray:
    """P(no success in ``draws`` uniform draws without replacement from ``size`` candidates of
    which ``hits`` succeed): C(size - hits, n) / C(size, n), n = min(draws, size), as the
    product over draws of (size - hits - i) / (size - i). (scipy.stats.hypergeom gives the
    same but costs 1.5 s to import, on the path of every live ``next_goal`` caller.)
    """
    size = np.asarray(size, np.float64)
    miss = np.ones_like(size)
    for i in range(draws):  # attempts - 1 factors, each over all queries at once
        left = size - i
        factor = np.where(left > 0, (left - hits) / np.maximum(left, 1), 1.0)
        miss *= np.clip(factor, 0.0, 1.0)
    return miss
