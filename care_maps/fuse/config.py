"""The two map builds' settings: :class:`GridConfig` and :class:`InstanceConfig`.

They live apart from the builders (:mod:`care_maps.fuse.grid`, :mod:`care_maps.fuse.instances`, which import
numpy, Arrow and open3d) so the CLI can generate its options from them without paying
for those imports on every ``care`` call. Each field's default and the docstring under it
are the one source of the default and ``--help`` of ``care fuse grid``/``instances``.

A map config holds only what shapes the map: its fingerprint (the map's cache key) and the
settings JSON a map records are of all its fields. How a build runs (read-ahead, memory,
batch sizes, rebuilding a current map, progress bars) is the run's
:class:`care_maps.runtime.execution.Execution`, passed to the builders beside the config.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

from care_maps.core.checks import check_numbers
from care_maps.core.config import member
from care_maps.core.encoders.base import CLIP_LOGIT_SCALE
from care_maps.core.errors import FuseError
from care_maps.core.fingerprint import config_json, fingerprint

__all__ = [
    "DEFAULT_LOGIT_SCALE",
    "DEFAULT_STRIDE",
    "GridConfig",
    "InstanceConfig",
    "InstanceFeatures",
    "ProposalMethod",
]

DEFAULT_LOGIT_SCALE = CLIP_LOGIT_SCALE
"""CLIP's learned logit scale: the default s of softmax(s * f . t) of both maps."""
DEFAULT_STRIDE = 2
"""Depth pixels used by both maps: every second one in both image directions."""


class ProposalMethod(StrEnum):
    """Class-agnostic instance proposals (``care_maps.fuse.proposals.PROPOSERS`` has one function each)."""

    GEOMETRIC = "geometric"
    """Structural planes removed (RANSAC), the rest clustered (DBSCAN); no labels needed."""
    LABELS = "labels"
    """Oracle masks from the recording's instance images."""


class InstanceFeatures(StrEnum):
    """How an instance's per-view feature is made."""

    MASKED = "masked"
    """Dense features pooled inside the projected mask."""
    CROPS = "crops"
    """Bounding-box crops re-encoded (encoders with crop support only)."""


@dataclass(frozen=True)
class GridConfig:
    """What a grid map is fused from (shared by ``care fuse grid``, ``care run`` and
    :func:`care_maps.fuse.grid.build_grid`): every field shapes the map."""

    cell_size: float = 0.05
    """Cell edge in metres."""
    stride: int = DEFAULT_STRIDE
    """Use every stride-th depth pixel in both image directions (1 = full resolution; 2, the
    default, is the same map at a quarter of the work)."""
    z_min: float = -0.2
    """Lowest world height (m) of a fused point; the floor (z = 0) is kept."""
    z_max: float = 2.0
    """Highest world height (m) of a fused point; keeps the ceiling out of the top-down map."""
    sigma_z: float = 2.5
    """Depth scale (m) of the distance weight exp(-z^2 / (2 sigma_z^2))."""
    distance_weighting: bool = True
    """Weight pixels by depth (VLMaps); False gives every pixel weight 1."""
    logit_scale: float = DEFAULT_LOGIT_SCALE
    """Scale s of the class distributions softmax(s * f . t)."""
    vocabulary: tuple[str, ...] | None = None
    """Class names of the columns: a bundled vocabulary name, a file, or comma-separated
    names (default: the names cached in the store)."""
    obstacle_height: float = 0.1
    """A cell whose highest point is above this height (m) is an obstacle."""

    def __post_init__(self) -> None:
        check_numbers(
            FuseError,
            "grid config",
            positive={"cell_size": self.cell_size, "sigma_z": self.sigma_z,
                      "logit_scale": self.logit_scale},
            finite={"z_min": self.z_min, "z_max": self.z_max,
                    "obstacle_height": self.obstacle_height},
            at_least_one={"stride": self.stride},
        )  # fmt: skip
        if self.cell_size <= 0 or self.stride < 1 or self.sigma_z <= 0 or self.z_min > self.z_max:
            msg = (
                f"invalid grid config: cell_size={self.cell_size}, stride={self.stride}, "
                f"sigma_z={self.sigma_z}, z_min={self.z_min}, z_max={self.z_max}; need positive "
                "sizes and z_min <= z_max"
            )
            raise FuseError(msg)

    def fingerprint(self) -> str:
        """The map's cache key: a hash of every field (each one shapes the map)."""
        return fingerprint(self.settings(), length=16)

    def settings(self) -> str:
        """The config as JSON (``care.grid.config_json``), what a later command reuses."""
        return config_json(self)


