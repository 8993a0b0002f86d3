"""What an evaluation and the main job run: :class:`EvalConfig` and :class:`RunConfig`.

They live apart from the job (:mod:`care_maps.evaluate.job`, :mod:`care_maps.evaluate.pipeline`, which import
the whole pipeline) so the CLI can generate ``care eval``'s and ``care run``'s options from
them on every call. Each field's default and docstring are the one source of the option's
default and help; the registries' names are enums (:class:`QueryProtocol` here,
:class:`care_maps.core.maps.MapKind`, :class:`care_maps.replan.strategies.StrategyName`,
:class:`care_maps.replan.strategies.Criterion`, :class:`TravelStart` here).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum, StrEnum
from pathlib import Path

from care_maps.core.checks import check_numbers
from care_maps.core.config import member
from care_maps.core.encoders import EncoderOptions
from care_maps.core.errors import EvalError
from care_maps.core.fingerprint import config_fields, fingerprint
from care_maps.core.maps import MapKind
from care_maps.evaluate.groundtruth import GtSource, UnknownClasses
from care_maps.fuse.config import GridConfig, InstanceConfig
from care_maps.ingest.select import FrameSelection
from care_maps.ingest.source import ReadOptions
from care_maps.query.goals import GoalConfig
from care_maps.replan.attempts import DEFAULT_ATTEMPTS, DEFAULT_EXCLUDE_RADIUS
from care_maps.replan.strategies import Criterion, StrategyName
from care_maps.truth.model import LABEL_DISTANCE

__all__ = ["EvalConfig", "QueryProtocol", "RunConfig", "TravelStart", "grid_protocol"]

NO_CRITERION = "-"
"""The criterion column of the strategies that use no candidate set (their k is 0): a
report's rule key, never parsed out of a display string."""

IOU_THRESHOLD = 0.25
"""An instance attempt succeeds when its mask's point IoU with the ground truth exceeds this."""
DEFAULT_BOOTSTRAP = 1000
"""Resamples of a report's 95% intervals when none is given (:attr:`EvalConfig.bootstrap`)."""


class QueryProtocol(StrEnum):
    """How the instance map's queries are made."""

    INSTANCE = "instance"
    """One query per GT instance that must match that very instance (the paper's)."""
    CLASS = "class"
    """One query per class present; any instance of it succeeds (a robot's need)."""


class TravelStart(StrEnum):
    """Where each attempt sequence of the evaluation starts walking (``docs/evaluation.md``)."""

    FIRST_POSE = "first_pose"
    """The recording's first camera position, on the floor: where the robot was put down."""
    FREE_SPACE = "free_space"
    """A cell drawn per query (seeded) from the largest connected region of free space."""
    OFF = "off"
    """No walking: path length and SPL are left out (NaN)."""


def grid_protocol(radius: float) -> str:
    """The protocol name of a grid evaluation with exclusion ``radius`` (m), as every table
    shows it: ``next-cell`` for 0 (the paper's literal rule), else ``exclude-<r>m``."""
    return "next-cell" if radius == 0 else f"exclude-{radius:g}m"


def _one(kind: type[Enum], value: object, option: str) -> Enum:
    return member(kind, value, EvalError, f"invalid evaluation config: {option}")


