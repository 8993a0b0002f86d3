"""Rerun logging of an ingest run (``care ingest ... --rrd PATH``) and its blueprint.

Everything lies on the ``stamp`` timeline and uses Rerun's entity-path transforms: the camera
entity carries the optical-frame pose (a ``Transform3D`` relative to ``world``, z up) and the
``Pinhole`` (RDF optical axes), and its children ``rgb`` (JPEG) and ``depth`` (16-bit PNG,
millimetres) are images in that pinhole's image plane. A 2D view whose origin is the camera
entity therefore has the pinhole as its root, which is what the viewer needs to draw camera
images without an error. The recording's TF names (world and optical frame) are drawn as a
small graph, since the entity paths are the viewer's frames, not TF's.

The back-projected points of every Nth frame go to their own entity per frame
(``world/map/<n>``) so the 3D view builds the map up as time advances instead of replacing it;
the trajectory is logged as the path so far at every frame.

A store of several exploration runs (``care ingest --append``) is logged run by run: each run
on a timeline of its own (``run 1``, ``run 2``, ...: runs days apart would leave one
timeline empty between them), its trajectory its own entity (``world/trajectory/run_<k>``)
in a colour of its own (:data:`RUN_COLOURS`), its clouds tinted towards it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from care_maps.core.frames import DEFAULT_CAMERA_FRAME, DEFAULT_WORLD_FRAME, Frame
from care_maps.core.outputs import temporary
from care_maps.core.viz import (
    depth_png,
    jpeg,
    open_scene_recording,
    panels,
    send_blueprint,
    set_stamp,
)
from care_maps.geometry.transforms import backproject, transform_points
from care_maps.ingest.write import CAMERA_FRAME, WORLD_FRAME

__all__ = [
    "CAMERA_ENTITY",
    "DEPTH_ENTITY",
    "DEPTH_SCALE_ENTITY",
    "MAP_ENTITY",
    "RGB_ENTITY",
    "RUN_COLOURS",
    "TF_ENTITY",
    "TRAJECTORY_ENTITY",
    "IngestLogger",
    "cloud_every",
    "ingest_blueprint",
]

CAMERA_ENTITY = "world/camera"
"""Camera pose (Transform3D) and intrinsics (Pinhole): the root of the 2D camera views."""
RGB_ENTITY = "world/camera/rgb"
DEPTH_ENTITY = "world/camera/depth"
MAP_ENTITY = "world/map"
"""Parent of ``world/map/<frame index>``: the back-projected points of every Nth frame."""
TRAJECTORY_ENTITY = "world/trajectory"
TF_ENTITY = "tf"
"""The recording's TF frames as a graph (world frame -> optical frame -> image)."""
DEPTH_SCALE_ENTITY = "legend/depth"
"""A strip of depths from the near to the far end of the depth view's colour range, drawn
with the same colour map: the depth view's scale."""

SHORT_RECORDING = 40
"""Views up to which every view's points are logged: a short recording is looked at view by
view, and its clouds are few."""
CLOUD_EVERY = 10
"""Views between logged clouds of a longer recording (the map still builds up, the file
stays small)."""
_POINT_STRIDE = 4
"""Pixels between back-projected points (16x fewer points than pixels)."""
RUN_COLOURS = ((255, 170, 0), (0, 170, 255), (230, 60, 160), (90, 200, 80), (150, 110, 255))
"""Trajectory colour of each run of a store of several (cycled); the first is the one run's."""
RUN_TINT = 0.35
"""Share of a run's colour mixed into its clouds' pixel colours (several runs only)."""
_DEPTH_RANGE_M = (0.0, 6.0)
"""Colour range of the depth view; indoor RGB-D cameras see a few metres."""
_DEPTH_COLORMAP: rr.components.ColormapLike = "turbo"
_SCALE_SIZE = (16, 240)
"""Rows and columns of the depth scale strip (metres grow to the right)."""
_DEPTH_SCALE_NAME = (
    f"depth scale: {_DEPTH_RANGE_M[0]:g} m (left) to {_DEPTH_RANGE_M[1]:g} m (right)"
)


def ingest_blueprint(world_frame: str = WORLD_FRAME, camera_frame: str = CAMERA_FRAME):
    """Layout of an ingest recording: camera image and depth side by side on top, the 3D map
    building up beside the TF tree below; the time panel open to scrub through the frames."""
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(
                rrb.Spatial2DView(origin=CAMERA_ENTITY, contents=RGB_ENTITY, name="camera rgb"),
                rrb.Vertical(
                    rrb.Spatial2DView(
                        origin=CAMERA_ENTITY, contents=DEPTH_ENTITY, name="camera depth (m)"
                    ),
                    rrb.Spatial2DView(origin=DEPTH_SCALE_ENTITY, name=_DEPTH_SCALE_NAME),
                    row_shares=[8, 1],
                ),
            ),
            rrb.Horizontal(
                rrb.Spatial3DView(
                    origin="world",
                    contents=["+ world/**", f"- {RGB_ENTITY}", f"- {DEPTH_ENTITY}"],
                    name="3D: map so far, trajectory, camera",
                ),
                rrb.GraphView(origin=TF_ENTITY, name=f"TF: {world_frame} -> {camera_frame}"),
                column_shares=[3, 1],
            ),
            row_shares=[1, 1],
        ),
        *panels(time=True),
    )


def cloud_every(every: int | None, views: int | None) -> int:
    """Views between back-projected clouds: ``every`` when given, else every view of a
    recording of at most :data:`SHORT_RECORDING` views (``views``: their number, or an
    estimate; None: unknown), else :data:`CLOUD_EVERY`."""
    if every is not None:
        return every
    return 1 if views is not None and views <= SHORT_RECORDING else CLOUD_EVERY


