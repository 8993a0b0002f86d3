"""Success weighted by path length (SPL) of attempt sequences: pure functions of arrays.

Anderson et al. 2018, "On evaluation of embodied navigation agents": for episode i,
``SPL_i = S_i * l_i / max(p_i, l_i)`` with ``S_i`` its success, ``p_i`` the length of the
path the agent walked and ``l_i`` the shortest path from the start to the goal. Here:

- ``p``: the sum of the attempts' legs the robot could walk (each from where the one before
  ended; an unreachable goal adds nothing and leaves the robot where it was);
- ``S``: some attempt succeeded *at a goal the robot reached*. The success tables count the
  map's answer (the paper's protocol); a right answer no robot can drive to scores 0 here;
- ``l``: the shortest path from the start to the nearest success region: the nearest
  reachable approach point of any candidate that counts as a success, the same goals the
  attempts walk to, so a robot that knew the answer walks ``l`` and scores 1;
- an episode whose every success is out of reach (``l = inf``) scores 0; one that starts on
  its nearest success (``l = 0``) scores ``S``; NaN stays NaN (no travel known).

Success against distance travelled (:func:`success_within`) is the share of episodes solved
(``S``) with ``p`` at most each budget.
"""

from __future__ import annotations

import numpy as np

__all__ = ["episode_paths", "shortest_to_success", "spl", "success_within"]


def shortest_to_success(start: np.ndarray, success: np.ndarray) -> np.ndarray:
    """(Q,) ``l``: the least of ``start`` (Q, N) metres to each candidate's goal over the
    candidates that succeed (``success`` (Q, N)); inf where none is reachable."""
    start = np.asarray(start, np.float64)
    if start.shape[1] == 0:
        return np.full(len(start), np.inf)
    return np.where(np.asarray(success, bool), start, np.inf).min(axis=1)


def episode_paths(
    distance: np.ndarray, success: np.ndarray, made: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per episode (rows of (Q, A) arrays): ``p`` (metres walked over the attempts ``made``,
    their unreachable legs adding nothing) and ``S`` (an attempt succeeded at a goal reached)."""
    distance = np.asarray(distance, np.float64)
    made = np.asarray(made, bool)
    reached = made & np.isfinite(distance)
    path = np.where(reached, distance, 0.0).sum(axis=1)
    return path, (reached & np.asarray(success, bool)).any(axis=1)


def spl(solved: np.ndarray, shortest: np.ndarray, path: np.ndarray) -> np.ndarray:
    """(Q,) ``S * l / max(p, l)`` (module docstring for ``l = inf``, ``l = 0`` and NaN)."""
    s = np.asarray(solved, np.float64)
    l_ = np.asarray(shortest, np.float64)
    p = np.asarray(path, np.float64)
    longest = np.maximum(p, l_)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(longest > 0, l_ / np.where(longest > 0, longest, 1.0), 1.0)
    out = s * np.where(np.isinf(l_), 0.0, ratio)
    return np.where(np.isnan(l_) | np.isnan(p), np.nan, out)


def success_within(
    path: np.ndarray, solved: np.ndarray, budgets: np.ndarray, weight: np.ndarray | None = None
) -> np.ndarray:
    """(B,) share of episodes solved within each distance budget: the weighted mean of
    ``solved & path <= budget`` (``weight``: e.g. one over the seeds of a random rule, so a
    query counts once)."""
    path = np.asarray(path, np.float64)
    hit = np.asarray(solved, bool)
    w = np.ones(len(path)) if weight is None else np.asarray(weight, np.float64)
    total = w.sum()
    if total == 0:
        return np.full(len(budgets), np.nan)
    inside = hit[None, :] & (path[None, :] <= np.asarray(budgets, np.float64)[:, None])
    return (inside * w).sum(axis=1) / total
