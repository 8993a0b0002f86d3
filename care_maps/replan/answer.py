"""What an answer of ``care query`` or ``care replan`` promises, candidate by candidate: a
goal that keeps the robot's clearance, a way to it from the start, and, where either fails,
why, so that the robot is never sent somewhere it cannot stand or reach without a word.

A candidate's goal (:meth:`care_maps.query.goals.GoalMaker.goal`) is the approach point nearest the
object that keeps ``clearance``. The answer then checks it against the start's shortest
paths (:class:`care_maps.query.paths.Travel`) and gives each candidate an :class:`Offer`:

- the goal keeps the clearance and a way leads there: offered as it is
  (:attr:`PathState.REACHABLE`);
- it keeps the clearance but is cut off from the start (behind furniture, past a door too
  narrow for the robot): the search goes on among the approach points within ``reach`` of the
  object that the start reaches, and offers the nearest to the object
  (:attr:`PathState.DETOUR`), else none (:attr:`PathState.CUT_OFF`);
- no free cell within ``reach`` keeps the clearance (:attr:`PathState.TIGHT`), or none is
  free at all (:attr:`PathState.NO_FREE_CELL`): no goal is offered unless
  ``allow_tight_goals``, and then flagged;
- no paths at all: the start is off the roadmap at this clearance (the note says where the
  nearest cell a robot may stand on is), or there is no grid, or no start.

:func:`offer_next` is :func:`care_maps.replan.attempts.next_goal` that passes over the candidates
with nothing to offer, says which and why, and goes on to the next the rule picks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from functools import cached_property
from typing import Any, cast

import numpy as np

from care_maps.query.goals import Goal, GoalMaker
from care_maps.query.map import CandidateMap
from care_maps.query.paths import PathConfig, Roadmap, Travel
from care_maps.query.travel import approach_cells
from care_maps.replan.attempts import Choice, next_goal

__all__ = [
    "MAX_PASSED",
    "AnswerGoals",
    "Offer",
    "Offered",
    "PathState",
    "first_offer",
    "offer_next",
]

MAX_PASSED = 32
"""Candidates :func:`offer_next` passes over one by one, each said with its reason; past
these, every candidate with nothing to offer is left out at once (one vectorised check of
the whole map: a grid can hold thousands of cells behind one wall)."""


class PathState(StrEnum):
    """How a candidate's goal stands against the clearance and the start."""

    REACHABLE = "reachable"
    """The goal keeps the clearance and the start reaches it."""
    DETOUR = "detour"
    """The nearest approach point is cut off; a farther one within reach is offered."""
    CUT_OFF = "cut_off"
    """Every approach point within reach is cut off from the start at this clearance."""
    TIGHT = "tight"
    """No free cell within reach keeps the clearance."""
    NO_FREE_CELL = "no_free_cell"
    """No free cell within reach at all (the goal is the object's own position)."""
    START_OFF_ROADMAP = "start_off_roadmap"
    """No paths: no cell the robot may stand on lies within the start's reach."""
    NO_START = "no_start"
    """No paths: no ``--from`` and no views to start from."""
    NO_GRID = "no_grid"
    """No paths and no clearance to check: the store has no grid with obstacle layers."""


_PASSED = frozenset({PathState.CUT_OFF, PathState.TIGHT, PathState.NO_FREE_CELL})
"""States whose candidates have nothing to offer (tight ones unless allowed)."""


@dataclass(frozen=True)
class Offer:
    """One candidate's goal as the answer gives it."""

    candidate: int
    goal: Goal
    """The approach point nearest the object (what :meth:`GoalMaker.goal` gives)."""
    drive: Goal | None
    """Where the robot is sent: ``goal``, or the nearest reachable approach point
    (:attr:`PathState.DETOUR`); None: nothing keeps the promise (the candidate is passed
    over)."""
    state: PathState
    note: str | None
    """Why the goal is not plainly reachable (None: it is)."""
    distance: float | None
    """Metres along free space from the start to :attr:`drive` (None: no way, no paths)."""
    waypoints: np.ndarray | None
    """(M, 2) map (x, y) of that way (None likewise)."""

    @property
    def offerable(self) -> bool:
        return self.drive is not None

    def as_dict(self) -> dict[str, Any]:
        """The offer's JSON fields of a candidate row: the state, the note and, where the
        robot is sent elsewhere than ``goal``, that goal."""
        detour = self.drive is not None and self.drive is not self.goal
        return {
            "path_state": self.state.value,
            "path_note": self.note,
            "reachable_goal": self.drive.as_dict() if detour and self.drive is not None else None,
            "reachable_distance": self.distance if detour else None,
        }

    def passed(self, rank: int | None = None) -> dict[str, Any]:
        """The JSON of a candidate passed over: which, why."""
        out: dict[str, Any] = {"candidate": self.candidate}
        if rank is not None:
            out["rank"] = rank
        return {**out, "path_state": self.state.value, "reason": self.note}


