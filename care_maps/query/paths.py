"""Paths on the map: how far a robot drives to each goal, and the way there.

A goal's distance is the length of the shortest path over the grid's free space that a
robot of radius ``clearance`` (:attr:`care_maps.query.goals.GoalConfig.clearance`, the same radius its
approach points keep) can follow, from a start to the goal's approach point:

- the robot may stand on a cell that is free (seen, not an obstacle) and whose clearance is
  at least ``clearance``, by the rule approach points are chosen by (so a goal said to keep
  the clearance is always a cell the robot may stand on);
- it moves between the 8 neighbours of a cell (``cell_size`` straight, ``sqrt 2`` times that
  diagonally), and a diagonal step needs both cells beside it passable, so a path never
  slips between two obstacles that touch at a corner;
- a start that is not itself on such a cell (a hand-held camera above a table, a pose by a
  wall) joins the nearest one within :attr:`PathConfig.start_reach`, in a straight line.

Distances come from one single-source search over that graph (scipy's ``csgraph.dijkstra``,
or on a grid of up to :data:`_NUMPY_CELLS` cells its very answer computed in NumPy, without
scipy's import: :meth:`Roadmap.nearest_first`), so every candidate of a query costs one
search, and a roadmap keeps its last searches: a second query or a batch from the same
place pays a look-up. A goal
the search does not reach, or that is the object itself (no approach point), is
unreachable: its distance is ``inf``. A path is the list of cells back from a goal to the
start, as ``nav_msgs/Path`` JSON (:func:`nav_path`) in the goals' frame; :func:`walk`
strings the attempts of a sequence together, each from where the one before ended (a
search per place stood at).

Why scipy's Dijkstra (``bench/paths.py`` times each on the same floor): python-igraph,
networkit and rustworkx search the same graph 2-4.5 times slower at 1M cells;
scikit-image's ``MCP_Geometric`` is twice as slow and cuts corners (it lets a diagonal step
pass an obstacle's corner, so its distances come out shorter than a robot can drive).

Math only: the start of a recording (its first pose) is read by the caller.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt

from care_maps.core.errors import QueryError
from care_maps.fuse.layout import GridLayout
from care_maps.query.goals import FreeSpace, Goal, GoalMaker, squared_distances, stamped_poses

__all__ = [
    "Leg",
    "PathConfig",
    "Roadmap",
    "Travel",
    "nav_path",
    "passable_squared_distance",
    "path_length",
    "walk",
]

_STEPS = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1))
"""The 8 moves from a cell, (dx, dy) in cells: four straight, then four diagonal."""
_NUMPY_CELLS = 250_000
"""Grids up to this many cells are searched in NumPy (:meth:`Roadmap.nearest_first`: 5 ms
at a room's 24k cells, 0.05 s at 90k, against scipy's 0.15 s import); larger ones by scipy's
Dijkstra (0.2 s at 1M cells, where the NumPy bands take 0.7 s)."""
TIED = -2
"""A cell before which :meth:`Roadmap.nearest_first` cannot tell scipy's choice."""
_KEPT_SEARCHES = 2
"""Searches a roadmap keeps (12 bytes a cell each: 24 MB at 1M cells): the start of a query
and of its walk's first leg, a batch's start."""


@dataclass(frozen=True)
class PathConfig:
    """Where paths start (the robot's radius is the goals' ``clearance``)."""

    start: tuple[float, ...] | None = None
    """Where the robot starts: x,y in metres, in the frame of the goals and map.yaml.
    Default: the recording's first pose (its first camera position, on the floor)."""
    start_reach: float = 1.0
    """Farthest (m) the first passable cell may lie from a start that is not on one itself."""

    def __post_init__(self) -> None:
        if self.start is not None and (
            len(self.start) != 2 or not all(math.isfinite(v) for v in self.start)
        ):
            msg = f"path start must be two finite numbers x,y in metres, got {self.start}"
            raise QueryError(msg)
        if not (math.isfinite(self.start_reach) and self.start_reach >= 0):
            msg = f"path start reach must be a finite distance >= 0 m, got {self.start_reach}"
            raise QueryError(msg)


