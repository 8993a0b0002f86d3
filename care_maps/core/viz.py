"""Rerun helpers shared by every stage: opening a recording and reading one back.

Each stage keeps its own logging module with its entity paths; this module only holds what
they all need. Timelines: ``stamp`` (recording time, ns) for sensor data, ``query`` (a
sequence) for query and replan decisions, ``k`` for evaluation scalars.

Every stage's file of one scene shares :data:`APP_ID` and the scene's recording id (see
:func:`open_scene_recording`), so ``rerun a.rrd b.rrd ...`` opens them as one recording that
merges; each file also carries the blueprint of its stage (the last file opened shows its own).
Images are logged encoded (:func:`jpeg`, :func:`depth_png`): the viewer decodes them, and a
file weighs a fraction of the raw pixels.
"""

from __future__ import annotations

import io
import uuid
from collections import Counter
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

__all__ = [
    "APP_ID",
    "STAMP_TIMELINE",
    "depth_png",
    "jpeg",
    "log_camera",
    "open_recording",
    "open_scene_recording",
    "overview_eye",
    "panels",
    "rrd_entity_counts",
    "send_blueprint",
    "set_stamp",
]

STAMP_TIMELINE = "stamp"
APP_ID = "care_maps"
"""The one application id of every recording the pipeline writes."""
JPEG_QUALITY = 90
"""Quality of the JPEG colour images in recordings (visually lossless at 320x240)."""


def open_recording(
    app_id: str, rrd_path: Path, *, recording_id: str | None = None, name: str | None = None
) -> rr.RecordingStream:
    """A recording stream that streams to ``rrd_path`` (opened with ``rerun rrd_path``).

    Files with the same ``app_id`` and ``recording_id`` merge into one recording in the viewer.
    """
    rrd_path = Path(rrd_path)
    rrd_path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(app_id, recording_id=recording_id)
    # the SDK keeps a thread's times per recording id, and every stage's file of a scene
    # shares one: without this, a file opened after another in the same thread (a run that
    # fuses and evaluates in one process) would log on the last one's timelines
    rec.reset_time()
    rec.save(rrd_path)
    if name:
        rec.send_recording_name(name)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    return rec


_LAYOUT_IDS = uuid.UUID("6c1d2a8e-4b7f-5e0a-9c3d-2f8e1b7a4c60")
"""Namespace of the ids :func:`send_blueprint` gives a layout's views and containers."""


def send_blueprint(rec: rr.RecordingStream, blueprint: rrb.Blueprint) -> None:
    """Send ``blueprint`` with each view's and container's id derived from its place in the
    layout, not the SDK's random ``uuid4``: the same layout then writes the same blueprint,
    so a recording made twice holds the same rows (``tests/faults/test_same_bytes.py``)."""

    def place(part: object, where: str) -> None:
        part.id = uuid.uuid5(_LAYOUT_IDS, where)  # type: ignore[attr-defined]
        for i, child in enumerate(getattr(part, "contents", None) or ()):
            if hasattr(child, "blueprint_path"):  # a view or container, not an entity query
                place(child, f"{where}/{i}")

    root = getattr(blueprint, "root_container", None)
    if root is not None:
        place(root, "root")
    rec.send_blueprint(blueprint)


def open_scene_recording(rrd_path: Path, scene: str) -> rr.RecordingStream:
    """The recording of one stage of ``scene``: project app id, the scene as id and name."""
    return open_recording(APP_ID, rrd_path, recording_id=f"scene:{scene}", name=scene)


def panels(*, time: bool = False) -> list[rrb.BlueprintPart]:
    """Side panels of every blueprint: the views get the room; the time panel when it matters."""
    return [
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="expanded" if time else "collapsed"),
    ]


def overview_eye(points: np.ndarray) -> rrb.EyeControls3D:
    """A 3D view's starting eye: above and south of the ``(n, 3)`` points, looking at their
    middle from about 45 degrees, so a scene opens seen from outside and above its walls."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital)
    lo, hi = np.percentile(pts, [1, 99], axis=0)
    centre = (lo + hi) / 2
    reach = float(max(hi[0] - lo[0], hi[1] - lo[1], 1.0))
    return rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=centre + np.array([0.0, -0.75 * reach, 0.9 * reach]),
        look_target=centre,
        eye_up=(0.0, 0.0, 1.0),
    )


def jpeg(rgb: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    """JPEG bytes of an (H, W, 3) uint8 image, for ``rr.EncodedImage``."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8)).save(buf, "JPEG", quality=quality)
    return buf.getvalue()


def depth_png(depth_m: np.ndarray) -> bytes:
    """16-bit PNG bytes of a depth image in millimetres (lossless to 1 mm, 0 = invalid),
    for ``rr.EncodedDepthImage(..., meter=1000)``."""
    from PIL import Image

    mm = np.nan_to_num(np.asarray(depth_m, np.float64) * 1000.0, nan=0.0, posinf=0.0)
    mm = np.clip(np.rint(mm), 0, 65535).astype(np.uint16)
    buf = io.BytesIO()
    Image.fromarray(mm).save(buf, "PNG", optimize=False, compress_level=6)
    return buf.getvalue()


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
