"""The map frame of a recording, estimated from its depth points (the frame itself:
:class:`care_maps.core.mapframe.MapFrame`).

How it is found (:func:`estimate_map_frame`), from the recording itself:

1. a first guess of "up" from the cameras: a robot's or a person's camera is held roughly
   level, so the mean of the optical frames' -y axes points up; the second guess is the
   world's +z (REP 103), for cameras that look straight down;
2. the floor: among the largest planes (seeded RANSAC, :func:`care_maps.geometry.planes.fit_plane`) of a
   bounded sample of the depth points, oriented towards the cameras (so the ceiling, above
   them, points down), the largest whose normal lies within ``max_tilt`` of the first guess
   that has one (walls are not horizontal);
3. up = the floor's normal, snapped to a world axis when within ``snap`` of it (so a z-up
   recording keeps its exact axes); the floor's height becomes z = 0, except that a world
   frame already z-up with its floor within ``floor_tolerance`` of 0 is kept as it is;
4. the map's x axis is the world's x (or, when x is nearly vertical, y) projected on the
   floor, so a z-up world only moves vertically.

``--up-axis`` (``+x``, ``-x``, ..., ``+z``) replaces steps 1-3's axis, ``--floor-z`` the floor
height (metres along that axis).
"""

from __future__ import annotations

import math

import numpy as np

from care_maps.core.errors import CareError
from care_maps.core.mapframe import MapFrame, UpAxis, map_from_up
from care_maps.geometry.planes import along, fit_plane

__all__ = ["FloorNotFoundError", "estimate_map_frame"]


_MIN_POINTS = 30
"""Fewest points a plane is fitted to."""

_RANSAC_ITERATIONS = 500
"""Random triples tried per plane."""


class FloorNotFoundError(CareError):
    """No horizontal plane below the cameras: the up axis must be given."""


def _snap(up: np.ndarray, snap_deg: float) -> np.ndarray:
    axis = np.zeros(3)
    i = int(np.argmax(np.abs(up)))
    axis[i] = math.copysign(1.0, up[i])
    return axis if np.degrees(np.arccos(np.clip(up @ axis, -1, 1))) <= snap_deg else up


def estimate_map_frame(
    points: np.ndarray,
    cam_to_world: np.ndarray,
    *,
    up_axis: UpAxis = UpAxis.AUTO,
    floor: float | None = None,
    max_tilt: float = 25.0,
    snap: float = 3.0,
    floor_tolerance: float = 0.02,
    distance: float = 0.03,
    planes: int = 6,
    seed: int = 0,
) -> MapFrame:
    """The map frame of a recording from a sample of its world points (P, 3) and its poses.

    Raises :class:`FloorNotFoundError` when ``up_axis`` is ``auto`` and no plane within
    ``max_tilt`` degrees of the cameras' up lies below them.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    centres = cam_to_world[:, :3, 3]
    if up_axis is not UpAxis.AUTO:
        up = up_axis.vector()
        if floor is None:
            floor = _floor_along(points, centres, up, distance, seed)
        return _frame(up, floor, "given", float("nan"), floor_tolerance)
    guess = -cam_to_world[:, :3, 1].mean(axis=0)
    hints = [guess / np.linalg.norm(guess)] if np.linalg.norm(guess) >= 0.5 else []
    hints.append(np.array([0.0, 0.0, 1.0]))  # REP 103: a z-up world
    found = _floor_plane(points, centres, hints, max_tilt, distance, planes, seed)
    if found is None:
        msg = (
            "no floor found: no large horizontal plane lies below the cameras; pass --up-axis "
            "(the world axis that points up, e.g. +z for REP 103 frames) and --floor-z"
        )
        raise FloorNotFoundError(msg)
    normal, offset, _ = found
    up = _snap(normal, snap)
    if up is not normal:  # snapped: measure the floor's height along the exact axis
        offset = _floor_along(points, centres, up, distance, seed)
    # the share of points on the floor, measured on the final (possibly snapped) plane
    fraction = (
        float(np.mean(np.abs(along(points, up) - offset) <= distance)) if len(points) else 0.0
    )
    return _frame(up, offset if floor is None else floor, "floor plane", fraction, floor_tolerance)


def _frame(up: np.ndarray, floor: float, method: str, fraction: float, tol: float) -> MapFrame:
    if np.array_equal(up, [0.0, 0.0, 1.0]) and abs(floor) <= tol and method != "given":
        return MapFrame(np.eye(4), (0.0, 0.0, 1.0), float(floor), "identity", fraction)
    x, y, z = (float(v) for v in up)
    return MapFrame(map_from_up(up, floor), (x, y, z), float(floor), method, fraction)


def _floor_plane(
    points: np.ndarray,
    centres: np.ndarray,
    hints: list[np.ndarray],
    max_tilt: float,
    distance: float,
    planes: int,
    seed: int,
) -> tuple[np.ndarray, float, float] | None:
    """(up normal, offset along it, inlier share) of the floor: among the ``planes`` largest
    planes, those below the cameras whose normal lies within ``max_tilt`` of a hint; the
    largest for the first hint that has any (the cameras' up, then the world's +z)."""
    rng = np.random.default_rng(seed)
    rest = points
    found: list[tuple[np.ndarray, float, int]] = []
    for _ in range(planes):
        if len(rest) < _MIN_POINTS:
            break
        plane = fit_plane(rest, distance, _RANSAC_ITERATIONS, rng)
        if plane is None:
            break
        normal, d, inliers = plane.normal, plane.offset, plane.inliers
        side = np.median(along(centres, normal) + d)
        if side < 0:  # orient the normal towards the cameras
            normal, d = -normal, -d
        found.append((normal, -d, len(inliers)))
        keep = np.ones(len(rest), bool)
        keep[inliers] = False
        rest = rest[keep]
    cos_tilt = math.cos(math.radians(max_tilt))
    for hint in hints:
        level = [f for f in found if f[0] @ hint >= cos_tilt]
        if level:
            normal, offset, count = max(level, key=lambda f: f[2])
            return normal, offset, count / max(len(points), 1)
    return None


def _floor_along(
    points: np.ndarray, centres: np.ndarray, up: np.ndarray, distance: float, seed: int
) -> float:
    """The floor's height along a known up axis: the lowest dense height band below the
    cameras (a histogram of point heights at the plane-fit distance)."""
    heights = along(points, up)
    cams = float(np.median(along(centres, up)))
    below = heights[heights < cams]
    if below.size < _MIN_POINTS:
        msg = "no floor found below the cameras along the given up axis; pass --floor-z"
        raise FloorNotFoundError(msg)
    bins = np.arange(below.min(), cams + distance, distance)
    if len(bins) < 2:
        return float(below.min())
    counts, edges = np.histogram(below, bins=bins)
    dense = np.flatnonzero(counts >= 0.2 * counts.max())
    i = int(dense[0])
    band = below[(below >= edges[i]) & (below < edges[i + 1] + distance)]
    return float(np.median(band))