@dataclass(eq=False)
class AnswerGoals:
    """The offers of one map's candidates for one start (each made once, on demand)."""

    goals: GoalMaker
    cmap: CandidateMap
    travel: Travel | None
    """Shortest paths from the start (None: no grid, or no start)."""
    paths: PathConfig
    _offers: dict[int, Offer] = field(default_factory=dict, repr=False)

    @property
    def clearance(self) -> float:
        return self.goals.config.clearance

    @property
    def usable(self) -> bool:
        """There are paths: a grid, a start, and a cell to stand on near it."""
        return self.travel is not None and self.travel.source is not None

    @cached_property
    def reachable(self) -> np.ndarray | None:
        """(nx, ny) bool: the cells the start reaches (None without paths)."""
        travel = self.travel
        if travel is None or not self.usable:
            return None
        roadmap = travel.roadmap
        return np.isfinite(travel.distance).reshape(roadmap.layout.shape)

    @cached_property
    def roadmap(self) -> Roadmap | None:
        if self.travel is not None:
            return self.travel.roadmap
        return Roadmap.for_goals(self.goals)

    def _xy(self, xy: tuple[float, ...] | np.ndarray) -> tuple[float, float]:
        x, y, _ = self.goals.in_frame(np.array([xy[0], xy[1], 0.0]))[0]
        return float(x), float(y)

    @cached_property
    def start_note(self) -> str | None:
        """Why there are no paths (None where there are): part of the answer, not an
        error."""
        if self.goals.free_space is None:
            return (
                "no paths and no clearance check: the store has no grid with obstacle layers "
                "(goals are the objects' own positions)"
            )
        if self.travel is None:
            return "no paths: no start (the store has no views); give --from x,y in free space"
        if self.travel.source is not None:
            return None
        x, y = self._xy(self.travel.start)
        head = (
            f"no paths: the start ({x:.2f}, {y:.2f}) is off the roadmap at --clearance "
            f"{self.clearance:g} m (no cell a robot of that radius may stand on within "
            f"{self.paths.start_reach:g} m of it)"
        )
        roadmap = self.travel.roadmap  # what self.roadmap is with a travel
        passable = np.flatnonzero(roadmap.passable.reshape(-1))
        if len(passable) == 0:
            return f"{head}; no cell of the grid keeps that clearance"
        centres = roadmap.centres(passable)
        gap = np.hypot(*(centres - self.travel.start).T)
        nx_, ny_ = self._xy(centres[np.argmin(gap)])
        return (
            f"{head}; the nearest roadmap cell is ({nx_:.2f}, {ny_:.2f}), {gap.min():.2f} m "
            "away: give --from x,y there"
        )

    def _paths_state(self) -> PathState:
        if self.goals.free_space is None:
            return PathState.NO_GRID
        return PathState.NO_START if self.travel is None else PathState.START_OFF_ROADMAP

    def offer(self, candidate: int) -> Offer:
        """The offer of ``candidate`` (made once)."""
        kept = self._offers.get(candidate)
        if kept is None:
            kept = self._offers[candidate] = self._make(candidate)
        return kept

    def _make(self, candidate: int) -> Offer:
        goal = self.goals.goal(self.cmap, candidate)
        if goal.keeps_clearance is False:
            return self._tight(goal)
        travel = self.travel
        if travel is None or not self.usable:
            return Offer(candidate, goal, goal, self._paths_state(), self.start_note, None, None)
        metres = travel.distance_to(goal)
        if math.isfinite(metres):
            points = travel.waypoints(goal)
            return Offer(candidate, goal, goal, PathState.REACHABLE, None, metres, points)
        reachable = cast(np.ndarray, self.reachable)  # an array wherever there are paths
        alt = self.goals.goal_within(self.cmap, candidate, reachable)
        c, reach = self.clearance, self.goals.config.reach
        x, y = self._xy(goal.position)
        cut = f"the nearest approach point ({x:.2f}, {y:.2f}) is cut off from the start"
        if alt is None:
            note = (
                f"unreachable: {cut}, and so is every approach point within {reach:g} m of the "
                f"object, at --clearance {c:g} m (its free space does not connect to the "
                "start's for a robot of that radius)"
            )
            return Offer(candidate, goal, None, PathState.CUT_OFF, note, None, None)
        ax, ay = self._xy(alt.position)
        off = math.dist(alt.position[:2], goal.target[:2])
        note = (
            f"{cut} at --clearance {c:g} m; sent to the nearest reachable one, "
            f"({ax:.2f}, {ay:.2f}), {off:.2f} m from the object"
        )
        metres = travel.distance_to(alt)
        points = travel.waypoints(alt)
        return Offer(candidate, goal, alt, PathState.DETOUR, note, metres, points)

    def _tight(self, goal: Goal) -> Offer:
        """The offer of a goal that cannot keep the clearance: passed over, or (allowed)
        offered without a way (the roadmap is the cells that keep it)."""
        c, reach = self.clearance, self.goals.config.reach
        if goal.approach:
            state = PathState.TIGHT
            note = (
                f"no free cell within {reach:g} m of the object keeps --clearance {c:g} m "
                f"(its goal keeps {goal.clearance:.2f} m)"
            )
        else:
            state = PathState.NO_FREE_CELL
            note = f"no free cell within {reach:g} m of the object (its goal is the object)"
        if not self.goals.config.allow_tight_goals:
            return Offer(goal.candidate, goal, None, state, note, None, None)
        note += "; offered anyway (--allow-tight-goals), with no way that keeps the clearance"
        return Offer(goal.candidate, goal, goal, state, note, None, None)

    def offerable(self) -> np.ndarray:
        """(N,) bool: the candidates with a goal to offer, for the whole map at once (the
        rule of :meth:`offer`, through :func:`care_maps.query.travel.approach_cells`)."""
        n = self.cmap.num_candidates
        if self.roadmap is None:
            return np.ones(n, bool)
        xy, reach = self.cmap.positions[:, :2], self.goals.config.reach
        keeps = approach_cells(self.roadmap, xy, reach) >= 0
        if self.goals.config.allow_tight_goals:
            if not self.usable:
                return np.ones(n, bool)
            reachable = cast(np.ndarray, self.reachable)  # an array wherever there are paths
            near = approach_cells(Roadmap(self.roadmap.layout, reachable), xy, reach)
            return ~keeps | (near >= 0)
        if not self.usable:
            return keeps
        reachable = cast(np.ndarray, self.reachable)
        return approach_cells(Roadmap(self.roadmap.layout, reachable), xy, reach) >= 0


