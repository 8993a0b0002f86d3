"""The gravity-aligned map frame: z up, the floor at z = 0, whatever the recording's world.

Both maps are top-down: the grid bins points by (x, y) and filters them by height, the
instance map removes the floor by its plane. Most SLAM and dataset trajectories are expressed
in the first camera's frame (y down), not REP 103's z up, so the store carries a rigid
``map_from_world`` transform and every stage works in the map frame it defines.

How it is found (:func:`estimate_map_frame`), from the recording itself:

1. a first guess of "up" from the cameras: a robot's or a person's camera is held roughly
   level, so the mean of the optical frames' -y axes points up; the second guess is the
   world's +z (REP 103), for cameras that look straight down;
2. the floor: among the largest planes (seeded RANSAC, :func:`care.planes.fit_plane`) of a
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
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from care.errors import CareError
from care.planes import along, fit_plane

__all__ = [
    "FloorNotFoundError",
    "MapFrame",
    "UpAxis",
    "estimate_map_frame",
    "map_from_up",
]


_MIN_POINTS = 30
"""Fewest points a plane is fitted to."""

_RANSAC_ITERATIONS = 500
"""Random triples tried per plane."""


class FloorNotFoundError(CareError):
    """No horizontal plane below the cameras: the up axis must be given."""


class UpAxis(StrEnum):
    """Which axis of the recording's world frame points up (``auto``: found from the floor)."""

    AUTO = "auto"
    PX = "+x"
    NX = "-x"
    PY = "+y"
    NY = "-y"
    PZ = "+z"
    NZ = "-z"

    def vector(self) -> np.ndarray:
        if self is UpAxis.AUTO:
            msg = "the auto up axis has no fixed vector"
            raise ValueError(msg)
        axis = np.zeros(3)
        axis["xyz".index(self.value[1])] = 1.0 if self.value[0] == "+" else -1.0
        return axis


@dataclass(frozen=True)
class MapFrame:
    """The map frame of a store: ``map_from_world`` and how it was found."""

    map_from_world: np.ndarray
    """(4, 4) rigid transform from the recording's world frame to the map frame."""
    up: tuple[float, float, float]
    """The world-frame vector that points up."""
    floor: float
    """Height of the floor along ``up`` in the world frame (metres)."""
    method: str
    """How it was found: ``identity`` (already z-up, floor at 0), ``floor plane``, ``given``."""
    floor_fraction: float = float("nan")
    """Share of the sampled points on the floor plane (a detection's support)."""

    @property
    def is_identity(self) -> bool:
        return bool(np.array_equal(self.map_from_world, np.eye(4)))

    def as_json(self) -> dict:
        return {
            "map_from_world": self.map_from_world.reshape(-1).tolist(),
            "up": list(self.up),
            "floor": self.floor,
            "method": self.method,
            "floor_fraction": None if math.isnan(self.floor_fraction) else self.floor_fraction,
        }

    @classmethod
    def from_json(cls, data: dict) -> MapFrame:
        frac = data.get("floor_fraction")
        return cls(
            np.asarray(data["map_from_world"], np.float64).reshape(4, 4),
            tuple(float(v) for v in data["up"]),  # type: ignore[arg-type]
            float(data["floor"]),
            str(data["method"]),
            float("nan") if frac is None else float(frac),
        )

    @classmethod
    def identity(cls) -> MapFrame:
        return cls(np.eye(4), (0.0, 0.0, 1.0), 0.0, "identity")

    def describe(self) -> str:
        names = {tuple(UpAxis(a).vector()): a for a in ("+x", "-x", "+y", "-y", "+z", "-z")}
        up = names.get(
            tuple(np.round(self.up, 12)), "[" + ", ".join(f"{v:.3f}" for v in self.up) + "]"
        )
        if self.method == "identity":
            return "map frame = world frame (z up, floor at z = 0)"
        support = (
            ""
            if math.isnan(self.floor_fraction)
            else f", {self.floor_fraction:.0%} of sampled points"
        )
        return f"map frame: up = {up} of the world, floor at {self.floor:.3f} m along it ({self.method}{support})"


def map_from_up(up: np.ndarray, floor: float) -> np.ndarray:
    """(4, 4) rigid transform taking ``up`` to +z and the plane ``up . p = floor`` to z = 0,
    with the world's x axis (or y when x is nearly vertical) projected on the floor as map x."""
    z = np.asarray(up, np.float64) / np.linalg.norm(up)
    if np.allclose(z, [0.0, 0.0, 1.0]):
        rot = np.eye(3)
    else:
        ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = ref - (ref @ z) * z
        x /= np.linalg.norm(x)
        rot = np.stack([x, np.cross(z, x), z])  # rows: the map axes in world coordinates
        rot[np.abs(rot) < 1e-15] = 0.0
    out = np.eye(4)
    out[:3, :3] = rot
    out[2, 3] = -float(floor)
    return out


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
    return MapFrame(
        map_from_up(up, floor), tuple(float(v) for v in up), float(floor), method, fraction
    )  # type: ignore[arg-type]


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
