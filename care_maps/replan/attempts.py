"""Attempts: the first by max confidence, then a strategy's rule after each failure.

:func:`run_attempts` plays whole episodes for a batch of queries when success is known (the
evaluation); :func:`next_goal` is the live call a robot makes after a failed attempt, with
only the list of visited candidates.

For the grid a failed attempt also excludes every cell within ``exclude_radius`` metres (floor
plane) of it, so the agent does not try the same object again from the next cell; instances
exclude only the visited instance.

With a :class:`Walk` every episode also walks: from its start to the first goal, then from
each goal reached to the next. An attempt at a goal the robot cannot reach (distance
``inf``) still counts as one of the attempts, adds nothing to the path, and leaves the robot
where it was. Travel rules (``nearest_topk``, ``*_near``) see the distances from where the
robot stands.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from care_maps.core.checks import check_numbers
from care_maps.core.config import member
from care_maps.core.errors import ReplanError
from care_maps.core.maps import MapKind
from care_maps.query.map import MEASURES, REPLAN_COLUMNS, CandidateMap
from care_maps.replan.strategies import (
    Criterion,
    Pick,
    Situation,
    Strategy,
    StrategyName,
    best_of,
    candidate_set,
    get_strategy,
)

__all__ = [
    "DEFAULT_ATTEMPTS",
    "DEFAULT_EXCLUDE_RADIUS",
    "DEFAULT_K",
    "Attempts",
    "Choice",
    "ReplanConfig",
    "Walk",
    "available_after",
    "candidates_near",
    "next_goal",
    "run_attempts",
]

DEFAULT_EXCLUDE_RADIUS = 1.0
"""Metres around a failed grid cell that later attempts skip (the success radius)."""
DEFAULT_K = 4
"""Size parameter of a replan's candidate set when none is given."""
DEFAULT_ATTEMPTS = 2
"""Attempts per query when none is given: the first answer and one replan."""


@dataclass(frozen=True)
class ReplanConfig:
    """How the next goal is chosen after a failed attempt (``care replan`` and
    :func:`next_goal`; :class:`care_maps.replan.batch.BatchConfig` shares k and the radius)."""

    strategy: StrategyName = StrategyName.MIN_STDERR
    """Replan strategy."""
    criterion: Criterion = Criterion.CONFIDENCE
    """Candidate set of the strategies that choose within one."""
    k: int = DEFAULT_K
    """Size parameter of the candidate set (>= 1)."""
    exclude_radius: float = DEFAULT_EXCLUDE_RADIUS
    """Grid: metres around a failed cell skipped later; also the radius of a visited place."""
    seed: int = 0
    """Seed of the random strategies."""

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "strategy", member(StrategyName, self.strategy, ReplanError, "unknown strategy")
        )
        object.__setattr__(
            self, "criterion", member(Criterion, self.criterion, ReplanError, "unknown criterion")
        )
        check_numbers(
            ReplanError,
            "replan settings",
            non_negative={"exclude_radius": self.exclude_radius},
            at_least_one={"k": self.k},
        )


_REPLAN = ReplanConfig()


@dataclass(frozen=True)
class Attempts:
    """Every attempt of Q episodes (A attempts at most; ``-1`` where none was made)."""

    candidate: np.ndarray
    """(Q, A) int64 chosen candidate per attempt."""
    success: np.ndarray
    """(Q, A) bool."""
    value: np.ndarray
    """(Q, A) float64 measure value that chose the candidate (confidence for attempt 1)."""
    fell_back: np.ndarray
    """(Q, A) bool: the candidate set was empty and max confidence chose."""
    set_size: np.ndarray
    """(Q, A) int64 size of the candidate set the rule chose from (0 where not set-based)."""
    distance: np.ndarray | None = None
    """(Q, A) float64 metres walked to each attempt's goal from where the robot stood (inf:
    unreachable, NaN: no attempt); None: played without a :class:`Walk`."""

    @property
    def solved(self) -> np.ndarray:
        """(Q,) bool: some attempt succeeded."""
        return cast(np.ndarray, self.success.any(axis=1))


@dataclass(frozen=True)
class Walk:
    """Where each episode's robot starts and how far it is from one goal to the next."""

    start: np.ndarray
    """(Q, N) metres from each query's start to each candidate's goal (inf: unreachable)."""
    legs: Callable[[np.ndarray], np.ndarray]
    """Candidate ids (M,) -> (M, N) metres from each one's goal to every candidate's goal
    (:meth:`care_maps.query.travel.Legs.from_goals`)."""


