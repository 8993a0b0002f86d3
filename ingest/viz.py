"""Rerun logging of an ingest run (``care ingest ... --rrd PATH``).

Everything lies on the ``stamp`` timeline. Named transform frames mirror the recording's TF
names: the world entity is in the world frame (e.g. ``map``), a Transform3D relates it to
the camera's optical frame (e.g. ``camera_optical_frame``), and the pinhole relates that to
the image plane (``<camera frame>/image``), so the viewer shows the same frame names as
``tf2`` would.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import rerun as rr

from care.frames import Frame
from care.geometry import backproject, transform_points
from care.viz import open_recording, set_stamp

__all__ = [
    "CAMERA_ENTITY",
    "DEPTH_ENTITY",
    "IMAGE_ENTITY",
    "POINTS_ENTITY",
    "RGB_ENTITY",
    "TRAJECTORY_ENTITY",
    "TRANSFORM_ENTITY",
    "IngestLogger",
]

WORLD_ENTITY = "world"
TRANSFORM_ENTITY = "world/tf/camera"
CAMERA_ENTITY = "world/camera"
IMAGE_ENTITY = "world/camera/image"
RGB_ENTITY = "world/camera/image/rgb"
DEPTH_ENTITY = "world/camera/image/depth"
POINTS_ENTITY = "world/points"
TRAJECTORY_ENTITY = "world/trajectory"

_POINT_STRIDE = 4
"""Pixels between back-projected points (16x fewer points than pixels)."""


class IngestLogger:
    """Logs frames as they are ingested into a temporary file.

    :meth:`close` writes the trajectory and flushes; then :meth:`keep` renames the file
    into place (or :meth:`discard` removes it after a failed run).
    """

    def __init__(
        self,
        rrd_path: Path,
        *,
        every: int = 10,
        world_frame: str = "map",
        camera_frame: str = "camera_optical_frame",
    ) -> None:
        self.path = Path(rrd_path)
        self.tmp = self.path.with_name(f".{self.path.name}.tmp-{os.getpid()}")
        self.rec = open_recording("care-ingest", self.tmp)
        self.every = max(1, int(every))
        self.world_frame = world_frame or "map"
        self.camera_frame = camera_frame or "camera_optical_frame"
        self.image_frame = f"{self.camera_frame}/image"
        self._positions: list[np.ndarray] = []
        self._last_stamp = 0
        self._static_done = False

    def _log_static(self) -> None:
        rec = self.rec
        world = rr.CoordinateFrame(self.world_frame)
        rec.log(WORLD_ENTITY, world, static=True)
        for entity in (POINTS_ENTITY, TRAJECTORY_ENTITY):
            rec.log(entity, world, static=True)
        rec.log(CAMERA_ENTITY, rr.CoordinateFrame(self.camera_frame), static=True)
        rec.log(IMAGE_ENTITY, rr.CoordinateFrame(self.image_frame), static=True)
        for entity in (RGB_ENTITY, DEPTH_ENTITY):
            rec.log(entity, rr.CoordinateFrame(self.image_frame), static=True)
        self._static_done = True

    def log(self, index: int, frame: Frame) -> None:
        """Log frame number ``index`` (0-based) of the run."""
        if not self._static_done:
            self._log_static()
        rec = self.rec
        set_stamp(rec, frame.stamp_ns)
        T = np.asarray(frame.cam_to_world, np.float64)
        rec.log(
            TRANSFORM_ENTITY,
            rr.Transform3D(
                translation=T[:3, 3],
                mat3x3=T[:3, :3],
                parent_frame=self.world_frame,
                child_frame=self.camera_frame,
            ),
        )
        rec.log(
            CAMERA_ENTITY,
            rr.Pinhole(
                image_from_camera=frame.K,
                width=frame.width,
                height=frame.height,
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=0.3,
                parent_frame=self.camera_frame,
                child_frame=self.image_frame,
            ),
        )
        rec.log(RGB_ENTITY, rr.Image(frame.rgb))
        rec.log(DEPTH_ENTITY, rr.DepthImage(frame.depth_m, meter=1.0))
        self._positions.append(T[:3, 3].copy())
        self._last_stamp = frame.stamp_ns
        if index % self.every == 0:
            points, pixels = backproject(frame.depth_m, frame.K, stride=_POINT_STRIDE)
            colours = frame.rgb[pixels[:, 1], pixels[:, 0]]
            rec.log(POINTS_ENTITY, rr.Points3D(transform_points(T, points), colors=colours))
            self._log_trajectory()

    def _log_trajectory(self) -> None:
        if len(self._positions) >= 2:
            self.rec.log(TRAJECTORY_ENTITY, rr.LineStrips3D([np.asarray(self._positions)]))

    def close(self) -> None:
        """Log the whole trajectory at the last stamp and flush the file."""
        if self._positions:
            set_stamp(self.rec, self._last_stamp)
            self._log_trajectory()
        self.rec.flush()
        self.rec.disconnect()

    def keep(self) -> Path:
        """Move the finished file to its final path (after :meth:`close`)."""
        self.tmp.replace(self.path)
        return self.path

    def discard(self) -> None:
        """Remove the unfinished file of a failed run (after :meth:`close`)."""
        self.tmp.unlink(missing_ok=True)