@dataclass(frozen=True)
class EvalConfig:
    """What an evaluation runs (shared by ``care eval``, ``care run`` and the Python API)."""

    maps: tuple[MapKind, ...] = (MapKind.INSTANCES, MapKind.GRID)
    """Map kinds to evaluate: ``instances`` (OpenMask3D-like) and/or ``grid`` (VLMaps-like)."""
    strategies: tuple[StrategyName, ...] = tuple(StrategyName)
    """Replan strategies (default: all of ``replan.STRATEGIES``)."""
    criteria: tuple[Criterion, ...] = tuple(Criterion)
    """Selection criteria of the set-based strategies."""
    k_instances: tuple[int, ...] = (2, 4, 8, 16, 40)
    """k of the candidate sets on the instance map (the paper's Table 1)."""
    k_grid: tuple[int, ...] = (4, 8, 16, 40, 100)
    """k of the candidate sets on the grid map (the paper's Table 2)."""
    attempts: int = DEFAULT_ATTEMPTS
    """Attempts per query: the first by max confidence, then the strategy after each failure."""
    protocols: tuple[QueryProtocol, ...] = tuple(QueryProtocol)
    """Instance-map query protocols: ``instance`` (the paper's) and/or ``class``."""
    iou_threshold: float = IOU_THRESHOLD
    """An instance attempt succeeds when its mask's point IoU with the GT mask exceeds this."""
    success_radius: float = 1.0
    """A grid attempt succeeds within this floor-plane distance (m) of an object of the class."""
    exclude_radii: tuple[float, ...] = (0.0, DEFAULT_EXCLUDE_RADIUS)
    """Grid protocols: after a failed grid attempt, cells within this distance (m) of it are
    skipped, each radius its own protocol in every table (0: the paper's next unvisited cell)."""
    rooms: bool = True
    """Evaluate room by room (each room its own candidate set) where the GT has rooms."""
    seeds: int = 10
    """Seeds the random strategies are averaged over."""
    seed: int = 0
    """Base seed of every random draw."""
    label_distance: float = LABEL_DISTANCE
    """Scene points farther than this (m) from every GT point get no GT label."""
    bootstrap: int = DEFAULT_BOOTSTRAP
    """Resamples of the 95% intervals: random sign patterns of the scene-level test above 16
    scenes (every pattern below); 0: no intervals."""
    unknown_classes: UnknownClasses = UnknownClasses.REFUSE
    """Ground-truth classes the map's vocabulary lacks: refuse the scene, or ignore them."""
    travel_start: TravelStart = TravelStart.FIRST_POSE
    """Where each attempt sequence starts walking (each attempt then from the goal before):
    the recording's first pose, a seeded free-space cell per query, or off (no path length
    and SPL)."""
    clearance: float = GoalConfig.clearance
    """The robot's radius (m): the walks keep it from every obstacle, as the goals do."""

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(
            self,
            "unknown_classes",
            _one(UnknownClasses, self.unknown_classes, "--gt-unknown-classes"),
        )
        set_(self, "travel_start", _one(TravelStart, self.travel_start, "--travel-start"))
        for name, kind in (("maps", MapKind), ("strategies", StrategyName),
                           ("criteria", Criterion), ("protocols", QueryProtocol)):  # fmt: skip
            set_(self, name, tuple(_one(kind, v, f"--{name}") for v in getattr(self, name)))
        check_numbers(
            EvalError,
            "evaluation config",
            positive={"iou_threshold": self.iou_threshold, "success_radius": self.success_radius,
                      "label_distance": self.label_distance},
            non_negative={"bootstrap": self.bootstrap, "clearance": self.clearance,
                          **{f"exclude_radii[{i}]": r for i, r in enumerate(self.exclude_radii)}},
        )  # fmt: skip
        set_(self, "exclude_radii", tuple(float(r) for r in self.exclude_radii))
        if len(set(map(grid_protocol, self.exclude_radii))) < len(self.exclude_radii):
            msg = (
                f"invalid evaluation config: --exclude-radii {self.exclude_radii} repeats a radius"
            )
            raise EvalError(msg)
        bad = [f"k={k}" for k in (*self.k_grid, *self.k_instances) if not 1 <= k <= 32767]
        bad += [
            name
            for name in ("strategies", "maps", "protocols", "criteria", "exclude_radii")
            if not getattr(self, name)
        ]
        if bad or self.attempts < 1 or self.seeds < 1:
            msg = (
                f"invalid evaluation config: {bad} (out of range or empty), "
                f"attempts={self.attempts}, seeds={self.seeds}; k 1..32767; "
                "attempts and seeds >= 1"
            )
            raise EvalError(msg)

    def ks(self, kind: MapKind | str) -> tuple[int, ...]:
        return self.k_grid if kind == MapKind.GRID else self.k_instances

    def fingerprint(self) -> str:
        """Hash of everything that shapes a scene's attempts (not ``bootstrap``)."""
        return fingerprint(config_fields(self, ("bootstrap",)), length=16)


@dataclass(frozen=True)
class RunConfig:
    """What the main job makes (the CLI's ``care run`` options); how it runs (workers, Ray,
    progress) is the run's :class:`care_maps.runtime.execution.Execution`."""

    encoder: str = "labels"
    """Encoder of ``care ingest`` (``labels``: the sample world's perception model)."""
    encoder_options: EncoderOptions = field(default_factory=EncoderOptions)
    """Its options (``--weights`` for ``clip``, ...)."""
    vocabulary: str | None = None
    """Class names to cache at ingest (default: the recording's own class names)."""
    read: ReadOptions = field(default_factory=ReadOptions)
    """How each recording is read (topics, frames, poses), as ``care ingest`` takes it."""
    select: FrameSelection = field(default_factory=FrameSelection)
    """Which frames of each recording are kept, as ``care ingest`` takes it."""
    grid: GridConfig = field(default_factory=GridConfig)
    """Grid map settings (the defaults of ``care fuse grid``: neither rebuilds the other's map)."""
    instances: InstanceConfig = field(default_factory=InstanceConfig)
    """Instance map settings."""
    evaluation: EvalConfig = field(default_factory=EvalConfig)
    """What the evaluation runs."""
    gt: tuple[Path, ...] = ()
    """Ground truth of each recording, in order (default: its index entry's, or beside it)."""
    gt_defaults: GtSource = field(default_factory=GtSource)
    """Format, frame transform and class map of ground truth that names none."""
    rrd_ingest: bool = True
    """Also write ``<name>.ingest.rrd`` (camera images, depth, the map building up)."""
    rrd_class: str | None = None
    """Class of the grid recording's confidence layer (default: one layer per query class of
    the scene's evaluation)."""