def candidates_near(cmap: CandidateMap, xy: np.ndarray, radius: float) -> np.ndarray:
    """Sorted ids of the candidates within ``radius`` m (floor plane) of any position in
    ``xy`` (P, 2): the candidates a robot that went there has seen not to be the object.

    A position farther than ``radius`` outside the box of the map's candidates is an error,
    not a visit that excludes nothing: it is almost always given in another frame."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if not np.isfinite(xy).all():
        msg = "visited positions must be finite x,y in metres"
        raise ReplanError(msg)
    pos = cmap.positions[:, :2].astype(np.float64)
    if len(xy) and len(pos):
        lo, hi = pos.min(axis=0) - radius, pos.max(axis=0) + radius
        outside = ~((xy >= lo) & (xy <= hi)).all(axis=1)
        if outside.any():
            x, y = xy[np.argmax(outside)]
            msg = (
                f"visited position {x:g},{y:g} lies outside the map (its candidates span x "
                f"{lo[0] + radius:.2f}..{hi[0] - radius:.2f}, y {lo[1] + radius:.2f}.."
                f"{hi[1] - radius:.2f} m, in the map frame of the goals and map.yaml); give "
                "positions in that frame"
            )
            raise ReplanError(msg)
    near = np.zeros(cmap.num_candidates, bool)
    for p in xy:
        near |= ((pos - p) ** 2).sum(axis=1) <= radius**2
    return np.flatnonzero(near)


def available_after(
    available: np.ndarray,
    chosen: np.ndarray,
    positions: np.ndarray | None,
    exclude_radius: float,
) -> np.ndarray:
    """``available`` without each row's ``chosen`` candidate and, with positions (grid), the
    candidates within ``exclude_radius`` of it on the floor plane."""
    out = available.copy()
    rows = np.flatnonzero(chosen >= 0)
    out[rows, chosen[rows]] = False
    if positions is not None and exclude_radius > 0 and len(rows):
        xy = positions[:, :2]
        d2 = ((xy[None, :, :] - xy[chosen[rows]][:, None, :]) ** 2).sum(-1)
        out[rows] &= d2 > exclude_radius**2
    return out


def _step(
    strategy: Strategy,
    conf: np.ndarray,
    available: np.ndarray,
    columns: dict[str, np.ndarray],
    *,
    criterion: str,
    k: int,
    rank: np.ndarray | None,
    rng: np.random.Generator | None,
    success: np.ndarray | None,
    distance: np.ndarray | None = None,
) -> tuple[Pick, np.ndarray]:
    cset = candidate_set(criterion, conf, available, k, rank) if strategy.uses_set else available
    situation = Situation(conf, available, cset, columns, rng, success, distance)
    if strategy.rule is None:
        msg = f"strategy {strategy.name!r} makes no further attempt"
        raise ReplanError(msg)
    size = cset.sum(axis=1) if strategy.uses_set else np.zeros(len(conf), np.int64)
    return strategy.rule(situation), size


def run_attempts(
    strategy: Strategy | str,
    conf: np.ndarray,
    success: np.ndarray,
    columns: dict[str, np.ndarray],
    *,
    criterion: Criterion | str = Criterion.CONFIDENCE,
    k: int = DEFAULT_K,
    attempts: int = DEFAULT_ATTEMPTS,
    rank: np.ndarray | None = None,
    positions: np.ndarray | None = None,
    exclude_radius: float = 0.0,
    rng: np.random.Generator | None = None,
    searched: np.ndarray | None = None,
    walk: Walk | None = None,
) -> Attempts:
    """Play Q episodes: attempt 1 by max confidence, then ``strategy`` on what remains after
    each failure, up to ``attempts`` attempts; an episode stops at its first success.

    ``conf``/``success``/``rank`` are (Q, N); ``positions`` (N, 3) turns on the grid's radius
    exclusion. ``no_replan`` makes one attempt whatever ``attempts`` says. ``searched``
    (Q, N) bool: candidates already searched before the episode (places the robot has been);
    a row with any is already replanning, so its attempt 1 is ``strategy``'s choice too (none
    for ``no_replan``), as :func:`next_goal` answers after a visit. ``walk``: the episodes
    walk (module docstring); each attempt's leg length comes back in :attr:`Attempts.distance`.
    """
    strategy = get_strategy(strategy) if isinstance(strategy, str) else strategy
    if attempts < 1:
        msg = f"attempts must be at least 1, got {attempts}"
        raise ReplanError(msg)
    n_q, n_c = conf.shape
    shapes = {"success": success, "rank": rank, "searched": searched}
    if walk is not None:
        shapes["walk.start"] = walk.start
    bad = [
        f"{n} {np.shape(a)}"
        for n, a in shapes.items()
        if a is not None and np.shape(a) != conf.shape
    ]
    if strategy.measure in MEASURES and strategy.measure not in columns:
        bad.append(f"no {strategy.measure!r} column")
    if bad:
        msg = f"episodes of {conf.shape} confidences got {', '.join(bad)}"
        raise ReplanError(msg)
    n_a = 1 if strategy.rule is None else attempts
    cand = np.full((n_q, attempts), -1, np.int64)
    ok = np.zeros((n_q, attempts), bool)
    value = np.full((n_q, attempts), np.nan)
    fell = np.zeros((n_q, attempts), bool)
    size = np.zeros((n_q, attempts), np.int64)
    available = np.ones((n_q, n_c), bool) if searched is None else ~searched
    replanning = np.zeros(n_q, bool) if searched is None else searched.any(axis=1)
    first, found = best_of(conf, available, conf, maximise=True)
    chosen = np.where(found & ~replanning, first, -1)
    rows = np.arange(n_q)
    here = None if walk is None else np.array(walk.start, np.float64)  # (Q, N) from the robot
    legs = None if walk is None else np.full((n_q, attempts), np.nan)
    for a in range(n_a):
        if a == 0 and replanning.any() and strategy.rule is not None:
            pick, set_size = _step(
                strategy, conf, available, columns,
                criterion=criterion, k=k, rank=rank, rng=rng, success=success, distance=here,
            )  # fmt: skip
            chosen = np.where(replanning, pick.candidate, chosen)
            value[:, 0] = np.where(replanning, pick.value, np.nan)
            fell[:, 0] = replanning & pick.fell_back
            size[:, 0] = np.where(replanning, set_size, 0)
        if a > 0:
            live = ~ok[:, :a].any(axis=1) & (cand[:, a - 1] >= 0)
            available = available_after(
                available, np.where(live, cand[:, a - 1], -1), positions, exclude_radius
            )
            available[~live] = False
            if walk is not None and here is not None and legs is not None:  # all or none set
                here = _walk_on(walk, here, cand[:, a - 1], legs[:, a - 1], live)
            pick, set_size = _step(
                strategy, conf, available, columns,
                criterion=criterion, k=k, rank=rank, rng=rng, success=success, distance=here,
            )  # fmt: skip
            chosen = np.where(live, pick.candidate, -1)
            value[:, a] = np.where(live, pick.value, np.nan)
            fell[:, a] = live & pick.fell_back
            size[:, a] = np.where(live, set_size, 0)
        else:
            first_rows = found & ~replanning
            value[:, 0] = np.where(first_rows, conf[rows, np.maximum(chosen, 0)], value[:, 0])
        cand[:, a] = chosen
        ok[:, a] = (chosen >= 0) & success[rows, np.maximum(chosen, 0)]
        if legs is not None and here is not None:  # both set with a walk
            legs[:, a] = np.where(chosen >= 0, here[rows, np.maximum(chosen, 0)], np.nan)
    return Attempts(cand, ok, value, fell, size, legs)


def _walk_on(
    walk: Walk, here: np.ndarray, went: np.ndarray, leg: np.ndarray, live: np.ndarray
) -> np.ndarray:
    """The distances from where each live episode's robot stands after its last attempt:
    at that attempt's goal where it could reach it, else still where it was."""
    moved = np.flatnonzero(live & (went >= 0) & np.isfinite(leg))
    if len(moved) == 0:
        return here
    here = here.copy()
    here[moved] = walk.legs(went[moved])
    return here