def passable_squared_distance(clearance: float, cell_size: float) -> int:
    """The least squared distance (in cells) from an obstacle at which a cell keeps
    ``clearance``, by the approach points' own rule: the whole grid's distance transform
    (``sqrt`` of an integer, times the cell size) in float32, at least ``clearance``."""
    k = max(math.floor((clearance / cell_size) ** 2) - 2, 0)
    while np.float32(math.sqrt(k) * cell_size) < clearance:
        k += 1
    return k


@dataclass(frozen=True)
class Roadmap:
    """The cells a robot of radius ``clearance`` may stand on, and the graph of its moves."""

    layout: GridLayout
    passable: np.ndarray
    """(nx, ny) bool: free, and at least ``clearance`` from every obstacle cell."""

    @classmethod
    def from_free_space(cls, space: FreeSpace, clearance: float) -> Roadmap:
        """Free cells outside the obstacles grown by the robot's radius: those at least
        :func:`passable_squared_distance` from every obstacle cell, the same cells a
        whole-grid distance transform keeps. The transform stops at that distance
        (:func:`care_maps.query.goals.squared_distances`): a few passes over the grid, some
        10 ms at 1M cells, and neither scipy nor OpenCV to import at a query's start."""
        k = passable_squared_distance(clearance, space.layout.cell_size)
        if k == 0 or not space.blocked.any():
            return cls(space.layout, space.free.copy())
        near = squared_distances(space.blocked, below=k) < k
        return cls(space.layout, space.free & ~near)

    @classmethod
    def for_goals(cls, goals: GoalMaker) -> Roadmap | None:
        """The roadmap of ``goals``' free space, their clearance the robot's radius (None
        without a grid). Built once per map and radius; each start is then one search."""
        if goals.free_space is None:
            return None
        return cls.from_free_space(goals.free_space, goals.config.clearance)

    @cached_property
    def moves(self) -> np.ndarray:
        """(nx, ny, 8) bool: whether the robot may step from a cell along each of
        :data:`_STEPS` (both cells passable, and no corner cut)."""
        nx, ny = self.layout.shape
        ok = np.pad(self.passable, 1)
        centre = ok[1:-1, 1:-1]
        moves = np.empty((nx, ny, len(_STEPS)), bool)
        for d, (dx, dy) in enumerate(_STEPS):
            moves[..., d] = centre & ok[1 + dx : 1 + dx + nx, 1 + dy : 1 + dy + ny]
            if dx and dy:  # no corner cutting: both cells beside the diagonal passable
                moves[..., d] &= ok[1 + dx : 1 + dx + nx, 1 : 1 + ny]
                moves[..., d] &= ok[1 : 1 + nx, 1 + dy : 1 + dy + ny]
        return moves

    @property
    def steps(self) -> tuple[np.ndarray, np.ndarray]:
        """The flat-index offset and the length (m) of each of :data:`_STEPS`."""
        ny, size = self.layout.shape[1], self.layout.cell_size
        offset = np.array([dx * ny + dy for dx, dy in _STEPS])
        return offset, np.array([size * math.hypot(dx, dy) for dx, dy in _STEPS])

    @cached_property
    def graph(self):
        """The moves as a CSR matrix over every cell (flat index ``ix * ny + iy``): an entry
        (a, b) is the length (m) of the step from cell a to neighbour b, both passable."""
        from scipy.sparse import csr_matrix

        nx, ny = self.layout.shape
        moves = self.moves
        flat = np.flatnonzero(moves)  # row-major: sorted by cell, as CSR wants
        cell, step = np.divmod(flat, len(_STEPS))
        offset, length = self.steps
        indptr = np.zeros(nx * ny + 1, np.int32)
        np.cumsum(moves.sum(axis=2, dtype=np.int32).reshape(-1), out=indptr[1:])
        indices = (cell + offset[step]).astype(np.int32)
        return csr_matrix((length[step], indices, indptr), shape=(nx * ny, nx * ny))

    def cell_of(self, xy: tuple[float, float]) -> tuple[int, int]:
        """(ix, iy) of the cell holding map point ``xy`` (possibly outside the grid)."""
        size, (ox, oy) = self.layout.cell_size, self.layout.origin
        return math.floor((xy[0] - ox) / size), math.floor((xy[1] - oy) / size)

    def centres(self, flat: npt.ArrayLike) -> np.ndarray:
        """(M, 2) map (x, y) of the cells of flat index ``flat``."""
        ix, iy = np.divmod(np.asarray(flat, np.int64), self.layout.shape[1])
        size, (ox, oy) = self.layout.cell_size, self.layout.origin
        return np.stack([ox + (ix + 0.5) * size, oy + (iy + 0.5) * size], axis=1)

    def entry(self, start: tuple[float, float], reach: float) -> int | None:
        """Flat index of the cell a path from ``start`` begins at: its own when passable,
        else the passable cell whose centre is nearest within ``reach``; None if none is."""
        nx, ny = self.layout.shape
        cx, cy = self.cell_of(start)
        if 0 <= cx < nx and 0 <= cy < ny and self.passable[cx, cy]:
            return cx * ny + cy
        r = math.ceil(reach / self.layout.cell_size) + 1
        x0, x1, y0, y1 = max(cx - r, 0), min(cx + r + 1, nx), max(cy - r, 0), min(cy + r + 1, ny)
        if x0 >= x1 or y0 >= y1:
            return None
        gx, gy = np.nonzero(self.passable[x0:x1, y0:y1])
        flat = (gx + x0) * ny + (gy + y0)
        dist = np.hypot(*(self.centres(flat) - start).T)
        near = dist <= reach
        return int(flat[near][np.argmin(dist[near])]) if near.any() else None

    def travel(self, start: tuple[float, float], reach: float) -> Travel:
        """Shortest paths from ``start`` to every cell (``reach``: how far the first
        passable cell may lie from it, :attr:`PathConfig.start_reach`). The last few
        searches are kept: asking again from the same start costs nothing, and returns the
        same :class:`Travel`, its arrays read-only."""
        start = (float(start[0]), float(start[1]))
        key = (start, float(reach))
        kept = self._searches.pop(key, None)
        if kept is None:
            kept = self._search(start, reach)
            kept.distance.flags.writeable = kept.predecessor.flags.writeable = False  # shared
        self._searches[key] = kept  # the newest last: the oldest goes first
        while len(self._searches) > _KEPT_SEARCHES:
            del self._searches[next(iter(self._searches))]
        return kept

    @cached_property
    def _searches(self) -> dict[tuple[tuple[float, float], float], Travel]:
        return {}

    def _search(self, start: tuple[float, float], reach: float) -> Travel:
        """One search from the cell ``start`` enters at: :meth:`nearest_first` on a grid
        of up to :data:`_NUMPY_CELLS` cells, scipy's Dijkstra over :attr:`graph` above."""
        source = self.entry(start, reach)
        n = self.passable.size
        if source is None:
            return Travel(self, start, None, np.full(n, np.inf), np.full(n, -1, np.int32))
        if n <= _NUMPY_CELLS:
            dist, pred = self.nearest_first(source)
        else:
            dist, pred = self.dijkstra(source)
        lead = float(np.hypot(*(self.centres([source])[0] - start)))
        return Travel(self, start, source, dist + lead, pred)

    def dijkstra(self, source: int) -> tuple[np.ndarray, np.ndarray]:
        """scipy's Dijkstra over :attr:`graph` from cell ``source``: (nx * ny,) metres
        and the cell before each on its path (-9999: none)."""
        from scipy.sparse.csgraph import dijkstra

        dist, pred = dijkstra(self.graph, indices=source, return_predecessors=True)
        return dist, pred

    def nearest_first(self, source: int) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`dijkstra`'s answer in NumPy, without importing scipy (0.15 s at every
        query's start, where a room's search takes a few milliseconds): the same
        metres bit for bit, the same cell before each, except :data:`TIED` where two
        cells before it tie (:meth:`Travel.waypoints` asks :meth:`dijkstra` there).

        Cells are settled a band at a time, nearest first: every open cell nearer than the
        nearest one plus the shortest step is final (no step from inside the band can lower
        another), and the band's steps are taken at once. Each distance is then the least
        ``d(u) + step`` over the cells ``u`` before it, summed as scipy sums it, so the
        distances are scipy's whatever the order. The cell before each is the one scipy's
        search reaches it from: the first cell settled among those giving its distance,
        i.e. the nearest of them; only when two of them are equally near does the order of
        scipy's heap decide, and that cell is left :data:`TIED` (a few in a thousand).
        ``tests/query/test_paths.py`` checks both against scipy on many floors.
        """
        n = self.passable.size
        moves = self.moves.reshape(n, len(_STEPS))
        offset, length = self.steps
        shortest = float(length.min())
        dist = np.full(n, np.inf)
        dist[source] = 0.0
        settled = np.zeros(n, bool)
        last = np.zeros(n, np.int64)  # for dropping repeats from the open cells
        open_ = np.array([source], np.int64)
        while len(open_):
            near = dist[open_]
            band = near < near.min() + shortest
            now, open_ = open_[band], open_[~band]
            settled[now] = True
            cell, step = np.nonzero(moves[now])
            src = now[cell]
            dst = src + offset[step]
            new = dist[src] + length[step]
            better = ~settled[dst] & (new < dist[dst])
            dst, new = dst[better], new[better]
            np.minimum.at(dist, dst, new)
            open_ = np.concatenate([open_, dst])
            last[open_] = np.arange(len(open_))
            open_ = open_[last[open_] == np.arange(len(open_))]
        return dist, self._predecessors(dist, source)

    def _predecessors(self, dist: np.ndarray, source: int) -> np.ndarray:
        """The cell before each on its path: the nearest of the cells ``u`` with
        ``dist[u] + step == dist[cell]`` (:data:`TIED` when two are equally near)."""
        n = self.passable.size
        moves = self.moves.reshape(n, len(_STEPS))
        offset, length = self.steps
        pred = np.full(n, -9999, np.int32)
        cells = np.flatnonzero(np.isfinite(dist))
        cells = cells[cells != source]
        best = np.full(len(cells), np.inf)
        before = np.full(len(cells), -9999, np.int64)
        tied = np.zeros(len(cells), bool)
        for k in range(len(_STEPS)):
            u = cells - offset[k]  # a step k from u lands on the cell
            inside = (u >= 0) & (u < n)
            u = np.where(inside, u, 0)
            gives = inside & moves[u, k] & (dist[u] + length[k] == dist[cells])
            du = np.where(gives, dist[u], np.inf)
            tied |= gives & (du == best)
            nearer = du < best
            tied &= ~nearer
            best = np.where(nearer, du, best)
            before = np.where(nearer, u, before)
        pred[cells] = np.where(tied, TIED, before)
        return pred


@dataclass(frozen=True)
class Travel:
    """Shortest paths from one start over a :class:`Roadmap`."""

    roadmap: Roadmap
    start: tuple[float, float]
    """The start (map x, y)."""
    source: int | None
    """Flat index of the cell the paths begin at; None: no passable cell near the start."""
    distance: np.ndarray
    """(nx * ny,) metres from the start to each cell's centre (inf: unreachable)."""
    predecessor: np.ndarray
    """(nx * ny,) the cell before each on its shortest path (-9999 or -1: none;
    :data:`TIED`: scipy's heap decides, :meth:`waypoints` asks it)."""

    def cell(self, xy: tuple[float, float]) -> int | None:
        """Flat index of the cell holding ``xy``; None outside the grid."""
        nx, ny = self.roadmap.layout.shape
        cx, cy = self.roadmap.cell_of(xy)
        return cx * ny + cy if 0 <= cx < nx and 0 <= cy < ny else None

    def distance_to(self, goal: Goal) -> float:
        """Metres to ``goal``'s approach point (inf: unreachable, or no approach point)."""
        cell = self.cell(goal.position[:2]) if goal.approach else None
        return math.inf if cell is None else float(self.distance[cell])

    def distances(self, goals: Sequence[Goal]) -> np.ndarray:
        """(len(goals),) :meth:`distance_to` of each goal, in one look-up."""
        xy = np.array([g.position[:2] for g in goals], np.float64).reshape(-1, 2)
        size, (ox, oy) = self.roadmap.layout.cell_size, self.roadmap.layout.origin
        nx, ny = self.roadmap.layout.shape
        cx = np.floor((xy[:, 0] - ox) / size).astype(np.int64)
        cy = np.floor((xy[:, 1] - oy) / size).astype(np.int64)
        inside = (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
        inside &= np.array([g.approach for g in goals], bool)
        out = np.full(len(xy), np.inf)
        out[inside] = self.distance[cx[inside] * ny + cy[inside]]
        return out

    @cached_property
    def _scipys_predecessor(self) -> np.ndarray:
        """The cell before each, by scipy's Dijkstra (asked only for a :data:`TIED` one)."""
        assert self.source is not None
        return self.roadmap.dijkstra(self.source)[1]

    def waypoints(self, goal: Goal) -> np.ndarray | None:
        """(M, 2) map (x, y) from the start to ``goal``'s approach point: the start, the
        centre of each cell on the way, the goal (None: unreachable)."""
        if not math.isfinite(self.distance_to(goal)):
            return None
        cells = [self.cell(goal.position[:2])]
        while cells[-1] != self.source:
            before = int(self.predecessor[cells[-1]])
            if before == TIED:
                before = int(self._scipys_predecessor[cells[-1]])
            cells.append(before)
        centres = self.roadmap.centres(np.array(cells[::-1]))
        return centres if np.allclose(centres[0], self.start) else np.vstack([self.start, centres])


@dataclass(frozen=True)
class Leg:
    """One attempt's way: from where the robot stood to the attempt's goal."""

    goal: Goal
    start: tuple[float, float]
    """Where the robot stood (map x, y): the walk's start, or the last goal it reached."""
    waypoints: np.ndarray | None
    """(M, 2) map (x, y) from ``start`` to the goal (None: unreachable from there)."""

    @property
    def length(self) -> float:
        """Metres driven (inf: unreachable)."""
        return math.inf if self.waypoints is None else path_length(self.waypoints)


def walk(
    roadmap: Roadmap, start: tuple[float, float], reach: float, goals: Sequence[Goal]
) -> list[Leg]:
    """The way of each attempt in turn, as a robot replanning after each failure drives it:
    the first from ``start``, each later one from where the one before ended (its goal; an
    unreachable goal leaves the robot where it stood). One search per place stood at."""
    here = (float(start[0]), float(start[1]))
    legs = []
    for goal in goals:
        points = roadmap.travel(here, reach).waypoints(goal)
        legs.append(Leg(goal, here, points))
        if points is not None:
            here = (float(points[-1, 0]), float(points[-1, 1]))
    return legs


def path_length(waypoints: np.ndarray) -> float:
    """Length (m) of the polyline through ``waypoints``."""
    return float(np.hypot(*np.diff(waypoints, axis=0).T).sum()) if len(waypoints) > 1 else 0.0


def nav_path(goal: Goal, waypoints: np.ndarray) -> dict:
    """The way to ``goal`` as ``nav_msgs/Path`` JSON (ROS 2 field names) in the goal's frame:
    each pose on the floor facing the next one, the last the goal's own pose (facing the
    object); header and stamps those of the goal."""
    points = np.asarray(waypoints, np.float64).reshape(-1, 2)
    step = np.diff(points, axis=0)
    yaw = np.append(np.arctan2(step[:, 1], step[:, 0]), goal.yaw)
    poses = np.repeat(np.eye(4)[None], len(points), axis=0)
    poses[:, 0, 0] = poses[:, 1, 1] = np.cos(yaw)
    poses[:, 1, 0] = np.sin(yaw)
    poses[:, 0, 1] = -poses[:, 1, 0]
    poses[:, :2, 3] = points
    poses[-1] = goal.pose_matrix()
    if goal.frame_from_map is not None:
        poses = goal.frame_from_map @ poses
    stamped = stamped_poses(poses, goal.frame_id, goal.stamp_ns)
    return {"header": stamped[-1]["header"], "poses": stamped}
