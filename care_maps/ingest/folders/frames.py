"""A dataset folder as the stream of frames ingest reads, and the one function that opens
any source (recording or folder).

:class:`FolderFrames` stands where :class:`care_maps.ingest.source.RecordingFrames` stands for a
recording, with the same surface (a context manager; ``world_frame``, ``camera_frame``,
``label_names``, ``stats``, ``distortions``, ``total``, :meth:`describe`; iterating yields
:class:`care_maps.core.frames.Frame` in stamp order), so the pipeline and ``care topics`` treat both
alike. What a recording needs (topics, TF, camera info) a layout gives from its own files.

Of :class:`care_maps.ingest.source.ReadOptions` a folder takes ``format``, ``max_dt`` (where a layout
associates by time), the pose bounds ``max_translation`` and ``max_speed``,
``accept_geometry``, and what the user states about the folder's camera and poses
(``intrinsics``, ``depth_scale``, ``pose_convention``, ``quaternion_order``,
``camera_convention``: :class:`care_maps.ingest.folders.base.FolderOptions`, applied by the layouts'
common base); any other option names a topic or frame only a recording has, and is refused
in one line rather than ignored. The pose bounds are checked here with messages that name
the view's image and the layout's poses file (a recording's name its topics and TF, and
point at ``--pose-source``, which a folder has not). Lens distortion (a TUM sensor's, or a
given ``--intrinsics``') is removed here, from colour and depth alike, whatever the layout.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.core.frames import DEFAULT_CAMERA_FRAME, Frame
from care_maps.ingest.folders import LAYOUTS, DatasetLayout, FolderLayout, detect_layout
from care_maps.ingest.folders.base import FolderOptions, FolderView
from care_maps.ingest.parts import Recording, parts_label, recording_parts
from care_maps.ingest.readers import ClosedOnExit
from care_maps.ingest.source import ReadOptions, ReadStats, RecordingFrames
from care_maps.ingest.undistort import Distortion, undistort

__all__ = [
    "FOLDER_OPTIONS",
    "FolderFrames",
    "Frames",
    "folder_identity",
    "open_frames",
    "resolve_layout",
]

FOLDER_OPTIONS = (
    "format",
    "max_dt",
    "max_translation",
    "max_speed",
    "accept_geometry",
    *(f.name for f in fields(FolderOptions)),
)
"""The :class:`care_maps.ingest.source.ReadOptions` fields a dataset folder takes."""
_RIGID_TOLERANCE = 1e-3
"""Largest deviation of a pose's rotation from orthonormal (and of its last row from
0 0 0 1): text files with six decimals stay far inside it, a scaled or projective matrix
(another convention) far outside."""


def _is_rosbag2(path: Path) -> bool:
    return (path / "metadata.yaml").is_file()


def resolve_layout(path: Path, forced: DatasetLayout | None = None) -> DatasetLayout | None:
    """The layout ``path`` is read with: ``forced`` (``--format``), else the one its names
    match; None for a recording (a file or a rosbag2 directory). A folder that is neither a
    recording nor of a known layout is refused here, naming the layouts."""
    path = Path(path)
    folder = path.is_dir() and not _is_rosbag2(path)
    if forced is not None:
        forced = DatasetLayout(forced)
        if not folder:
            msg = f"{path}: --format {forced} reads dataset folders, and this is a recording; leave --format out."
            raise IngestError(msg)
        if forced not in LAYOUTS:
            readers = ", ".join(str(k) for k in LAYOUTS)
            msg = f"{path}: no reader for --format {forced} here (readers: {readers})."
            raise IngestError(msg)
        return forced
    if not folder:
        return None
    kind = detect_layout(path)
    if kind is None:
        known = ", ".join(str(k) for k in LAYOUTS)
        msg = f"{path}: neither a rosbag2 recording (no metadata.yaml) nor a dataset folder of a known layout ({known}; docs/inputs.md lists what each holds); pass the recording, or --format LAYOUT to be told what the folder lacks."
        raise IngestError(msg)
    return kind


def open_frames(path: Recording, options: ReadOptions | None = None) -> Frames:
    """The frames of ``path`` (not yet entered: ``with open_frames(p, o) as frames``): a
    :class:`FolderFrames` for a dataset folder, else a :class:`care_maps.ingest.source.RecordingFrames`
    (of one recording's several files too, :mod:`care_maps.ingest.parts`)."""
    options = options or ReadOptions()
    parts = recording_parts(path)
    if len(parts) > 1:
        if options.format is not None:
            msg = f"{parts_label(parts)}: --format {options.format} reads dataset folders, and these are the files of a recording; leave --format out."
            raise IngestError(msg)
        return RecordingFrames(parts, options)
    path = parts[0]
    kind = resolve_layout(path, options.format)
    if kind is None:
        return RecordingFrames(path, options)
    return FolderFrames(path, options, kind)


def folder_identity(path: Path, options: ReadOptions) -> dict[str, Any] | None:
    """What a dataset folder is read as, for the store's source identity and fingerprint: the
    layout and what it reads the folder with (intrinsics, depth scale, files), so reading it
    as another layout, or a calibration that lies outside the folder changing, rebuilds the
    store. None for a recording (its identity is its bytes alone)."""
    kind = resolve_layout(path, options.format)
    if kind is None:
        return None
    return {"kind": str(kind), **open_layout(path, kind, options).identity()}


def open_layout(path: Path, kind: DatasetLayout, options: ReadOptions) -> FolderLayout:
    """The layout ``kind`` of ``path`` with what ``options`` states about the folder."""
    return LAYOUTS[kind](Path(path), max_dt=options.max_dt, options=FolderOptions.of(options))


class FolderFrames(ClosedOnExit):
    """Context manager over a dataset folder; iterate it (once) for posed frames."""

    def __init__(
        self, path: Path, options: ReadOptions | None = None, kind: DatasetLayout | None = None
    ) -> None:
        self.path = Path(path)
        self.options = options or ReadOptions()
        self.kind = kind
        self.stats = ReadStats()
        self.label_names: tuple[str, ...] = ()
        self.world_frame: str | None = None
        self.camera_frame: str | None = None
        self._layout: FolderLayout | None = None
        self._views: list[FolderView] = []
        self._last_pose: tuple[int, np.ndarray] | None = None
        self._poses_file = ""

    def __enter__(self) -> FolderFrames:
        self._refuse_recording_options()
        kind = self.kind or resolve_layout(self.path, self.options.format)
        if kind is None:
            msg = f"{self.path}: not a dataset folder; read it as a recording."
            raise IngestError(msg)
        self.kind = kind
        layout = open_layout(self.path, kind, self.options)
        views = layout.views()
        stamps = [v.stamp_ns for v in views]
        if any(b <= a for a, b in itertools.pairwise(stamps)):
            msg = f"{self.path}: the {kind} layout listed two views at one stamp or out of order; fix the folder's lists."
            raise IngestError(msg)
        self._layout, self._views = layout, views
        self._poses_file = str(layout.describe().get("poses", "its poses"))
        self.world_frame, self.camera_frame = layout.world_frame, DEFAULT_CAMERA_FRAME
        self.label_names = tuple(layout.label_names())
        self.stats.rgb_messages = len(views) + sum(layout.dropped.values())
        self.stats.dropped.update(layout.dropped)
        return self

    def close(self) -> None:
        """Nothing stays open between views: each image is read and closed in turn."""

    def _refuse_recording_options(self) -> None:
        given = [
            f.name
            for f in fields(ReadOptions)
            if f.name not in FOLDER_OPTIONS and getattr(self.options, f.name) != f.default
        ]
        if given:
            flags = ", ".join("--" + name.replace("_", "-") for name in given)
            msg = f"{self.path}: {flags} only apply to recordings (their topics, frames and poses), and a dataset folder has none; leave them out (a folder's layout gives its images, poses and camera: docs/inputs.md)."
            raise IngestError(msg)

    @property
    def layout(self) -> FolderLayout | None:
        """The layout reading the folder (once entered): what it reads the poses, depth and
        camera with, for the consistency check's fix (:mod:`care_maps.ingest.consistency`)."""
        return self._layout

    @property
    def total(self) -> int:
        """Views the folder lists (the progress bar's length)."""
        return len(self._views)

    @property
    def distortions(self) -> list[Distortion]:
        """The lens distortions removed from the images (as a recording's camera infos)."""
        return self._layout.distortions() if self._layout is not None else []

    def describe(self) -> dict[str, Any]:
        """The layout and what it read, for ``care topics`` and the store's meta.json."""
        layout = self._layout
        return {
            "topics": None
            if layout is None
            else {"layout": str(self.kind), "views": len(self._views), **layout.identity()},
            "world_frame": self.world_frame,
            "camera_frame": self.camera_frame,
            "label_names": list(self.label_names),
            "options": asdict(self.options),
        }

    def __iter__(self) -> Iterator[Frame]:
        layout = self._layout
        if layout is None:
            msg = "FolderFrames must be entered (with ...) before iterating"
            raise IngestError(msg)
        for view in self._views:
            # tracking lost (ScanNet's -inf poses): no pose, skipped as the datasets' loaders do
            if not np.isfinite(view.cam_to_world).all():
                self.stats.dropped["no_pose"] += 1
                continue
            layout.lost_pixels.clear()
            frame = layout.load(view)
            if frame.depth_m.shape != frame.rgb.shape[:2]:
                msg = f"{view.depth}: depth image is {frame.depth_m.shape[1]}x{frame.depth_m.shape[0]}, its colour image {view.colour.name} {frame.width}x{frame.height}; the {self.kind} layout pairs them pixel by pixel (re-copy the folder, or check --format)."
                raise IngestError(msg)
            frame = self._undistorted(frame)
            if not frame.depth_m.any():
                self.stats.dropped["no_valid_depth"] += 1
                continue
            self._check_pose(frame, view)
            self.stats.frames += 1
            self.stats.lost_pixels.update(layout.lost_pixels)
            yield frame
        if self.stats.frames == 0:
            msg = f"{self.path}: none of the {len(self._views)} views has a pose and valid depth ({dict(self.stats.dropped)}); check the folder's poses and depth images."
            raise IngestError(msg)

    def _undistorted(self, frame: Frame) -> Frame:
        """``frame`` with the layout's lens distortion removed from colour (blended) and
        depth (nearest: a blend of two depths is a point in mid-air), so their pixels stay
        paired; the colour file's own JPEG bytes then differ from its pixels, and are not kept."""
        lens = self._layout.lens() if self._layout is not None else None
        if lens is None or lens.is_zero:
            return frame
        rgb = undistort(frame.rgb, frame.K, lens, blend=True)
        depth = undistort(frame.depth_m, frame.K, lens, blend=False)
        return replace(frame, rgb=rgb, depth_m=depth, rgb_jpeg=None)

    def _check_pose(self, frame: Frame, view: FolderView) -> None:
        """Refuse a pose no camera can have: not rigid (a file in another convention),
        farther than ``max_translation`` from the origin, or reached faster than
        ``max_speed`` from the previous view (the bounds of a recording's poses)."""
        o = self.options
        where = f"{self.path}: view {view.colour.name} (pose from {self._poses_file})"
        T = np.asarray(frame.cam_to_world, np.float64)
        R = T[:3, :3]
        rigid = (
            np.abs(R.T @ R - np.eye(3)).max() <= _RIGID_TOLERANCE
            and np.linalg.det(R) > 0
            and np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() <= _RIGID_TOLERANCE
        )
        if not rigid:
            msg = f"{where}: {T.round(4).tolist()} is not a rigid camera pose (rotation not orthonormal, or a last row other than 0 0 0 1); the file is not in the {self.kind} layout's convention (check --format, or fix the file)."
            raise IngestError(msg)
        position = T[:3, 3]
        distance = float(np.linalg.norm(position))
        if distance > o.max_translation:
            msg = f"{where}: the camera lies {distance:.4g} m from the origin, beyond --max-translation {o.max_translation:g} m; the poses file is corrupt there (fix it), or, if the world is that large, raise --max-translation."
            raise IngestError(msg)
        if self._last_pose is not None:
            last_stamp, last_position = self._last_pose
            step = float(np.linalg.norm(position - last_position))
            dt = (frame.stamp_ns - last_stamp) / 1e9
            speed = step / dt if dt > 0 else math.inf
            if speed > o.max_speed:
                msg = f"{where}: the camera moved {step:.4g} m in {dt * 1e3:.4g} ms since the previous view: {speed:.4g} m/s, faster than --max-speed {o.max_speed:g} m/s; the poses jump there (fix the file), or, if the camera moves that fast, raise --max-speed."
                raise IngestError(msg)
        self._last_pose = (frame.stamp_ns, position)


Frames = RecordingFrames | FolderFrames
"""What :func:`open_frames` returns: the frames of a recording or of a dataset folder."""
