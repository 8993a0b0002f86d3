"""How far a robot walks between the places of one map: from a start, and from one
candidate's goal to every other's, over :mod:`care_maps.query.paths`' roadmap.

An evaluation plays thousands of attempt sequences; each attempt is a walk from where the
previous one ended (a goal's approach point) to the next goal. This module gives those walks'
lengths as arrays:

- :func:`approach_cells`: the cell of every candidate's approach point, by the rule of
  :meth:`care_maps.query.goals.FreeSpace.approach` (the free cell nearest the object within ``reach``
  that keeps the robot's clearance; ties to the lower cell index), for all candidates at
  once. One :meth:`~care_maps.query.goals.GoalMaker.goal` per candidate cost 9 s for the 21k cells of
  the sample's grid, this 0.3-0.4 s (2 cores, shared). A candidate whose every free cell in reach is too near
  an obstacle gets the goal with the most clearance there, which no robot of that radius
  can stand on: here it is ``-1``, unreachable, as :meth:`care_maps.query.paths.Travel.distance_to`
  finds it;
- :class:`Legs`: distances from points and from candidates' goals to every candidate's goal,
  one scipy Dijkstra per distinct place (several at once), cached by the cell it starts
  from, since most sequences share their first goals.

Math only: where a recording starts is read by the caller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from care_maps.query.paths import Roadmap

__all__ = ["Legs", "approach_cells", "largest_region"]

_KEPT_BYTES = 256 * 2**20
"""Memory the rows a :class:`Legs` keeps may take (the oldest go first): a few hundred rows of
a large grid's candidates, every row of a room's."""
_BATCH_BYTES = 64 * 2**20
"""Memory the searches run together may take (each returns a row over the whole floor)."""
_CHUNK = 256
"""Candidates whose approach cells are found together (a chunk holds chunk x window cells)."""


def approach_cells(roadmap: Roadmap, targets: np.ndarray, reach: float) -> np.ndarray:
    """(N,) flat cell index of each target's approach point (``-1``: no passable cell within
    ``reach``), for ``targets`` (N, 2) map x, y.

    The rule and the arithmetic of :meth:`care_maps.query.goals.FreeSpace.approach`, so ties resolve
    alike: cell centres ``origin + (i + 0.5) * size``, the Euclidean distance by
    ``np.hypot``, within ``reach`` inclusive, the nearest passable cell, the lower flat index
    among equals (offsets run in flat order and ``argmin`` keeps the first).

    Only the offsets that can hold the answer are tried: a target lies within half a
    diagonal of its own cell's centre, so if the nearest passable centre to that centre is
    ``e`` cells away (one distance transform of the floor), every cell that can be nearest
    to the target is within ``e + sqrt 2`` cells of it. Most targets lie on or by free
    floor and try a few dozen offsets, not the whole reach (21k grid cells: 2 s -> 0.3 s).
    """
    targets = np.asarray(targets, np.float64).reshape(-1, 2)
    layout = roadmap.layout
    size, (ox, oy) = layout.cell_size, layout.origin
    nx, ny = layout.shape
    r = math.ceil(reach / size) + 1
    out = np.full(len(targets), -1, np.int64)
    if len(targets) == 0 or not roadmap.passable.any():
        return out
    from scipy import ndimage

    cx = np.floor((targets[:, 0] - ox) / size).astype(np.int64)
    cy = np.floor((targets[:, 1] - oy) / size).astype(np.int64)
    inside = (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
    nearest = ndimage.distance_transform_edt(~roadmap.passable)
    radius = np.full(len(targets), r, np.int64)
    e = nearest[cx[inside], cy[inside]]
    radius[inside] = np.minimum(np.ceil(e + math.sqrt(2)).astype(np.int64), r)
    dx, dy = (a.reshape(-1) for a in np.mgrid[-r : r + 1, -r : r + 1])  # flat order
    span = np.maximum(np.abs(dx), np.abs(dy))
    for ring in np.unique(radius):
        which = np.flatnonzero(radius == ring)
        keep = span <= ring
        out[which] = _nearest_passable(roadmap, targets[which], reach, dx[keep], dy[keep])
    return out


def _nearest_passable(
    roadmap: Roadmap, targets: np.ndarray, reach: float, dx: np.ndarray, dy: np.ndarray
) -> np.ndarray:
    """:func:`approach_cells` of ``targets`` over the cell offsets ``dx, dy`` (flat order)."""
    layout = roadmap.layout
    size, (ox, oy) = layout.cell_size, layout.origin
    nx, ny = layout.shape
    out = np.full(len(targets), -1, np.int64)
    for lo in range(0, len(targets), _CHUNK):
        t = targets[lo : lo + _CHUNK]
        cx = np.floor((t[:, 0] - ox) / size).astype(np.int64)
        cy = np.floor((t[:, 1] - oy) / size).astype(np.int64)
        gx, gy = cx[:, None] + dx, cy[:, None] + dy
        inside = (gx >= 0) & (gx < nx) & (gy >= 0) & (gy < ny)
        px, py = ox + (gx + 0.5) * size, oy + (gy + 0.5) * size
        dist = np.hypot(px - t[:, :1], py - t[:, 1:])
        ok = inside & (dist <= reach)
        ok[inside] &= roadmap.passable[gx[inside], gy[inside]]
        dist = np.where(ok, dist, np.inf)
        best = dist.argmin(axis=1)
        rows = np.arange(len(t))
        found = ok[rows, best]
        out[lo : lo + len(t)] = np.where(found, gx[rows, best] * ny + gy[rows, best], -1)
    return out


def largest_region(roadmap: Roadmap) -> np.ndarray:
    """Flat indices of the passable cells of the largest connected region of the roadmap:
    where a robot can be put down and still drive to most of the floor (a cell behind a
    sofa is passable and cut off)."""
    from scipy.sparse.csgraph import connected_components

    cells = np.flatnonzero(roadmap.passable.reshape(-1))
    if len(cells) == 0:
        return cells
    _, label = connected_components(roadmap.graph, directed=False)
    label = label[cells]
    return cells[label == np.bincount(label).argmax()]


@dataclass(frozen=True, eq=False)
class Legs:
    """Distances (m) over one roadmap to the goals of N candidates; rows are kept (up to
    256 MB, the oldest dropped first).

    ``goal_cell`` is :func:`approach_cells` of the candidates. A row is the distance from
    one place to every goal: ``inf`` where the search does not reach it or the candidate
    has no goal a robot can stand on.
    """

    roadmap: Roadmap
    goal_cell: np.ndarray
    """(N,) flat cell index of each candidate's approach point, -1: unreachable."""
    start_reach: float
    """How far a start off the passable cells may join them (:class:`care_maps.query.paths.PathConfig`)."""
    _rows: dict[int, np.ndarray] = field(default_factory=dict, repr=False)

    def from_point(self, xy: tuple[float, float]) -> np.ndarray:
        """(N,) metres from map point ``xy`` to every goal (all inf: no passable cell within
        :attr:`start_reach` of it)."""
        travel = self.roadmap.travel(xy, self.start_reach)
        return self._to_goals(travel.distance)

    def from_cells(self, cells: np.ndarray) -> np.ndarray:
        """(M, N) metres from the centre of each flat cell of ``cells`` to every goal; a
        cell of ``-1`` (a goal no robot stands on) reaches nothing."""
        cells = np.asarray(cells, np.int64).reshape(-1)
        todo = sorted({int(c) for c in cells if c >= 0 and int(c) not in self._rows})
        if todo:
            from scipy.sparse.csgraph import dijkstra

            batch = max(1, _BATCH_BYTES // (8 * self.roadmap.passable.size))
            for lo in range(0, len(todo), batch):  # a search's row is the whole floor
                dist = dijkstra(self.roadmap.graph, indices=todo[lo : lo + batch])
                for cell, row in zip(todo[lo : lo + batch], np.atleast_2d(dist), strict=True):
                    self._rows[cell] = self._to_goals(row)
        nowhere = np.full(len(self.goal_cell), np.inf)
        rows = [self._rows[int(c)] if c >= 0 else nowhere for c in cells]
        out = np.stack(rows) if rows else np.zeros((0, len(self.goal_cell)))
        keep = max(len(todo), _KEPT_BYTES // (8 * max(len(self.goal_cell), 1)))
        for cell in list(self._rows)[: max(len(self._rows) - keep, 0)]:  # the oldest first
            del self._rows[cell]
        return out

    def from_goals(self, ids: np.ndarray) -> np.ndarray:
        """(M, N) metres from the goal of each candidate of ``ids`` to every goal."""
        return self.from_cells(self.goal_cell[np.asarray(ids, np.int64)])

    def _to_goals(self, grid_distance: np.ndarray) -> np.ndarray:
        cell = np.maximum(self.goal_cell, 0)
        return np.where(self.goal_cell >= 0, grid_distance[cell], np.inf)