@dataclass(frozen=True)
class Offered:
    """The next goal an answer offers, and the candidates passed over on the way to it."""

    choice: Choice | None
    """The rule's choice (``candidate`` -1: none left with a goal to offer); None for the
    first of a ranking (:func:`first_offer`)."""
    offer: Offer | None
    passed: list[Offer]
    """The candidates the rule picked first and that had nothing to offer, in order."""
    left_out: int = 0
    """Candidates with nothing to offer left out at once after :data:`MAX_PASSED`."""


def offer_next(
    answer: AnswerGoals,
    query: Any,
    visited: Sequence[int] | np.ndarray = (),
    *,
    skip: list[int] | None = None,
    **rule: Any,
) -> Offered:
    """:func:`care_maps.replan.attempts.next_goal` (``rule``: its keyword arguments, the rule's
    ``config`` among them) that passes over a
    candidate with no goal to offer and asks the rule again without it (without the
    exclusion radius: a neighbouring cell may well have a goal); ``skip``: candidates
    already passed over (a walk of attempts). The first attempt stays max confidence among
    the rest."""
    skip = list(skip or [])
    passed: list[Offer] = []
    left_out = 0
    while True:
        choice = next_goal(answer.cmap, query, visited, skip=skip, **rule)
        if choice.candidate < 0:
            return Offered(choice, None, passed, left_out)
        offer = answer.offer(choice.candidate)
        if offer.offerable:
            return Offered(choice, offer, passed, left_out)
        passed.append(offer)
        skip.append(choice.candidate)
        if len(passed) == MAX_PASSED:
            rest = set(np.flatnonzero(~answer.offerable()).tolist()) - set(skip)
            left_out = len(rest)
            skip.extend(sorted(rest))


def first_offer(answer: AnswerGoals, order: np.ndarray) -> Offered:
    """The first attempt of a ranking (``order``: candidate ids, best first): the
    best-ranked candidate with a goal to offer, and those passed over before it."""
    passed: list[Offer] = []
    order = np.asarray(order, np.int64).reshape(-1)
    for i, c in enumerate(order):
        offer = answer.offer(int(c))
        if offer.offerable:
            return Offered(None, offer, passed)
        passed.append(offer)
        if len(passed) == MAX_PASSED:
            ok = answer.offerable()[order[i + 1 :]]
            later = np.flatnonzero(ok)
            if len(later) == 0:
                return Offered(None, None, passed, len(ok))
            best = int(order[i + 1 + later[0]])
            return Offered(None, answer.offer(best), passed, int(later[0]))
    return Offered(None, None, passed)
