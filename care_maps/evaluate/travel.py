"""Where the evaluation's robot walks: one scene's roadmap, the goal of every candidate, the
start of every query (:class:`care_maps.evaluate.config.TravelStart`).

Read once per scene and map (the store's free space and first pose), then each query set
(a room, or the scene) gets its :class:`care_maps.replan.attempts.Walk`: the distances from each
query's start, and from any goal to the others on demand (:class:`care_maps.query.travel.Legs`).

A scene has no travel (NaN path length and SPL, said in the report) when its store has no
grid with obstacle layers, when the start is the first pose and the store has no views, or
when that pose has no passable cell within :attr:`care_maps.query.paths.PathConfig.start_reach`.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from care_maps.core.store import Store
from care_maps.evaluate.config import EvalConfig, TravelStart
from care_maps.evaluate.success import QuerySet
from care_maps.query.goals import GoalConfig, GoalMaker
from care_maps.query.map import CandidateMap
from care_maps.query.paths import PathConfig, Roadmap
from care_maps.query.travel import Legs, approach_cells, largest_region
from care_maps.replan.attempts import Walk

__all__ = ["SceneTravel", "SceneWalks", "scene_travel"]


@dataclass(frozen=True, eq=False)
class SceneTravel:
    """One scene map's walks: its legs between goals and how its queries start."""

    legs: Legs
    """Distances to the goals of every candidate of the scene's map."""
    rule: TravelStart
    start: tuple[float, float] | None
    """The first pose (``first_pose`` rule)."""
    region: np.ndarray
    """Flat cells a free-space start is drawn from (``free_space`` rule)."""
    seed: int
    _kept: dict = field(default_factory=dict, repr=False)

    def walk(self, qs: QuerySet, *names: object) -> Walk | None:
        """The walk of ``qs``' queries (``names``: the scene, map, protocol, seeding the
        free-space starts with the unit and the query); None without a start. Searches are
        run and kept on the whole map's legs, so rooms and protocols share them."""
        ids = np.asarray(qs.candidate_ids, np.int64)
        if self.rule == TravelStart.FIRST_POSE:
            if "first" not in self._kept:
                start_xy = cast("tuple[float, float]", self.start)  # the first_pose rule has one
                self._kept["first"] = self.legs.from_point(start_xy)
            start = np.broadcast_to(self._kept["first"][ids], qs.success.shape)
        else:
            if len(self.region) == 0:
                return None
            cells = [self._start_cell(*names, qs.unit, q) for q in qs.queries]
            start = self.legs.from_cells(np.array(cells, np.int64))[:, ids]
        goal_cell = self.legs.goal_cell[ids]

        def legs(local: np.ndarray) -> np.ndarray:
            return self.legs.from_cells(goal_cell[local])[:, ids]

        return Walk(np.array(start, np.float64), legs)

    def _start_cell(self, *parts: object) -> int:
        key = zlib.crc32("\x1f".join(map(str, ("start", *parts))).encode())
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, key]))
        return int(self.region[rng.integers(len(self.region))])


class SceneWalks:
    """A scene's roadmap and starts, built once for both maps (:meth:`for_map` each)."""

    def __init__(self, store: Path, config: EvalConfig) -> None:
        self.config = config
        self.roadmap: Roadmap | None = None
        self.start: tuple[float, float] | None = None
        self.region = np.zeros(0, np.int64)
        if config.travel_start == TravelStart.OFF:
            return
        self.goals = GoalConfig(clearance=config.clearance)
        roadmap = Roadmap.for_goals(GoalMaker.from_store(store, self.goals))
        if roadmap is None:
            return
        if config.travel_start == TravelStart.FIRST_POSE:
            self.start = Store(store).first_position()
            if self.start is None or roadmap.entry(self.start, PathConfig.start_reach) is None:
                return
        else:
            self.region = largest_region(roadmap)
        self.roadmap = roadmap

    def for_map(self, cmap: CandidateMap) -> SceneTravel | None:
        """The walks to ``cmap``'s candidates' goals; None: the scene has no travel."""
        if self.roadmap is None:
            return None
        cells = approach_cells(self.roadmap, cmap.positions[:, :2], self.goals.reach)
        legs = Legs(self.roadmap, cells, PathConfig.start_reach)
        return SceneTravel(
            legs, self.config.travel_start, self.start, self.region, self.config.seed
        )


def scene_travel(store: Path, cmap: CandidateMap, config: EvalConfig) -> SceneTravel | None:
    """The walks of ``cmap`` (a map of ``store``) under ``config``; None: no travel."""
    return SceneWalks(store, config).for_map(cmap)
