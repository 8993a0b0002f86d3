"""What every dataset folder layout provides: its views (cheap, from its text files) and
each view decoded into a :class:`care_maps.core.frames.Frame` in our conventions.

Public RGB-D datasets ship as folders of images with a poses file, each with its own depth
scale, pose convention and timing. A layout converts all of that once, here, so ingest sees
the same :class:`~care_maps.core.frames.Frame` as from a bag: colour uint8, depth float32 metres
registered to the colour image (0 = invalid), ``K`` of the colour image as returned, and
``cam_to_world`` in the optical convention (x right, y down, z forward) in metres.

What the user states about a folder (:class:`FolderOptions`: ``--intrinsics``,
``--depth-scale``, ``--pose-convention``, ``--quaternion-order``, ``--camera-convention``)
is applied here, once for every layout: a layout asks :meth:`FolderLayout.camera`,
:meth:`FolderLayout.scale` and :meth:`FolderLayout.file_pose` instead of using its own
values directly, and :meth:`FolderLayout.identity` records what was given, so a store read
another way is another store.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections import Counter
from dataclasses import dataclass, field, fields
from enum import StrEnum
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame
from care_maps.ingest.conventions import (
    CameraConvention,
    PoseConvention,
    QuaternionOrder,
    optical_pose,
)
from care_maps.ingest.folders.files import Intrinsics
from care_maps.ingest.intrinsics import CameraIntrinsics
from care_maps.ingest.undistort import NO_DISTORTION, Distortion, parse_distortion

__all__ = [
    "FRAME_PERIOD_NS",
    "GIVEN_CAMERA",
    "DatasetLayout",
    "FolderLayout",
    "FolderOptions",
    "FolderView",
    "nominal_stamp_ns",
]

FRAME_PERIOD_NS = 33_333_333
"""The frame period of a dataset that records no times (30 Hz: the rate of the Kinect-class
sensors these datasets were captured with, and the rate their renders imitate)."""


def nominal_stamp_ns(index: int) -> int:
    """The stamp of view ``index`` of a dataset without times: its index at 30 Hz, so the
    speed bound (``--max-speed``) and time selections (``--start``) mean what they say."""
    return index * FRAME_PERIOD_NS


class DatasetLayout(StrEnum):
    """A dataset folder's layout (``--format`` on a folder)."""

    SCANNET = "scannet"
    """ScanNet's exported frames: ``color/``, ``depth/``, ``pose/``, ``intrinsic/``."""
    REPLICA = "replica"
    """Replica as NICE-SLAM/iMAP render it: ``results/frame*.jpg``, ``depth*.png``,
    ``traj.txt``."""
    TUM = "tum"
    """TUM RGB-D: ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, associated by stamp."""
    REDWOOD = "redwood"
    """ICL-NUIM / Redwood: ``image/`` (or ``rgb/``), ``depth/``, ``trajectory.log``."""
    MATTERPORT = "matterport"
    """Matterport3D undistorted frames: ``undistorted_color_images``,
    ``undistorted_depth_images``, ``undistorted_camera_parameters``."""
    ETH3D = "eth3d"
    """ETH3D SLAM: TUM's lists with ``calibration.txt`` (``fx fy cx cy``) and
    ``associated.txt``."""
    BONN = "bonn"
    """Bonn RGB-D Dynamic: TUM's lists in a folder named ``rgbd_bonn_*``."""
    SEVEN_SCENES = "7scenes"
    """Microsoft RGB-D 7-Scenes, one sequence: ``frame-000000.color.png``, ``.depth.png``,
    ``.pose.txt``."""
    GENERIC = "generic"
    """Our documented layout: ``rgb/``, ``depth/``, ``poses.txt``, ``intrinsics.json``."""


GIVEN_CAMERA = "--intrinsics"
"""The source recorded for a camera the user gave (``describe()["intrinsics"]["source"]``)."""


