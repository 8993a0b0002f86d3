"""A query's answer, assembled once for the CLI and the Python API alike: the map's
candidates ranked by confidence with their measures, each one's goal and the way to it, and
the first attempt (the best-ranked candidate with a goal that keeps the clearance and is
reachable), with what was passed over and why.

:func:`answer_query` returns a :class:`QueryAnswer`; ``care query --json`` prints its
:meth:`QueryAnswer.as_dict`, and ``care replan`` builds on :func:`answer_goals` and
:func:`offered_dict` the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from care_maps.core.maps import MapKind
from care_maps.query.goals import GoalConfig
from care_maps.query.paths import PathConfig
from care_maps.replan.batch import BatchConfig

__all__ = [
    "QueryAnswer",
    "Ranking",
    "answer_goals",
    "answer_query",
    "candidate_row",
    "first_position",
    "goal_maker",
    "offered_dict",
    "position_in_frame",
    "rank_and_offer",
    "travel_from",
]


@dataclass(frozen=True)
class QueryAnswer:
    """``care query``'s answer for one text."""

    query: str
    """The text asked."""
    class_name: str
    """The class it resolved to (free text: the text itself)."""
    method: str
    """How the text was matched (``vocabulary``, or the free-text way)."""
    frame_id: str
    """The frame of every position, goal and path."""
    candidates: list[dict[str, Any]]
    """The best-ranked candidates (``top`` of them): rank, id, measures, position, goal,
    distance and what the offer says."""
    first: dict[str, Any]
    """The first attempt: candidate, rank, goal, path, its length, the start, the candidates
    passed over and the note on the way."""
    target: Any = field(compare=False, repr=False)
    """The resolved :class:`care_maps.query.openvocab.QueryTarget` (its map inside)."""
    goals: Any = field(compare=False, repr=False)
    """The offers of the map's candidates (:class:`care_maps.replan.answer.AnswerGoals`)."""
    ranking: Ranking = field(compare=False, repr=False)
    offered: Any = field(compare=False, repr=False)
    """The first attempt as :func:`care_maps.replan.answer.first_offer` gave it."""

    def as_dict(self) -> dict[str, Any]:
        """The JSON of ``care query --json``."""
        return {
            "query": self.query,
            "class": self.class_name,
            "method": self.method,
            "frame_id": self.frame_id,
            "candidates": self.candidates,
            **self.first,
        }


def answer_query(
    store: Path,
    text: str,
    *,
    kind: MapKind = MapKind.INSTANCES,
    top: int = BatchConfig.top,
    goal: GoalConfig | None = None,
    paths: PathConfig | None = None,
    weights: Path | None = None,
    target: Any = None,
) -> QueryAnswer:
    """The answer for ``text`` on the store's ``kind`` map with the ``top`` best-ranked
    candidates, goals made with ``goal`` and paths from ``paths.start`` (default: the
    recording's first pose). ``target``: the query already resolved
    (:func:`care_maps.query.openvocab.open_query`), else resolved here (free text through the
    store's own text encoder; ``weights`` if its model moved)."""
    if target is None:
        from care_maps.query import load_map
        from care_maps.query.openvocab import open_query

        target = open_query(load_map(store, MapKind(kind).value, weights=weights), text)
    goal, paths = goal or GoalConfig(), paths or PathConfig()
    answer = answer_goals(store, target.cmap, goal, paths)
    ranking, first = rank_and_offer(answer, target.confidence())
    rows = [candidate_row(answer, target, ranking, int(c)) for c in ranking.order[:top]]
    return QueryAnswer(
        query=text,
        class_name=target.match.names[0],
        method=target.match.method,
        frame_id=answer.goals.frame_id,
        candidates=rows,
        first=offered_dict(answer, first, ranking),
        target=target,
        goals=answer,
        ranking=ranking,
        offered=first,
    )


def goal_maker(store: Path, config: GoalConfig) -> Any:
    """The store's :class:`care_maps.query.goals.GoalMaker`."""
    from care_maps.query.goals import GoalMaker

    return GoalMaker.from_store(store, config)


def travel_from(store: Path, goals: Any, config: PathConfig) -> Any:
    """Shortest paths over the store's free space (:class:`care_maps.query.paths.Travel`) from
    ``config.start``, else the recording's first pose; None without a grid or a start."""
    from care_maps.query.paths import Roadmap

    roadmap = Roadmap.for_goals(goals)
    given = cast("tuple[float, float] | None", config.start)  # x, y: PathConfig checks it
    start = given or first_position(store)
    if roadmap is None or start is None:
        return None
    return roadmap.travel(start, config.start_reach)


