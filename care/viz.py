"""Rerun helpers shared by every stage: opening a recording and reading one back.

Each stage keeps its own logging module with its entity paths; this module only holds what
they all need. Timelines: ``stamp`` (recording time, ns) for sensor data, ``query`` (a
sequence) for query and replan decisions, ``k`` for evaluation scalars.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import rerun as rr

__all__ = ["STAMP_TIMELINE", "log_camera", "open_recording", "rrd_entity_counts", "set_stamp"]

STAMP_TIMELINE = "stamp"


def open_recording(app_id: str, rrd_path: Path) -> rr.RecordingStream:
    """A recording stream that streams to ``rrd_path`` (opened with ``rerun rrd_path``)."""
    rrd_path = Path(rrd_path)
    rrd_path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(app_id)
    rec.save(rrd_path)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return rec


def set_stamp(rec: rr.RecordingStream, stamp_ns: int) -> None:
    """Put subsequent logs at recording time ``stamp_ns`` on the ``stamp`` timeline."""
    rec.set_time(STAMP_TIMELINE, timestamp=np.datetime64(int(stamp_ns), "ns"))


def log_camera(
    rec: rr.RecordingStream,
    entity: str,
    cam_to_world: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
) -> None:
    """Log an optical-frame camera (pose plus pinhole) at ``entity``, a child of ``world``."""
    rec.log(
        entity,
        rr.Transform3D(translation=cam_to_world[:3, 3], mat3x3=cam_to_world[:3, :3]),
        rr.Pinhole(
            image_from_camera=K,
            width=width,
            height=height,
            camera_xyz=rr.ViewCoordinates.RDF,
            image_plane_distance=0.3,
        ),
    )


def rrd_entity_counts(rrd_path: Path) -> Counter[tuple[str, str]]:
    """Rows per (entity path, component column) in an ``.rrd`` file, read with ``RrdReader``.

    Tests and users use it to check what a run logged without opening the viewer.
    """
    from rerun.chunk import RrdReader

    counts: Counter[tuple[str, str]] = Counter()
    for chunk in RrdReader(Path(rrd_path)).stream():
        names = chunk.to_record_batch().schema.names
        for name in names:
            if ":" in name:
                counts[(str(chunk.entity_path), name)] += chunk.num_rows
    return counts
