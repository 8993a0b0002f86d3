"""What every dataset folder layout provides: its views (cheap, from its text files) and
each view decoded into a :class:`care.frames.Frame` in our conventions.

Public RGB-D datasets ship as folders of images with a poses file, each with its own depth
scale, pose convention and timing. A layout converts all of that once, here, so ingest sees
the same :class:`~care.frames.Frame` as from a bag: colour uint8, depth float32 metres
registered to the colour image (0 = invalid), ``K`` of the colour image as returned, and
``cam_to_world`` in the optical convention (x right, y down, z forward) in metres.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections import Counter
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from care.frames import Frame
from ingest.undistort import Distortion

__all__ = ["FRAME_PERIOD_NS", "DatasetLayout", "FolderLayout", "FolderView", "nominal_stamp_ns"]

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
    GENERIC = "generic"
    """Our documented layout: ``rgb/``, ``depth/``, ``poses.txt``, ``intrinsics.json``."""


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

    def __init__(self, path: Path, *, max_dt: float) -> None:
        """``max_dt``: seconds, the largest stamp difference where a layout associates
        colour, depth and poses by time (TUM)."""
        self.path = Path(path)
        self.max_dt = max_dt
        self.dropped: Counter[str] = Counter()
        """Colour images :meth:`views` left out, by reason (the keys of
        :attr:`ingest.source.ReadStats.dropped`: ``no_depth``, ``no_pose``)."""

    @classmethod
    @abstractmethod
    def detect(cls, path: Path) -> bool:
        """Whether ``path`` is a folder in this layout (by the names it holds, no decoding)."""

    @abstractmethod
    def views(self) -> list[FolderView]:
        """Every view in stamp order, from the folder's text files (no image decoded).
        A missing or malformed file raises :class:`care.errors.IngestError` naming it."""

    @abstractmethod
    def load(self, view: FolderView) -> Frame:
        """The view decoded: colour, depth in metres registered to the colour image as
        returned, its ``K``, the view's pose. Raises :class:`care.errors.IngestError`
        naming the file when an image cannot be read."""

    def label_names(self) -> tuple[str, ...]:
        """Class names the folder ships for label images; none by default."""
        return ()

    def describe(self) -> dict[str, Any]:
        """What the layout read the folder with, as plain JSON values (file names relative
        to the folder, intrinsics, depth scale): printed by ``care topics``, recorded in the
        store and part of its fingerprint, so a changed calibration rebuilds the store."""
        return {}

    def distortions(self) -> list[Distortion]:
        """The lens distortions :meth:`load` removes from the images (none by default)."""
        return []