class IngestLogger:
    """Logs frames as they are ingested into a temporary file.

    :meth:`close` flushes; then :meth:`keep` renames the file into place (or :meth:`discard`
    removes it after a failed run). ``scene`` names the recording (default: the file's name
    up to its first dot), so the scene's other files merge with it in the viewer.
    """

    def __init__(
        self,
        rrd_path: Path,
        *,
        every: int = CLOUD_EVERY,
        world_frame: str = WORLD_FRAME,
        camera_frame: str = CAMERA_FRAME,
        scene: str | None = None,
        runs: int = 1,
    ) -> None:
        self.path = Path(rrd_path)
        self.runs = max(1, int(runs))
        """Runs the recording will hold: several are logged run by run (module docstring)."""
        self.run = 0
        """The run being logged (0-based; :meth:`start_run`)."""
        self.tmp = temporary(self.path)  # within the name limit however long the name
        self.scene = scene or self.path.name.split(".")[0]
        self.rec = open_scene_recording(self.tmp, self.scene)
        self.every = max(1, int(every))
        self.world_frame = world_frame or DEFAULT_WORLD_FRAME
        self.camera_frame = camera_frame or DEFAULT_CAMERA_FRAME
        self._positions: list[np.ndarray] = []
        self._static_done = False

    def _log_static(self, frame: Frame) -> None:
        rec = self.rec
        send_blueprint(rec, ingest_blueprint(self.world_frame, self.camera_frame))
        names = [self.world_frame, self.camera_frame, f"{self.camera_frame} image"]
        rec.log(
            TF_ENTITY,
            rr.GraphNodes(
                node_ids=names, labels=names, positions=[(0.0, -80.0 * i) for i in range(3)]
            ),
            rr.GraphEdges(
                edges=[(names[0], names[1]), (names[1], names[2])], graph_type="directed"
            ),
            static=True,
        )
        rec.log(
            CAMERA_ENTITY,
            rr.Pinhole(
                image_from_camera=frame.K,
                width=frame.width,
                height=frame.height,
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=0.3,
            ),
            static=True,
        )
        rec.log(DEPTH_SCALE_ENTITY, _depth_scale(), static=True)
        self._static_done = True

    def start_run(self, run: int) -> None:
        """The frames logged next are run ``run``'s (0-based): its timeline, its trajectory."""
        self.run = int(run)
        self._positions = []

    def log(self, index: int, frame: Frame) -> None:
        """Log frame number ``index`` (0-based) of the run."""
        if not self._static_done:
            self._log_static(frame)
        rec = self.rec
        if self.runs > 1:
            rec.reset_time()
            rec.set_time(f"run {self.run + 1}", timestamp=np.datetime64(frame.stamp_ns, "ns"))
        else:
            set_stamp(rec, frame.stamp_ns)
        T = np.asarray(frame.cam_to_world, np.float64)
        rec.log(CAMERA_ENTITY, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
        rec.log(RGB_ENTITY, rr.EncodedImage(contents=jpeg(frame.rgb), media_type="image/jpeg"))
        rec.log(
            DEPTH_ENTITY,
            rr.EncodedDepthImage(
                depth_png(frame.depth_m),
                media_type="image/png",
                meter=1000.0,
                colormap=_DEPTH_COLORMAP,
                depth_range=[r * 1000.0 for r in _DEPTH_RANGE_M],
            ),
        )
        self._positions.append(T[:3, 3].copy())
        colour = RUN_COLOURS[self.run % len(RUN_COLOURS)]
        if len(self._positions) >= 2:  # the path so far, so any time shows where it has been
            rec.log(
                TRAJECTORY_ENTITY if self.runs == 1 else f"{TRAJECTORY_ENTITY}/run_{self.run + 1}",
                rr.LineStrips3D([np.asarray(self._positions)], colors=[colour]),
            )
        if index % self.every == 0:
            points, pixels = backproject(frame.depth_m, frame.K, stride=_POINT_STRIDE)
            colours = frame.rgb[pixels[:, 1], pixels[:, 0]]
            if self.runs > 1:
                tint = np.asarray(colour, np.float32)
                colours = ((1 - RUN_TINT) * colours + RUN_TINT * tint).astype(np.uint8)
            rec.log(
                f"{MAP_ENTITY}/{index}",
                rr.Points3D(transform_points(T, points), colors=colours, radii=0.015),
            )

    def close(self) -> None:
        """Flush the file."""
        self.rec.flush()
        self.rec.disconnect()

    def keep(self) -> Path:
        """Move the finished file to its final path (after :meth:`close`)."""
        self.tmp.replace(self.path)
        return self.path

    def discard(self) -> None:
        """Remove the unfinished file of a failed run (after :meth:`close`)."""
        self.tmp.unlink(missing_ok=True)


def _depth_scale() -> rr.DepthImage:
    """The depth view's legend: millimetres rising left to right over its colour range,
    coloured by the viewer exactly as the depth images are (same map, range and unit)."""
    near, far = (r * 1000.0 for r in _DEPTH_RANGE_M)
    rows, cols = _SCALE_SIZE
    ramp = np.linspace(near, far, cols).round().astype(np.uint16)
    return rr.DepthImage(
        np.broadcast_to(ramp, (rows, cols)).copy(),
        meter=1000.0,
        colormap=_DEPTH_COLORMAP,
        depth_range=[near, far],
    )
