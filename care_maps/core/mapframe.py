"""The gravity-aligned map frame: z up, the floor at z = 0, whatever the recording's world.

Both maps are top-down: the grid bins points by (x, y) and filters them by height, the
instance map removes the floor by its plane. Most SLAM and dataset trajectories are expressed
in the first camera's frame (y down), not REP 103's z up, so the store carries a rigid
``map_from_world`` transform and every stage works in the map frame it defines.

How it is found from a recording: :mod:`care_maps.geometry.mapframe`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

__all__ = ["MapFrame", "UpAxis", "map_from_up"]


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

    @property
    def is_gravity_aligned(self) -> bool:
        """The world frame already has z up: the map frame differs from it by the floor's
        height at most, so x and y (a 2-D goal, an occupancy map) are the same in both."""
        return bool(np.allclose(self.map_from_world[:3, :3], np.eye(3), rtol=0.0, atol=1e-9))

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
