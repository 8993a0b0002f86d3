"""``care explore`` on a store: read what :mod:`care_maps.query.explore` needs, and give its views as
goals a navigation stack reads.

Everything comes from the store alone (no ground truth): the grid map's measures
(``cells.parquet``), its free space and obstacle heights, the recording's camera height
(the median of its views') and first pose (where the robot starts), and the goals' frame and
stamp (:class:`care_maps.query.goals.GoalMaker`, the frame ``care frame`` prints). A viewpoint must
be reachable from the start over free space with the robot's clearance
(:class:`care_maps.query.paths.Roadmap`); where the start is off free space, any free cell with the
clearance may serve, and the answer says so.

Each view is given twice: ``goal``, where the robot drives (a ``geometry_msgs/PoseStamped``
on the floor, facing the target, like ``care query``'s goals), and ``camera``, the camera
pose that sees the target (optical frame, pitched toward it) for a pan-tilt head or a
hand-held camera. ``goals`` lists the robot poses in proposal order (the most uncertain
place first), ready for a ``NavigateThroughPoses`` request.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from care_maps.core.errors import QueryError
from care_maps.core.maps import MapKind
from care_maps.core.store import Store
from care_maps.fuse.layout import GridLayout
from care_maps.query.explore import (
    ExploreConfig,
    Viewpoint,
    cell_uncertainty,
    choose_views,
    raster,
)
from care_maps.query.goals import FreeSpace, Goal, GoalConfig, GoalMaker, stamped_poses
from care_maps.query.map import CandidateMap, load_map
from care_maps.query.paths import PathConfig, Roadmap, Travel

__all__ = [
    "Exploration",
    "ExploreInputs",
    "camera_pose_stamped",
    "explore_store",
    "read_inputs",
    "recording_camera_height",
]


@dataclass(frozen=True, eq=False)
class Exploration:
    """The views proposed for one store, with what they were chosen from."""

    config: ExploreConfig
    views: list[Viewpoint]
    goals: list[Goal]
    """Where the robot drives for each view (on the floor, facing the target)."""
    distances: list[float | None]
    """Metres along free space from the start to each view (None: no paths)."""
    cmap: CandidateMap
    """The grid map."""
    layout: GridLayout
    uncertainty: np.ndarray
    """(N,) each cell's uncertainty in [0, 1] (:func:`care_maps.query.explore.cell_uncertainty`)."""
    camera_height: float
    start: tuple[float, float] | None
    path_note: str | None
    """Why viewpoints were not restricted to what the start reaches (None: they were)."""

    def as_dict(self) -> dict:
        """The answer as JSON: each view's goal, camera pose and target; ``goals``, the
        robot poses alone, in order."""
        views = []
        for rank, (view, goal, dist) in enumerate(
            zip(self.views, self.goals, self.distances, strict=True), 1
        ):
            cell = view.target_cell
            top = int(self.cmap.top_classes[cell, 0]) if cell >= 0 else -1
            forward = view.camera[:3, 2]
            views.append(
                {
                    "rank": rank,
                    "target": [round(v, 4) for v in view.target],
                    "target_cell": cell,
                    "target_class": self.cmap.vocabulary[top] if top >= 0 else None,
                    "target_uncertainty": float(self.uncertainty[cell]) if cell >= 0 else None,
                    "covered": view.uncertainty,
                    "cells": view.cells,
                    "goal": goal.as_dict(),
                    "camera": camera_pose_stamped(goal, view.camera),
                    **(
                        {"world_camera": camera_pose_stamped(goal, view.camera, in_world=True)}
                        if goal.map_from_world is not None
                        else {}
                    ),
                    "camera_height": self.camera_height,
                    "pitch_deg": math.degrees(math.asin(float(np.clip(forward[2], -1, 1)))),
                    "distance": dist,
                }
            )
        return {
            "views": views,
            "goals": [g.pose_stamped() for g in self.goals],
            "requested": self.config.views,
            "measures": [str(m) for m in self.config.measures],
            "start": None if self.start is None else list(self.start),
            "path_note": self.path_note,
        }


def camera_pose_stamped(goal: Goal, camera: np.ndarray, *, in_world: bool = False) -> dict:
    """The (4, 4) map-frame ``camera`` pose as ``geometry_msgs/PoseStamped`` JSON in
    ``goal``'s frame (or, ``in_world``, the recording's world frame), as the goal is given."""
    pose, frame_id = np.asarray(camera, np.float64), goal.frame_id
    if in_world and goal.map_from_world is not None:
        pose, frame_id = np.linalg.solve(goal.map_from_world, pose), goal.world_frame
    elif goal.frame_from_map is not None:
        pose = goal.frame_from_map @ pose
    return stamped_poses(pose[None], frame_id, goal.stamp_ns)[0]


def recording_camera_height(store: Path) -> float:
    """Median height (m above the map's floor) of the recording's cameras."""
    poses = Store(store).poses()
    height = float(np.median(poses[:, 2, 3])) if len(poses) else math.nan
    if not (math.isfinite(height) and height > 0):
        msg = (
            f"{store}: the recording's cameras are not above the map's floor (median height "
            f"{height:.2f} m); give --camera-height"
        )
        raise QueryError(msg)
    return height