@dataclass(frozen=True)
class Choice:
    """The live answer: where to go next, and why."""

    candidate: int
    """Candidate id, ``-1`` when every candidate has been visited or excluded."""
    strategy: str
    """The rule that chose: ``max_confidence`` for a first attempt or a fallback."""
    measure: str | None
    value: float
    """Value of ``measure`` for the chosen candidate."""
    confidence: float
    fell_back: bool
    """The candidate set was empty, so max confidence chose instead of the strategy."""
    set_size: int


def next_goal(
    cmap: CandidateMap,
    query: str | int,
    visited: Sequence[int] | np.ndarray = (),
    *,
    config: ReplanConfig = _REPLAN,
    visited_at: np.ndarray | Sequence[tuple[float, float]] = (),
    distance: np.ndarray | list[float] | None = None,
    skip: Sequence[int] | np.ndarray = (),
) -> Choice:
    """The next candidate to try for ``query`` after the ``visited`` (failed) ones.

    ``query`` is a class id, a class name or free text, resolved exactly as ``care query``
    does (:func:`care_maps.query.openvocab.open_query`: text the vocabulary lacks joins it through the
    store's own text encoder), or an already resolved ``QueryTarget``.

    With nothing visited this is the first attempt (max confidence); afterwards
    ``config.strategy`` over ``config.criterion``'s top-k set among unvisited candidates
    (``config``: a :class:`ReplanConfig`, checked when it was made). Its ``exclude_radius``
    (grid only, 1 m by default) also skips cells near failed ones. ``visited_at``: map
    positions (x, y) the robot went to without finding the object; the candidates within the
    exclusion radius of one (for instances too) count as visited. ``distance``: (N,) metres from
    where the robot stands to each candidate's goal (inf: unreachable), which the travel rules
    (``nearest_topk``, ``*_near``) trade against and the others ignore; a travel rule without
    it is refused, not played as if every candidate were equally far. ``skip``: candidates
    with no goal to offer (:func:`care_maps.replan.answer.offer_next`), left out as if absent: no
    exclusion radius around them, and the first attempt stays the first.
    """
    strategy, criterion, k = config.strategy, config.criterion, config.k
    from care_maps.query.openvocab import QueryTarget, open_query

    target = query if isinstance(query, QueryTarget) else open_query(cmap, query)
    # ranked by log-confidence: the same order as confidence, without float32's ties at 1.0
    conf = target.log_confidence()[None]
    visited_ids = np.asarray(visited, dtype=np.int64).reshape(-1)
    if visited_ids.size and (visited_ids.min() < 0 or visited_ids.max() >= cmap.num_candidates):
        msg = f"visited candidate ids must lie in 0..{cmap.num_candidates - 1}"
        raise ReplanError(msg)
    default_radius = config.exclude_radius
    places = np.asarray(visited_at, dtype=np.float64).reshape(-1, 2)
    available = np.ones_like(conf, dtype=bool)
    available[0, candidates_near(cmap, places, default_radius)] = False
    radius = default_radius if cmap.kind == MapKind.GRID else 0.0
    available[0, visited_ids] = False
    skipped = np.asarray(skip, dtype=np.int64).reshape(-1)
    if skipped.size and (skipped.min() < 0 or skipped.max() >= cmap.num_candidates):
        msg = f"skipped candidate ids must lie in 0..{cmap.num_candidates - 1}"
        raise ReplanError(msg)
    available[0, skipped] = False
    if radius > 0:  # the map's spatial index: each exclusion costs its window, not N
        for v in np.unique(visited_ids):
            available[0, cmap.near(int(v), radius)] = False
    chosen = get_strategy(strategy)
    # no_replan after a visit: _step says it makes no attempt
    first = visited_ids.size == 0 and not len(places)
    here = None if distance is None else np.asarray(distance, np.float64).reshape(1, -1)
    if here is not None and here.shape[1] != cmap.num_candidates:
        msg = f"distance gives {here.shape[1]} values for {cmap.num_candidates} candidates"
        raise ReplanError(msg)
    if chosen.travel and here is None and not first:
        msg = (
            f"strategy {chosen.name!r} trades its measure against travel: give each "
            "candidate's distance from where the robot stands (care replan finds them over "
            "the grid's free space)"
        )
        raise ReplanError(msg)
    if first:
        cand, found = best_of(conf, available, conf, maximise=True)
        pick = Pick(
            np.where(found, cand, -1), np.exp(conf[0, cand].astype(np.float64)), np.zeros(1, bool)
        )
        size = np.zeros(1, np.int64)
    else:
        rank = target.class_rank(limit=k)[None] if criterion == "category" else None
        columns = {name: cmap.column(name) for name in REPLAN_COLUMNS}
        pick, size = _step(
            chosen, conf, available, columns, criterion=criterion, k=k, rank=rank,
            rng=np.random.default_rng(config.seed), success=None, distance=here,
        )  # fmt: skip
    c = int(pick.candidate[0])
    fell = bool(pick.fell_back[0])
    used = "max_confidence" if first or fell else chosen.name
    measure = "confidence" if first or fell else chosen.measure
    value = float(pick.value[0]) if c >= 0 else float("nan")
    if measure == "confidence" and not first:  # chosen by log-confidence: report P
        value = float(np.exp(value))
    return Choice(
        candidate=c,
        strategy=used,
        measure=measure,
        value=value,
        confidence=float(np.exp(np.float64(conf[0, c]))) if c >= 0 else float("nan"),
        fell_back=fell,
        set_size=int(size[0]),
    )
