"""Goals a navigation stack can use: a pose in the map frame, facing the object, in free space.

A candidate is a place where the object may be (a cell centre, an instance centre); a robot
cannot drive *into* it. :class:`GoalMaker` turns a candidate into a
``geometry_msgs/PoseStamped``-shaped goal:

- ``header.frame_id``: the recording's world frame when it has z up (the map frame differs
  from it by the floor's height at most), else the map frame, ``care_map`` unless
  ``frame_id`` names it, which the user publishes as a static transform (then the goal also
  comes in the world frame, with ``map_from_world``; :mod:`care_maps.query.publish`);
- ``header.stamp``: the stamp of the last view fused into the map (the map's time);
- ``pose.position``: an *approach point* on the floor (z = 0): the free cell nearest to the
  object that keeps ``clearance`` metres from every obstacle, searched within ``reach`` of the
  object (the grid success radius of ``docs/method.md``: from there the object counts as found);
  without a grid, or when no free cell lies within reach, the object's own position;
- ``pose.orientation``: a yaw facing the object from the approach point (identity when the goal
  is the object itself).

Free space comes from the grid's own layers (``cells.parquet``): a cell the depth saw with
nothing above ``obstacle_height`` is free, an ``obstacle`` cell is not, an unseen cell is not
(the robot cannot know it is free). Instance goals use the store's grid when it has one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pyarrow.parquet as pq

from care_maps.core.errors import QueryError
from care_maps.core.frames import DEFAULT_WORLD_FRAME, check_frame_id
from care_maps.core.keys import GRID_SHAPE_KEY
from care_maps.core.store import META_FILE, StoreMeta, as_numpy, read_map_frame, read_table
from care_maps.fuse.layout import CELLS_TABLE, GridLayout
from care_maps.geometry.transforms import rotation_quaternion
from care_maps.query.map import CandidateMap
from care_maps.query.publish import MAP_FRAME_ID, FramePlan, frame_plan

__all__ = [
    "MAP_FRAME_ID",
    "Approach",
    "FreeSpace",
    "Goal",
    "GoalConfig",
    "GoalMaker",
    "squared_distances",
    "stamped_poses",
]


@dataclass(frozen=True)
class GoalConfig:
    """How a candidate becomes a goal pose."""

    clearance: float = 0.3
    """Metres the approach point keeps from every obstacle cell (about a robot's radius)."""
    reach: float = 1.0
    """Farthest (m, floor plane) the approach point may lie from the object: the grid success
    radius of ``docs/method.md``."""
    frame_id: str | None = None
    """Frame of the goals: the recording's world frame's name gives them in the world frame;
    any other name is the map frame's, published as a static transform (``care frame``).
    Default: the world frame when it has z up, else ``care_map``."""
    allow_tight_goals: bool = False
    """Offer a candidate whose goal cannot keep the clearance (no free cell within reach keeps
    it: the goal is the one with the most, flagged); by default such a candidate is passed
    over for the next one whose goal keeps the promise."""

    def __post_init__(self) -> None:
        if not (math.isfinite(self.clearance) and self.clearance >= 0):
            msg = f"goal clearance must be a finite distance >= 0 m, got {self.clearance}"
            raise QueryError(msg)
        if not (math.isfinite(self.reach) and self.reach > 0):
            msg = f"goal reach must be a finite distance > 0 m, got {self.reach}"
            raise QueryError(msg)
        if self.frame_id is not None:
            check_frame_id(self.frame_id)  # the Python API refuses what the CLI refuses


@dataclass(frozen=True)
class Goal:
    """Where to send the robot for one candidate."""

    candidate: int
    frame_id: str
    stamp_ns: int
    target: tuple[float, float, float]
    """Where the object is (candidate position, map frame; :meth:`as_dict` gives it in
    ``frame_id``)."""
    position: tuple[float, float, float]
    """Where to go: the approach point, or the target when there is none."""
    yaw: float
    """Heading (rad, about z) facing the target from ``position``; 0 when they coincide."""
    approach: bool
    """``position`` is a free-space approach point (else it is the target itself)."""
    clearance: float | None
    """Distance (m) from ``position`` to the nearest obstacle cell; None without a grid."""

    map_from_world: np.ndarray | None = None
    """(4, 4) the store's map frame, where goals are not in the world frame (None: they are)."""
    world_frame: str = DEFAULT_WORLD_FRAME
    """The recording's world frame name."""
    frame_from_map: np.ndarray | None = None
    """(4, 4) from the map frame to ``frame_id`` (None: ``frame_id`` is the map frame)."""
    keeps_clearance: bool | None = None
    """``position`` keeps :attr:`required_clearance` from every obstacle cell (False: no free
    cell within reach does, or there is none; None: no grid to tell)."""
    required_clearance: float | None = None
    """The clearance (m) the goal was asked to keep (``GoalConfig.clearance``)."""

    def in_frame(self, xyz: tuple[float, ...] | np.ndarray) -> np.ndarray:
        """(3,) map point ``xyz`` in ``frame_id``: every coordinate of an answer is given
        in the frame of its goal, so one transform places all of them."""
        point = np.append(np.asarray(xyz, np.float64)[:3], 1.0)
        return point[:3] if self.frame_from_map is None else (self.frame_from_map @ point)[:3]

    def pose_matrix(self) -> np.ndarray:
        """(4, 4) the goal pose in the map frame: at ``position``, yawed by ``yaw`` about z."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        out = np.eye(4)
        out[:2, :2] = [[c, -s], [s, c]]
        out[:3, 3] = self.position
        return out

    def pose_stamped(self, *, in_world: bool = False) -> dict:
        """The goal as ``geometry_msgs/PoseStamped`` JSON (ROS 2 field names), in the map
        frame or (``in_world``) in the recording's world frame."""
        pose, frame_id = self.pose_matrix(), self.frame_id
        if in_world and self.map_from_world is not None:
            pose, frame_id = np.linalg.solve(self.map_from_world, pose), self.world_frame
        elif self.frame_from_map is not None:
            pose = self.frame_from_map @ pose
        return stamped_poses(pose[None], frame_id, self.stamp_ns)[0]

    def as_dict(self) -> dict:
        """JSON of the goal: the PoseStamped and the target (the object's position) in the
        same frame, ``header.frame_id`` (and, where the map frame is not the world frame, both
        again in the world frame with the transform), how the point was found and whether it
        keeps the clearance asked for."""
        out = {
            "pose_stamped": self.pose_stamped(),
            "target": [float(v) for v in self.in_frame(self.target)],
            "yaw": self.yaw,
            "approach": self.approach,
            "clearance": self.clearance,
            "required_clearance": self.required_clearance,
            "clearance_ok": self.keeps_clearance,
        }
        if self.map_from_world is not None:
            world = np.linalg.solve(self.map_from_world, np.append(self.target, 1.0))[:3]
            out["world_pose_stamped"] = self.pose_stamped(in_world=True)
            out["world_target"] = [float(v) for v in world]
            out["map_from_world"] = self.map_from_world.reshape(-1).tolist()
        return out


def stamped_poses(poses: np.ndarray, frame_id: str, stamp_ns: int) -> list[dict]:
    """(M, 4, 4) poses as ``geometry_msgs/PoseStamped`` JSON (ROS 2 field names), one header
    for all: a goal is one of them, a ``nav_msgs/Path`` many (:mod:`care_maps.query.paths`)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    quats = rotation_quaternion(poses[:, :3, :3]) if len(poses) else np.empty((0, 4))
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return [
        {
            "header": {"frame_id": frame_id, "stamp": {"sec": sec, "nanosec": nanosec}},
            "pose": {
                "position": dict(zip("xyz", (float(v) for v in pose[:3, 3]), strict=True)),
                "orientation": dict(zip("xyzw", (float(v) for v in quat), strict=True)),
            },
        }
        for pose, quat in zip(poses, quats, strict=True)
    ]


def squared_distances(blocked: np.ndarray, below: int | None = None) -> np.ndarray:
    """(nx, ny) int64: the squared distance (in cells) from each cell to the nearest
    ``True`` of ``blocked`` ((nx, ny) bool, at least one ``True``). With ``below``, only
    the values under it are exact; the others are only said to be at least ``below`` (the
    passes stop there: :meth:`care_maps.query.paths.Roadmap.from_free_space` asks which
    cells are nearer than the robot's radius).

    The exact Euclidean distance transform: its square root is scipy's
    ``ndimage.distance_transform_edt(~blocked)`` bit for bit (the root of the same integer,
    tested against it), without importing scipy (0.2 s at every query's start). Down each
    column the distance to the column's nearest obstacle; then along each row the least of
    ``g(y')^2 + (y - y')^2`` over growing offsets, stopping once an offset's square reaches
    every cell's current value (further ones cannot lower it): as many passes as the
    largest clearance in cells, which is what a goal's window holds.
    """
    nx, ny = blocked.shape
    far = 2 * (nx + ny) + 2  # farther than any cell: a column without obstacles
    rows = np.arange(nx, dtype=np.int64)[:, None]
    before = np.maximum.accumulate(np.where(blocked, rows, -far), axis=0)
    after = np.minimum.accumulate(np.where(blocked, rows, far)[::-1], axis=0)[::-1]
    down = np.minimum(rows - before, after - rows)
    column = down * down
    out = column.copy()
    for d in range(1, ny):
        step = d * d
        if step >= (out.max() if below is None else below):
            break
        np.minimum(out[:, d:], column[:, :-d] + step, out=out[:, d:])
        np.minimum(out[:, :-d], column[:, d:] + step, out=out[:, :-d])
    return out


class Approach(NamedTuple):
    """An approach point found around an object."""

    x: float
    y: float
    clearance: float
    """Metres to the nearest obstacle cell (float32 precision, as goals report it)."""
    keeps: bool
    """``clearance`` is at least the one asked for."""


@dataclass(frozen=True)
class FreeSpace:
    """The grid's free cells and its obstacles; each cell's clearance (distance to the nearest
    obstacle) is computed where a goal is sought, not over the whole floor.

    A goal needs the clearance of the cells within ``reach`` of one object. A Euclidean
    distance transform of the whole grid cost 0.17 s at 1M cells and 0.7 s at 4M (a
    100 m x 100 m floor) on every ``care query``; :meth:`clearance` transforms the reach
    window and a margin of obstacles around it instead, widening the margin only while a value
    the goal depends on could still be changed by an obstacle beyond it. The goal is the one
    the whole grid's transform gives, clearance included, bit for bit (tested against it).
    """

    layout: GridLayout
    free: np.ndarray
    """(nx, ny) bool: seen and not an obstacle."""
    blocked: np.ndarray
    """(nx, ny) bool: obstacle cells."""

    @classmethod
    def from_cells(
        cls, layout: GridLayout, ix: np.ndarray, iy: np.ndarray, obstacle: np.ndarray
    ) -> FreeSpace:
        nx, ny = layout.shape
        seen = np.zeros((nx, ny), bool)
        blocked = np.zeros((nx, ny), bool)
        seen[ix, iy] = True
        blocked[ix[obstacle], iy[obstacle]] = True
        return cls(layout, seen & ~blocked, blocked)

    def clearance(self, xs: slice, ys: slice, margin: int) -> tuple[np.ndarray, float]:
        """Metres from each cell of ``[xs, ys]`` to the nearest obstacle within ``margin``
        cells of that window (float64; inf where there is none), and the distance up to which
        these are every obstacle's: an obstacle beyond the margin is at least ``(margin + 1)``
        cells away (inf once the margin reaches the grid's edges, where nothing lies beyond).
        A value at most that distance is the whole grid's own.
        """
        nx, ny = self.layout.shape
        x0, x1 = max(xs.start - margin, 0), min(xs.stop + margin, nx)
        y0, y1 = max(ys.start - margin, 0), min(ys.stop + margin, ny)
        if 4 * (x1 - x0) * (y1 - y0) >= nx * ny:  # a small grid: its transform, once for all
            return self._whole_clearance[xs, ys], np.inf
        dist = self._transform(self.blocked[x0:x1, y0:y1])
        exact = (margin + 1) * self.layout.cell_size
        return dist[xs.start - x0 : xs.stop - x0, ys.start - y0 : ys.stop - y0], exact

    @cached_property
    def _whole_clearance(self) -> np.ndarray:
        """The whole grid's clearance, for grids hardly larger than one goal's window (a batch
        of goals on a room-sized map would transform most of it again for each)."""
        return self._transform(self.blocked)

    def _transform(self, blocked: np.ndarray) -> np.ndarray:
        """Metres from each cell of ``blocked`` to its nearest obstacle cell (inf: none)."""
        if not blocked.any():
            return np.full(blocked.shape, np.inf)
        return np.sqrt(squared_distances(blocked).astype(np.float64)) * self.layout.cell_size

    @classmethod
    def from_store(cls, store: Path) -> FreeSpace | None:
        """The free space of a store's grid; None when it has no grid, or a grid table
        without the obstacle layers (a map written by other tools: goals are then the
        candidates' own positions, said by ``Goal.approach``)."""
        path = Path(store) / f"{CELLS_TABLE}.parquet"
        if not path.is_file():
            return None
        header = read_table(path, [])
        md = header.schema.metadata or {}
        columns = ["ix", "iy", "obstacle"]
        if GRID_SHAPE_KEY not in md or not set(columns) <= set(pq.read_schema(path).names):
            return None
        layout = GridLayout.from_table(header)
        cells = read_table(path, columns)
        ix = as_numpy(cells.column("ix")).astype(np.int64)
        iy = as_numpy(cells.column("iy")).astype(np.int64)
        obstacle = as_numpy(cells.column("obstacle")).astype(bool)
        return cls.from_cells(layout, ix, iy, obstacle)

    def approach(
        self, target_xy: tuple[float, float], config: GoalConfig
    ) -> tuple[float, float, float] | None:
        """(x, y, clearance) of the free cell nearest to ``target_xy`` within ``reach`` whose
        clearance is at least ``config.clearance``; if none keeps that clearance, the one with
        the most clearance; None when no free cell lies within reach."""
        found = self.approach_point(target_xy, config)
        return None if found is None else (found.x, found.y, found.clearance)

    def approach_point(
        self,
        target_xy: tuple[float, float],
        config: GoalConfig,
        *,
        within: np.ndarray | None = None,
        fallback: bool = True,
    ) -> Approach | None:
        """:meth:`approach` among the cells of ``within`` ((nx, ny) bool, e.g. those a robot
        can drive to from its start; None: every cell), saying whether the point keeps the
        clearance; without ``fallback``, None rather than a point that does not."""
        size = self.layout.cell_size
        ox, oy = self.layout.origin
        nx, ny = self.layout.shape
        cx, cy = (target_xy[0] - ox) / size, (target_xy[1] - oy) / size
        r = config.reach / size
        x0, x1 = max(math.floor(cx - r), 0), min(math.ceil(cx + r) + 1, nx)
        y0, y1 = max(math.floor(cy - r), 0), min(math.ceil(cy + r) + 1, ny)
        if x0 >= x1 or y0 >= y1:
            return None
        gx, gy = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1), indexing="ij")
        px, py = ox + (gx + 0.5) * size, oy + (gy + 0.5) * size
        dist = np.hypot(px - target_xy[0], py - target_xy[1])
        ok = self.free[x0:x1, y0:y1] & (dist <= config.reach)
        if within is not None:
            ok &= within[x0:x1, y0:y1]
        if not ok.any():
            return None
        # a margin past the clearance asked for: every value below it is then exact, so which
        # cells are safe is decided; only the chosen cell's own clearance may need more
        margin = math.ceil(config.clearance / size) + 2
        while True:
            metres, exact = self.clearance(slice(x0, x1), slice(y0, y1), margin)
            clear = metres.astype(np.float32)  # the precision goals have always reported
            safe = ok & (clear >= config.clearance)
            keeps = bool(safe.any())
            if not keeps:  # every clearance in reach is below the one asked for: exact
                if not fallback:
                    return None
                best = np.flatnonzero(ok.reshape(-1))[np.argmax(clear[ok])]
                break
            best = np.flatnonzero(safe.reshape(-1))[np.argmin(dist[safe])]
            if metres.flat[best] <= exact:
                break
            margin *= 2
        return Approach(float(px.flat[best]), float(py.flat[best]), float(clear.flat[best]), keeps)


@dataclass(frozen=True)
class GoalMaker:
    """Turns a map's candidates into goals: the store's frame, stamp and free space."""

    frame_id: str
    stamp_ns: int
    free_space: FreeSpace | None
    config: GoalConfig = GoalConfig()
    map_from_world: np.ndarray | None = None
    """The store's map frame when goals are not in the world frame (they then also come in
    the world frame)."""
    world_frame: str = DEFAULT_WORLD_FRAME
    frame_from_map: np.ndarray | None = None
    """From the map frame to :attr:`frame_id` when they differ (goals in the world frame)."""

    @classmethod
    def from_store(cls, store: Path, config: GoalConfig | None = None) -> GoalMaker:
        """Frame from the store's ``meta.json`` and map frame (:func:`care_maps.query.publish.frame_plan`),
        stamp of its last view (0, ROS's "latest", for a directory that holds maps without
        views)."""
        store = Path(store)
        config = config or GoalConfig()
        views = store / "views.parquet"
        stamps: np.ndarray | list[int] = (
            as_numpy(read_table(views, ["stamp_ns"]).column("stamp_ns")) if views.is_file() else []
        )
        plan = cls.plan(store, config.frame_id)
        frame = read_map_frame(store)
        in_world = not plan.publish
        return cls(
            frame_id=plan.frame_id,
            stamp_ns=int(np.max(stamps)) if len(stamps) else 0,
            free_space=FreeSpace.from_store(store),
            config=config,
            map_from_world=None if in_world else frame.map_from_world,
            world_frame=plan.world_frame,
            frame_from_map=(
                None if not in_world or frame.is_identity else np.linalg.inv(frame.map_from_world)
            ),
        )

    def world_from_frame(self) -> np.ndarray:
        """(4, 4) from :attr:`frame_id` to the world frame (identity where they are one)."""
        if self.map_from_world is None:
            return np.eye(4)
        return np.linalg.inv(self.map_from_world)

    @staticmethod
    def plan(store: Path, frame_id: str | None = None) -> FramePlan:
        """The frame goals of ``store`` are in (``frame_id``: the user's name for it)."""
        store = Path(store)
        meta = StoreMeta.read(store) if (store / META_FILE).is_file() else None
        world = str((meta and meta.world_frame) or DEFAULT_WORLD_FRAME)
        return frame_plan(read_map_frame(store), world, frame_id)

    def in_frame(self, xyz: np.ndarray) -> np.ndarray:
        """(M, 3) map points in :attr:`frame_id` (the frame of every coordinate of an
        answer)."""
        xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
        if self.frame_from_map is None:
            return xyz.copy()
        return xyz @ self.frame_from_map[:3, :3].T + self.frame_from_map[:3, 3]

    def goal(self, cmap: CandidateMap, candidate: int) -> Goal:
        """The goal for one candidate of ``cmap``: its nearest approach point that keeps the
        clearance, else (flagged) the one with the most clearance, else the object itself."""
        target = self._target(cmap, candidate)
        found = self.free_space.approach_point(target[:2], self.config) if self.free_space else None
        return self._goal(candidate, target, found)

    def goal_within(self, cmap: CandidateMap, candidate: int, within: np.ndarray) -> Goal | None:
        """The goal of ``candidate`` at the approach point nearest the object among the
        cells of ``within`` ((nx, ny) bool: those a robot can drive to) that keeps the
        clearance; None where there is none (or no grid)."""
        target = self._target(cmap, candidate)
        if self.free_space is None:
            return None
        found = self.free_space.approach_point(
            target[:2], self.config, within=within, fallback=False
        )
        return None if found is None else self._goal(candidate, target, found)

    def _target(self, cmap: CandidateMap, candidate: int) -> tuple[float, float, float]:
        if not 0 <= candidate < cmap.num_candidates:
            msg = f"candidate {candidate} is not in the map (0..{cmap.num_candidates - 1})"
            raise QueryError(msg)
        x, y, z = (float(v) for v in cmap.positions[candidate])  # a row of the (N, 3) positions
        return x, y, z

    def _goal(
        self, candidate: int, target: tuple[float, float, float], found: Approach | None
    ) -> Goal:
        frames = (self.map_from_world, self.world_frame, self.frame_from_map)
        required = self.config.clearance
        if found is None:  # no free cell in reach (or no grid): the object itself
            keeps = None if self.free_space is None else False
            return Goal(
                candidate, self.frame_id, self.stamp_ns, target, target, 0.0, False, None,
                *frames, keeps, required,
            )  # fmt: skip
        yaw = math.atan2(target[1] - found.y, target[0] - found.x)
        return Goal(
            candidate, self.frame_id, self.stamp_ns, target, (found.x, found.y, 0.0), yaw, True,
            found.clearance, *frames, found.keeps, required,
        )  # fmt: skip