def _clearance(space: FreeSpace, ix: int, iy: int) -> float:
    """Metres from cell (ix, iy) to the nearest obstacle (inf: none), as goals report it."""
    margin = 8
    while True:
        metres, exact = space.clearance(slice(ix, ix + 1), slice(iy, iy + 1), margin)
        if float(metres[0, 0]) <= exact:
            return float(np.float32(metres[0, 0]))
        margin *= 2


def _travel(store: Path, roadmap: Roadmap, config: PathConfig) -> Travel | None:
    """Paths from ``config.start``, else the recording's first pose (None: no views)."""
    given = cast("tuple[float, float] | None", config.start)  # x, y: PathConfig checks it
    start = given or Store(store).first_position()
    return None if start is None else roadmap.travel(start, config.start_reach)


@dataclass(frozen=True, eq=False)
class ExploreInputs:
    """What views are chosen from, read from a store: the grid map and its rasters."""

    cmap: CandidateMap
    """The grid map."""
    space: FreeSpace
    layout: GridLayout
    stand: np.ndarray
    """(nx, ny) bool: where a viewpoint may stand (free, with the robot's clearance,
    reachable from the start)."""
    heights: np.ndarray
    """(nx, ny) top of each cell (m above the floor; 0 unobserved)."""
    cell_ids: np.ndarray
    """(nx, ny) grid candidate of each cell (-1: none)."""
    camera_height: float
    goals: GoalMaker
    travel: Travel | None
    path_note: str | None

    def choose(self, values: np.ndarray, config: ExploreConfig) -> list[Viewpoint]:
        """Viewpoints that look at the most of per-cell ``values`` (N,)."""
        return choose_views(
            raster(self.layout, self.cmap.positions[:, :2], values), self.heights, self.stand,
            self.layout, camera_height=self.camera_height, config=config, cell_ids=self.cell_ids,
        )  # fmt: skip

    def goal(self, view: Viewpoint) -> Goal:
        """Where the robot drives for ``view``: its viewpoint on the floor, facing the target."""
        size, (ox, oy) = self.layout.cell_size, self.layout.origin
        ix, iy = (
            math.floor((view.position[0] - ox) / size),
            math.floor((view.position[1] - oy) / size),
        )
        g = self.goals
        return Goal(
            view.target_cell, g.frame_id, g.stamp_ns, view.target, (*view.position, 0.0),
            view.yaw, True, _clearance(self.space, ix, iy), g.map_from_world, g.world_frame,
            g.frame_from_map,
        )  # fmt: skip


def read_inputs(
    store: Path,
    config: ExploreConfig | None = None,
    goal_config: GoalConfig | None = None,
    path_config: PathConfig | None = None,
) -> ExploreInputs:
    """Read the grid, free space, camera height, start and goal frame of ``store``."""
    store = Path(store)
    config, goal_config = config or ExploreConfig(), goal_config or GoalConfig()
    path_config = path_config or PathConfig()
    Store(store)  # a complete store, or one line saying what to do
    space = FreeSpace.from_store(store)
    if space is None:
        msg = f"{store}: no grid map with free space; run `care fuse grid {store}` first"
        raise QueryError(msg)
    cmap = load_map(store, MapKind.GRID)
    roadmap = Roadmap.from_free_space(space, goal_config.clearance)
    travel = _travel(store, roadmap, path_config)
    stand, note = roadmap.passable, None
    if travel is not None and travel.source is not None:
        stand = stand & np.isfinite(travel.distance).reshape(space.layout.shape)
    elif travel is not None:
        x, y = travel.start
        note = (
            f"no free cell keeps --clearance within {path_config.start_reach} m of the start "
            f"({x:.2f}, {y:.2f}): viewpoints may lie anywhere in free space; give --from x,y"
        )
    xy = cmap.positions[:, :2]
    return ExploreInputs(
        cmap, space, space.layout, stand,
        np.maximum(raster(space.layout, xy, cmap.positions[:, 2]), 0.0),
        raster(space.layout, xy, np.arange(cmap.num_candidates), fill=-1).astype(np.int64),
        config.camera_height or recording_camera_height(store),
        GoalMaker.from_store(store, goal_config), travel, note,
    )  # fmt: skip


def explore_store(
    store: Path,
    config: ExploreConfig | None = None,
    goal_config: GoalConfig | None = None,
    path_config: PathConfig | None = None,
) -> Exploration:
    """Propose ``config.views`` views for ``store`` (its grid map; module docstring)."""
    config = config or ExploreConfig()
    inputs = read_inputs(store, config, goal_config, path_config)
    uncertainty = cell_uncertainty(inputs.cmap, config)
    views = inputs.choose(uncertainty, config)
    goals = [inputs.goal(view) for view in views]
    travel = inputs.travel
    distances = [
        None if travel is None or not math.isfinite(d := travel.distance_to(g)) else d
        for g in goals
    ]
    return Exploration(
        config, views, goals, distances, inputs.cmap, inputs.layout, uncertainty,
        inputs.camera_height, None if travel is None else travel.start, inputs.path_note,
    )  # fmt: skip
