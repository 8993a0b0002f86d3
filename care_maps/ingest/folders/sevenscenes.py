"""Microsoft RGB-D 7-Scenes, one sequence as unzipped (``chess/seq-01/``,
microsoft.com/en-us/research/project/rgb-d-dataset-7-scenes).

```
seq-01/
  frame-000000.color.png   colour, 640x480 8-bit RGB
  frame-000000.depth.png   16-bit depth in millimetres, 65535 where there is none
  frame-000000.pose.txt    camera-to-world 4x4, four rows of four numbers
```

A scene folder (``chess/``) holds its sequences (``seq-01`` ... ``seq-06``), each one
recording (``care run chess/`` maps each); all sequences of a scene share one world frame.

- Poses: camera-to-world (the dataset page: "camera-to-world, 4x4 matrix in homogeneous
  coordinates"), from KinectFusion tracking, in metres; the camera x right, y down,
  z forward, as KinectFusion's: our optical frame, as it is. A non-finite pose (the
  tracker's ``inf``/``nan``), or a missing pose or depth file, drops the view (``no_pose``,
  ``no_depth``).
- Depth: millimetres; 65535 marks no reading and reads as 0.
- Camera and registration: the page gives one camera, principal point (320, 240) and focal
  length 585: the depth sensor's. The raw release does not register depth to colour (the
  Kinect's colour camera, about 525 px, sits 2.5 cm beside the depth camera). The common
  RGB-D readers pair the two images pixel for pixel with that one camera (NeRF-VO's
  ``7_scenes.json``: fx = fy = 585, cx 320, cy 240, depth scale 1000; its loader maps 65535
  to 0), and so does this layout: depth is exact in the 585 camera, colour lands a few
  pixels off at depth edges. Relocalisation work that needs colour-exact depth registers it
  first (DSAC*'s ``setup_7scenes.py``, with the calibration of
  projet.liris.cnrs.fr/voir/activities-dataset/kinect-calibration.html) and gives the colour
  camera with ``--intrinsics 525,525,320,240``.
- Timing: none; 30 Hz by frame number.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

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
    DEPTH_MILLIMETRES,
    Intrinsics,
    numbers,
    read_colour_kept,
    read_depth,
    table,
)

__all__ = ["NO_DEPTH", "SEVEN_SCENES_CAMERA", "SevenScenesLayout"]

SEVEN_SCENES_CAMERA = Intrinsics(585.0, 585.0, 320.0, 240.0, width=640, height=480,
                                 source="7-Scenes depth camera")  # fmt: skip
"""The one camera the dataset page states (the depth sensor's)."""
NO_DEPTH = 65535
"""The depth value 7-Scenes writes where the sensor has no reading."""
_FRAME = re.compile(r"^frame-(\d+)\.(color\.png|depth\.png|pose\.txt)$")
_COLOUR, _DEPTH, _POSE = "color.png", "depth.png", "pose.txt"
_HOMOGENEOUS_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def _frames(folder: Path) -> dict[str, dict[int, Path]]:
    """The sequence's files by kind (colour, depth, pose) and frame number."""
    found: dict[str, dict[int, Path]] = {_COLOUR: {}, _DEPTH: {}, _POSE: {}}
    if folder.is_dir():
        for path in folder.iterdir():
            match = _FRAME.match(path.name)
            if match:
                found[match.group(2)][int(match.group(1))] = path
    return found


class SevenScenesLayout(FolderLayout):
    """One 7-Scenes sequence folder (see the module)."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.SEVEN_SCENES
    world_frame: ClassVar[str] = "7scenes_world"

    @classmethod
    def detect(cls, path: Path) -> bool:
        path = Path(path)
        return (
            next(path.glob(f"frame-*.{_COLOUR}"), None) is not None
            and next(path.glob(f"frame-*.{_POSE}"), None) is not None
        )

    def __init__(self, path: Path, *, max_dt: float, options: FolderOptions | None = None) -> None:
        super().__init__(path, max_dt=max_dt, options=options)
        self._camera: Intrinsics | None = None

    def _intrinsics(self) -> Intrinsics:
        if self._camera is None:
            self._camera = self.camera(SEVEN_SCENES_CAMERA)[0]
        return self._camera

    def _pose(self, path: Path) -> np.ndarray:
        rows = table(path, 4, "a camera-to-world 4x4, four rows of four numbers")
        if len(rows) != 4:
            msg = f"{path}: {len(rows)} rows, expected 4 rows of 4 numbers (a camera-to-world 4x4); re-copy the sequence."
            raise IngestError(msg)
        matrix = np.stack([numbers(fields, path, line) for line, fields in rows])
        if np.isfinite(matrix).all() and not np.allclose(matrix[3], _HOMOGENEOUS_ROW):
            msg = f"{path}: last row {matrix[3].tolist()} is not 0 0 0 1, so the matrix is not a pose; re-copy the sequence."
            raise IngestError(msg)
        return self.file_pose(matrix)

    def views(self) -> list[FolderView]:
        self._intrinsics()
        self.dropped.clear()
        files = _frames(self.path)
        views = []
        for number in sorted(files[_COLOUR]):
            pose = self._pose(files[_POSE][number]) if number in files[_POSE] else None
            if pose is None or not np.isfinite(pose).all():
                self.dropped["no_pose"] += 1
            elif number not in files[_DEPTH]:
                self.dropped["no_depth"] += 1
            else:
                colour, depth = files[_COLOUR][number], files[_DEPTH][number]
                views.append(FolderView(nominal_stamp_ns(number), colour, depth, pose))
        return views

    def load(self, view: FolderView) -> Frame:
        camera = self._intrinsics()
        rgb, jpeg = read_colour_kept(view.colour)
        fix = "give the camera of these images with --intrinsics"
        camera.check_size(rgb.shape[1], rgb.shape[0], view.colour, fix)
        depth = read_depth(view.depth, self.scale(DEPTH_MILLIMETRES), invalid=NO_DEPTH)
        return Frame(view.stamp_ns, rgb, depth, camera.K.copy(), view.cam_to_world, rgb_jpeg=jpeg)

    def describe(self) -> dict[str, Any]:
        return {
            "colour": f"frame-<i>.{_COLOUR}", "depth": f"frame-<i>.{_DEPTH}",
            "poses": f"frame-<i>.{_POSE}", "intrinsics": self._intrinsics().as_json(),
            "depth_scale": self.scale(DEPTH_MILLIMETRES), "no_depth_value": NO_DEPTH,
            "registration": "depth and colour paired pixel for pixel (the raw release's)",
        }  # fmt: skip