def answer_goals(store: Path, cmap: Any, goal: GoalConfig, paths: PathConfig) -> Any:
    """The offers of the map's candidates (:class:`care_maps.replan.answer.AnswerGoals`): goals, and
    paths from ``paths.start``, else the recording's first pose."""
    from care_maps.replan.answer import AnswerGoals

    goals = goal_maker(store, goal)
    return AnswerGoals(goals, cmap, travel_from(store, goals, paths), paths)


def first_position(store: Path) -> tuple[float, float] | None:
    """The recording's first camera position (:meth:`care_maps.core.store.Store.first_position`)."""
    from care_maps.core.store import Store

    return Store(store).first_position()


class Ranking:
    """A query's candidates by confidence (ties by lower id), and each one's rank."""

    def __init__(self, conf: Any) -> None:
        import numpy as np

        from care_maps.query import rank_by_confidence

        self.conf = conf
        self.order = rank_by_confidence(conf[None])[0]
        self.rank = np.empty(len(self.order), np.int64)
        self.rank[self.order] = np.arange(1, len(self.order) + 1)


def rank_and_offer(answer: Any, conf: Any) -> tuple[Ranking, Any]:
    """The ranking and its first attempt (:func:`care_maps.replan.answer.first_offer`)."""
    from care_maps.replan.answer import first_offer

    ranking = Ranking(conf)
    return ranking, first_offer(answer, ranking.order)


def position_in_frame(answer: Any, candidate: int) -> list[float]:
    """The candidate's position in the goals' frame."""
    return [float(v) for v in answer.goals.in_frame(answer.cmap.positions[candidate])[0]]


def candidate_row(answer: Any, target: Any, ranking: Ranking, c: int) -> dict:
    """One candidate of ``care query``'s answer: measures, position and goal (in the goals'
    frame), the metres to the goal (None: no way to it) and what its offer says."""
    cmap, offer = target.cmap, answer.offer(c)
    plain = offer.drive is offer.goal
    return {
        "rank": int(ranking.rank[c]),
        "candidate": c,
        "confidence": float(ranking.conf[c]),
        "entropy": float(cmap.entropy[c]),
        "stderr": float(cmap.stderr[c]),
        "pwkl": float(cmap.pwkl[c]),
        "num_views": int(cmap.num_views[c]),
        "position": [round(v, 3) for v in position_in_frame(answer, c)],
        "goal": offer.goal.as_dict(),
        "distance": offer.distance if plain else None,
        **offer.as_dict(),
    }


def offered_dict(answer: Any, offered: Any, ranking: Ranking | None = None) -> dict:
    """The answer's first (or next) attempt: the candidate, the goal the robot is sent to,
    the way there (``nav_msgs/Path`` JSON in the goals' frame, ``distance`` and
    ``path_length`` in metres, None: no way), the start (x, y, z in the goals' frame), the
    candidates passed over and why, and the note on the way (None: plainly reachable)."""
    from care_maps.query.paths import nav_path, path_length

    offer = offered.offer
    rank = (lambda c: int(ranking.rank[c])) if ranking is not None else (lambda c: None)
    travel = answer.travel
    start = None
    if travel is not None:
        start = [float(v) for v in answer.goals.in_frame([*travel.start, 0.0])[0]]
    points = None if offer is None else offer.waypoints
    note = answer.start_note if offer is None else offer.note
    if offer is None and (offered.passed or offered.left_out):
        note = (
            "no candidate left has a goal that keeps --clearance "
            f"{answer.clearance:g} m and is reachable (see passed_over)"
        )
    return {
        "candidate": None if offer is None else offer.candidate,
        "rank": None if offer is None else rank(offer.candidate),
        "goal": None if offer is None else offer.drive.as_dict(),
        "path_state": None if offer is None else offer.state.value,
        "passed_over": [p.passed(rank(p.candidate)) for p in offered.passed],
        "passed_over_more": offered.left_out,
        "distance": None if points is None else offer.distance,
        "path": None if points is None else nav_path(offer.drive, points),
        "path_length": None if points is None else path_length(points),
        "start": start,
        "path_note": note,
    }