@dataclass(frozen=True)
class FolderOptions:
    """The :class:`care_maps.ingest.source.ReadOptions` fields that change how a layout reads a folder
    (each None: the layout's own). Their docs are ReadOptions'; this copy keeps the layouts
    free of the recording reader's imports."""

    intrinsics: CameraIntrinsics | None = None
    depth_scale: float | None = None
    pose_convention: PoseConvention | None = None
    quaternion_order: QuaternionOrder | None = None
    camera_convention: CameraConvention | None = None

    @classmethod
    def of(cls, options: Any) -> FolderOptions:
        """The fields of ``options`` (a ReadOptions, or None) this class names."""
        if options is None:
            return cls()
        return cls(**{f.name: getattr(options, f.name) for f in fields(cls)})


@dataclass(frozen=True)
class FolderView:
    """One view of a dataset folder before decoding: where its images are and its pose."""

    stamp_ns: int
    """Stamp of the colour image (from the dataset's own times, or the frame index at the
    dataset's nominal rate when it has none)."""
    colour: Path
    depth: Path
    cam_to_world: np.ndarray = field(repr=False)
    """(4, 4) optical-frame camera-to-world pose in metres."""


class FolderLayout(ABC):
    """A dataset folder read as views; one subclass per :class:`DatasetLayout`."""

    kind: ClassVar[DatasetLayout]
    world_frame: ClassVar[str]
    """The name recorded for the dataset's world frame (e.g. ``scannet_world``)."""
    pose_lines: ClassVar[bool] = False
    """Whether the poses file holds ``tx ty tz`` and a quaternion per line (TUM's format),
    the poses ``--quaternion-order`` speaks of; else 4x4 matrices, where it is refused."""
    own_camera_axes: ClassVar[str] = ""
    """The camera axes the dataset's poses are of when they are not an optical frame's and
    the layout converts them (Matterport's OpenGL camera): ``--camera-convention`` is then
    refused, the convention is the dataset's."""

    def __init__(self, path: Path, *, max_dt: float, options: FolderOptions | None = None) -> None:
        """``max_dt``: seconds, the largest stamp difference where a layout associates
        colour, depth and poses by time (TUM); ``options``: what the user states about the
        folder (refused here, in one line, where the layout cannot take it)."""
        self.path = Path(path)
        self.max_dt = max_dt
        self.options = options or FolderOptions()
        self.dropped: Counter[str] = Counter()
        """Colour images :meth:`views` left out, by reason (the keys of
        :attr:`ingest.source.ReadStats.dropped`: ``no_depth``, ``no_pose``)."""
        self.lost_pixels: Counter[str] = Counter()
        """Valid depth pixels the last :meth:`load` left out, by reason (the keys of
        :attr:`ingest.source.ReadStats.lost_pixels`)."""
        self._refuse_options()

    def _refuse_options(self) -> None:
        o = self.options
        if o.quaternion_order is not None and not self.pose_lines:
            msg = f"{self.path}: --quaternion-order speaks of pose lines tx ty tz q q q q, and the {self.kind} layout's poses are 4x4 matrices; leave it out."
            raise IngestError(msg)
        if o.camera_convention is not None and self.own_camera_axes:
            msg = f"{self.path}: --camera-convention: the {self.kind} layout's poses are of {self.own_camera_axes}, which it converts itself; leave it out."
            raise IngestError(msg)

    # -- what the user states, applied once for every layout ---------------------------------
    def camera(
        self, own: Intrinsics | None = None, lens: Distortion = NO_DISTORTION
    ) -> tuple[Intrinsics, Distortion]:
        """The camera of the views: ``--intrinsics`` when given (its lens too), else the
        layout's own ``(own, lens)``; ``own`` None means the layout has none to offer."""
        given = self.options.intrinsics
        if given is not None:
            return Intrinsics.of(given, GIVEN_CAMERA), self._given_lens(given)
        if own is None:
            msg = f"{self.path}: the {self.kind} layout has no camera for this folder; give it with --intrinsics (docs/inputs.md)."
            raise IngestError(msg)
        return own, lens

    @staticmethod
    def _given_lens(given: CameraIntrinsics) -> Distortion:
        return parse_distortion(given.distortion_model, given.distortion, GIVEN_CAMERA)

    def scale(self, own: float) -> float:
        """The depth value of one metre: ``--depth-scale`` when given, else the layout's."""
        return own if self.options.depth_scale is None else float(self.options.depth_scale)

    def pose_convention(self) -> PoseConvention:
        """Which way the poses file maps points: ``--pose-convention``, else the layout's
        own (:meth:`own_pose_convention`)."""
        return self.options.pose_convention or self.own_pose_convention()

    def own_pose_convention(self) -> PoseConvention:
        """The layout's (or its files') pose convention: camera-to-world for every dataset."""
        return PoseConvention.CAMERA_TO_WORLD

    def quaternion_order(self) -> QuaternionOrder:
        """The order of a pose line's quaternion: ``--quaternion-order``, else the layout's."""
        return self.options.quaternion_order or self.own_quaternion_order()

    def own_quaternion_order(self) -> QuaternionOrder:
        """TUM's ``qx qy qz qw``, the order of every dataset's pose lines."""
        return QuaternionOrder.XYZW

    def file_pose(self, matrix: np.ndarray) -> np.ndarray:
        """A pose as the poses file states it, made the camera-to-world pose of the camera
        the file speaks of: inverted for world-to-camera files, a body frame's turned into
        the optical frame (``--camera-convention body``). A layout calls it on every pose it
        reads, before interpolating or its own conversions; a non-finite pose (tracking
        lost) stays one."""
        pose: np.ndarray = np.asarray(matrix, np.float64)
        if not np.isfinite(pose).all():
            return pose
        if self.pose_convention() is PoseConvention.WORLD_TO_CAMERA:
            pose = np.linalg.inv(pose)
        convention = self.options.camera_convention or CameraConvention.OPTICAL
        return optical_pose(pose, convention)

    def identity(self) -> dict[str, Any]:
        """:meth:`describe` and the reading conventions that differ from the layout's
        defaults (so stores read the default way keep their fingerprints)."""
        chosen = {
            "pose_convention": (self.pose_convention(), PoseConvention.CAMERA_TO_WORLD),
            "quaternion_order": (
                self.quaternion_order() if self.pose_lines else None,
                QuaternionOrder.XYZW if self.pose_lines else None,
            ),
            "camera_convention": (self.options.camera_convention, None),
        }
        changed = {k: str(v) for k, (v, default) in chosen.items() if v not in (None, default)}
        described = self.describe()
        lens = self.lens()
        if not lens.is_zero:  # a given camera's lens, where the layout states none itself
            described.setdefault("distortion", lens.as_json())
        return {**described, **changed}

    @classmethod
    @abstractmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` is a folder in this layout (by the names it holds, no decoding)."""

    @abstractmethod
    def views(self) -> list[FolderView]:
        """Every view in stamp order, from the folder's text files (no image decoded).
        A missing or malformed file raises :class:`care_maps.core.errors.IngestError` naming it."""

    @abstractmethod
    def load(self, view: FolderView) -> Frame:
        """The view decoded: colour, depth in metres registered to the colour image as
        returned, its ``K``, the view's pose. Raises :class:`care_maps.core.errors.IngestError`
        naming the file when an image cannot be read."""

    def label_names(self) -> tuple[str, ...]:
        """Class names the folder ships for label images; none by default."""
        return ()

    def describe(self) -> dict[str, Any]:
        """What the layout read the folder with, as plain JSON values (file names relative
        to the folder, intrinsics, depth scale): printed by ``care topics``, recorded in the
        store and part of its fingerprint, so a changed calibration rebuilds the store."""
        return {}

    def lens(self) -> Distortion:
        """The lens distortion of the images :meth:`load` returns, removed from colour and
        depth alike by :class:`care_maps.ingest.folders.frames.FolderFrames` (none by default; a given
        ``--intrinsics`` brings its own)."""
        given = self.options.intrinsics
        return NO_DISTORTION if given is None else self._given_lens(given)

    def distortions(self) -> list[Distortion]:
        """The lens distortions removed from the images (as a recording's camera infos)."""
        lens = self.lens()
        return [] if lens.is_zero else [lens]
