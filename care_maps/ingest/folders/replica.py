"""Replica as NICE-SLAM and iMAP render it (``Replica/room0/``), the version RGB-D mapping
papers evaluate on.

```
Replica/
  cam_params.json             {"camera": {"w", "h", "fx", "fy", "cx", "cy", "scale"}}
  room0/
    results/frame000000.jpg   colour, 1200x680
    results/depth000000.png   16-bit depth, ``scale`` (6553.5) per metre
    traj.txt                  one camera-to-world 4x4 per line, 16 numbers, row-major
```

- Poses: camera-to-world in the optical convention (x right, y down, z forward); NICE-SLAM's
  loader flips the y and z columns to reach its own OpenGL-style camera, so the file itself
  is ours, as it is. One line per frame, in frame order.
- Intrinsics and depth scale (``--intrinsics`` and ``--depth-scale`` override them):
  ``cam_params.json`` of the scene folder or of the release
  folder above it (NICE-SLAM's download has one for all scenes), else the values of NICE-SLAM's
  ``configs/Replica/replica.yaml`` (1200x680, fx = fy = 600, cx = 599.5, cy = 339.5, depth
  scale 6553.5: 10 m is 65535).
- Timing: none; 30 Hz by frame index.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, ClassVar

from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame
from care_maps.ingest.folders.base import (
    DatasetLayout,
    FolderLayout,
    FolderOptions,
    FolderView,
    nominal_stamp_ns,
)
from care_maps.ingest.folders.files import (
    PINHOLE_KEYS,
    Intrinsics,
    image_files,
    json_file,
    numbers,
    read_colour_kept,
    read_depth,
    table,
)

__all__ = ["NICE_SLAM_CAMERA", "ReplicaLayout"]

NICE_SLAM_CAMERA = {"w": 1200, "h": 680, "fx": 600.0, "fy": 600.0, "cx": 599.5, "cy": 339.5,
                    "scale": 6553.5}  # fmt: skip
"""``cam`` of NICE-SLAM's ``configs/Replica/replica.yaml`` (``png_depth_scale`` as ``scale``),
in the keys of the release's ``cam_params.json``."""
CAM_PARAMS_FILE = "cam_params.json"
TRAJECTORY_FILE = "traj.txt"
_NUMBER = re.compile(r"(\d+)$")


class ReplicaLayout(FolderLayout):
    """A NICE-SLAM Replica scene folder (see the module)."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.REPLICA
    world_frame: ClassVar[str] = "replica_world"

    @classmethod
    def detect(cls, path: Path) -> bool:
        results = Path(path) / "results"
        return results.is_dir() and next(results.glob("frame*.jpg"), None) is not None

    def __init__(self, path: Path, *, max_dt: float, options: FolderOptions | None = None) -> None:
        super().__init__(path, max_dt=max_dt, options=options)
        self._camera: tuple[Intrinsics, float] | None = None

    def _params_file(self) -> Path | None:
        return next(
            (p for p in (self.path / CAM_PARAMS_FILE, self.path.parent / CAM_PARAMS_FILE)
             if p.is_file()),
            None,
        )  # fmt: skip

    def _intrinsics(self) -> tuple[Intrinsics, float]:
        if self._camera is not None:
            return self._camera
        path = self._params_file()
        source = "NICE-SLAM replica.yaml"
        params: dict[str, Any] = {"camera": NICE_SLAM_CAMERA}
        if path is not None:
            params = json_file(
                path, 'the camera as {"camera": {"w", "h", "fx", "fy", "cx", "cy", "scale"}}'
            )
            source = CAM_PARAMS_FILE if path.parent == self.path else f"../{CAM_PARAMS_FILE}"
        try:
            cam = params["camera"]
            values = {k: float(cam[k]) for k in PINHOLE_KEYS}
            width, height, scale = int(cam["w"]), int(cam["h"]), float(cam["scale"])
        except (KeyError, TypeError, ValueError) as err:
            msg = f"{path}: camera {err!r} missing or not a number; write it as NICE-SLAM's {CAM_PARAMS_FILE}."
            raise IngestError(msg) from err
        if not scale > 0:
            msg = f"{path}: depth scale {scale} must be positive (the depth value of one metre)."
            raise IngestError(msg)
        own = Intrinsics(**values, width=width, height=height, source=source)
        self._camera = (self.camera(own)[0], self.scale(scale))
        return self._camera

    def views(self) -> list[FolderView]:
        self._intrinsics()
        results = self.path / "results"
        colour = image_files(results, (".jpg",), "frame*")
        path = self.path / TRAJECTORY_FILE
        rows = table(path, 16, "one camera-to-world 4x4 per frame, 16 numbers row-major")
        if len(rows) != len(colour):
            msg = f"{path}: {len(rows)} poses for {len(colour)} colour images results/frame*.jpg; the scene needs one pose line per frame (re-copy it)."
            raise IngestError(msg)
        views = []
        for i, (image, (line, fields)) in enumerate(zip(colour, rows, strict=True)):
            number = _NUMBER.search(image.stem)
            depth = results / f"depth{number.group(1) if number else image.stem}.png"
            if not depth.is_file():
                msg = f"{depth}: missing; every colour image {image.name} needs its depth image (re-copy the scene)."
                raise IngestError(msg)
            pose = self.file_pose(numbers(fields, path, line).reshape(4, 4))
            views.append(FolderView(nominal_stamp_ns(i), image, depth, pose))
        return views

    def load(self, view: FolderView) -> Frame:
        camera, scale = self._intrinsics()
        rgb, jpeg = read_colour_kept(view.colour)
        fix = f"give the camera of these renders in {self.path / CAM_PARAMS_FILE}"
        camera.check_size(rgb.shape[1], rgb.shape[0], view.colour, fix)
        depth = read_depth(view.depth, scale)
        return Frame(view.stamp_ns, rgb, depth, camera.K.copy(), view.cam_to_world, rgb_jpeg=jpeg)

    def describe(self) -> dict[str, Any]:
        camera, scale = self._intrinsics()
        return {
            "colour": "results/frame*.jpg", "depth": "results/depth*.png",
            "poses": TRAJECTORY_FILE, "intrinsics": camera.as_json(), "depth_scale": scale,
        }  # fmt: skip