@dataclass(frozen=True)
class InstanceConfig:
    """What an instance map is built from (shared by ``care fuse instances``, ``care run``
    and :func:`care_maps.fuse.instances.build_instances`; the proposers read their settings from it):
    every field shapes the map."""

    proposals: ProposalMethod = ProposalMethod.GEOMETRIC
    """Proposal method: geometric (planes removed, then DBSCAN) or labels (oracle masks from
    the recording's instance images)."""
    features: InstanceFeatures = InstanceFeatures.MASKED
    """Per-view feature: masked (dense features pooled inside the projected mask) or crops
    (bounding-box crops re-encoded; encoders with crop support only)."""
    voxel_size: float = 0.03
    """Voxel edge (m) of the scene cloud."""
    stride: int = DEFAULT_STRIDE
    """Back-project every stride-th depth pixel in both image directions."""
    max_depth: float = 8.0
    """Depth (m) beyond which pixels are left out of the scene cloud."""
    plane_distance: float = 0.03
    """RANSAC inlier distance (m) of a structural plane (geometric)."""
    max_planes: int = 20
    """Most planes RANSAC looks for (geometric)."""
    plane_min_points: int = 400
    """Smallest plane (points) still considered; the plane search stops below it (geometric)."""
    normal_radius: float = 0.1
    """Neighbourhood radius (m) of the point normals (geometric)."""
    normal_angle_deg: float = 30.0
    """Angle (degrees) within which a normal counts as parallel (to the plane's, or to z)."""
    wall_min_height: float = 1.2
    """Vertical planes spanning at least this height (m) are walls (geometric)."""
    floor_band: float = 0.15
    """Horizontal planes within this height (m) of the lowest/highest points are floor/ceiling."""
    cluster_eps: float = 0.08
    """DBSCAN neighbourhood radius (m); about 2.5 voxels (geometric)."""
    cluster_min_points: int = 10
    """DBSCAN core-point neighbour count (geometric)."""
    min_instance_points: int = 50
    """Clusters with fewer points are dropped as noise (geometric)."""
    min_label_points: int = 10
    """Oracle masks with fewer points are dropped (labels); small, since a label is no noise."""
    max_instance_extent: float = 4.0
    """Clusters longer than this (m) on any axis are structure, not objects (geometric)."""
    top_k: int = 5
    """Views kept per instance (OpenMask3D keeps 5)."""
    depth_tolerance: float = 0.1
    """A point is visible in a view if its depth is within this (m) of the view's depth there."""
    min_visible_points: int = 5
    """A view with fewer visible points of an instance is not one of its views."""
    crop_padding: float = 0.1
    """Crops grow by this fraction of the box size on each side (crops)."""
    logit_scale: float = DEFAULT_LOGIT_SCALE
    """Scale s of the class distributions softmax(s * f . t)."""
    vocabulary: tuple[str, ...] | None = None
    """Class names of the columns: a bundled vocabulary name, a file, or comma-separated
    names (default: the names cached in the store)."""
    seed: int = 0
    """Seed of RANSAC (open3d's global random seed)."""

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(
            self,
            "proposals",
            member(ProposalMethod, self.proposals, FuseError, "unknown proposals"),
        )
        set_(
            self, "features", member(InstanceFeatures, self.features, FuseError, "unknown features")
        )
        sizes = {
            "voxel_size": self.voxel_size,
            "stride": self.stride,
            "max_depth": self.max_depth,
            "plane_distance": self.plane_distance,
            "cluster_eps": self.cluster_eps,
            "top_k": self.top_k,
            "depth_tolerance": self.depth_tolerance,
        }
        bad = [f"{k}={v}" for k, v in sizes.items() if not v > 0]
        check_numbers(
            FuseError,
            "instance config",
            positive={f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                      if f.type in ("float", float) and f.name not in ("crop_padding",)},
            non_negative={"crop_padding": self.crop_padding},
        )  # fmt: skip
        if bad:
            msg = f"invalid instance config: {', '.join(bad)}; these must be positive"
            raise FuseError(msg)

    def fingerprint(self, names: Sequence[str] | None = None) -> str:
        """Hash of the settings ``names`` (default: all of them, the map's cache key)."""
        if names is None:
            return fingerprint(self.settings(), length=16)
        return fingerprint({k: getattr(self, k) for k in names}, length=16)

    def settings(self) -> str:
        """The config as JSON (``care.instances.config_json``), what a later command reuses."""
        return config_json(self)
