"""ETH3D SLAM benchmark datasets, RGB-D download (``eth3d.net/slam_documentation``), as
unpacked: TUM RGB-D's lists with the camera in a file of its own.

```
FOLDER/
  rgb.txt, depth.txt   "timestamp filename" per image, as TUM's (rgb/*.png, depth/*.png)
  associated.txt       "rgb_stamp rgb_file depth_stamp depth_file": the colour-depth pairs
  groundtruth.txt      "timestamp tx ty tz qx qy qz qw" (training datasets only)
  calibration.txt      one line "fx fy cx cy" of the pinhole camera of both images
```

Read as ETH3D's own reader does (BAD SLAM, ``libvis/rgbd_video_io_tum_dataset.h``,
``ReadTUMRGBDDatasetAssociatedAndCalibrated``), and as NeRF-VO's ``eth3d_dataset.py`` reads
it:

- Camera: ``calibration.txt``, the first line, four numbers; colour and depth share it (the
  depth is estimated in the infrared pair and re-projected into the colour camera's
  viewpoint by the benchmark). Its principal point counts pixel centres at integers, ours
  (BAD SLAM adds 0.5 for its own corner-based convention). The images are undistorted
  already. ``--intrinsics`` overrides it.
- Depth: 16-bit PNG, 5000 per metre (NeRF-VO's ``depth_scale`` for ETH3D; TUM's scale).
- Pairs: ``associated.txt`` when present (what BAD SLAM reads; the rig's cameras are
  synchronised, so the two stamps of a pair agree), else ``rgb.txt`` and ``depth.txt``
  associated as TUM's (:func:`care_maps.ingest.folders.tum.associate`, within ``--max-dt``).
- Poses: ``groundtruth.txt`` in TUM's format, camera-to-world of the colour camera's optical
  frame, interpolated at the colour stamp as for TUM (BAD SLAM interpolates the same way).
  Test datasets ship no ground truth and cannot be read.
- Detection: TUM's lists and ``calibration.txt``; a TUM folder has no ``calibration.txt``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

from care_maps.core.errors import IngestError
from care_maps.ingest.folders.base import DatasetLayout
from care_maps.ingest.folders.files import PINHOLE_KEYS, Intrinsics, numbers, stamp_ns, table
from care_maps.ingest.folders.tum import DEPTH_SCALE, TumLayout
from care_maps.ingest.undistort import NO_DISTORTION, Distortion

__all__ = ["CALIBRATION_FILE", "Eth3dLayout"]

CALIBRATION_FILE = "calibration.txt"
ASSOCIATED_FILE = "associated.txt"
_ASSOCIATED_COLUMNS = 4
"""``rgb_stamp rgb_file depth_stamp depth_file``."""


class Eth3dLayout(TumLayout):
    """An ETH3D SLAM RGB-D dataset folder (see the module)."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.ETH3D
    world_frame: ClassVar[str] = "eth3d_world"

    @classmethod
    def marks(cls, path: Path) -> bool:
        return (Path(path) / CALIBRATION_FILE).is_file()

    def own_camera(self) -> tuple[Intrinsics, Distortion, float]:
        path = self.path / CALIBRATION_FILE
        rows = table(path, len(PINHOLE_KEYS), "one line: fx fy cx cy")
        if len(rows) != 1:
            msg = f"{path}: {len(rows)} lines, expected one line fx fy cx cy; re-copy the dataset."
            raise IngestError(msg)
        line, fields = rows[0]
        fx, fy, cx, cy = numbers(fields, path, line)
        return Intrinsics(fx, fy, cx, cy, source=CALIBRATION_FILE), NO_DISTORTION, DEPTH_SCALE

    def own_depth_scale(self) -> float:
        return DEPTH_SCALE

    def camera_fix(self) -> str:
        return f"give the camera with --intrinsics, or fix {self.path / CALIBRATION_FILE}"

    def pairs(self) -> tuple[list[tuple[int, Path, Path]], int]:
        path = self.path / ASSOCIATED_FILE
        if not path.is_file():
            return super().pairs()
        _, colour = self._list("rgb")
        rows = table(path, _ASSOCIATED_COLUMNS, "rgb_stamp rgb_file depth_stamp depth_file")
        pairs = []
        for line, (stamp, colour_name, _, depth_name) in rows:
            images = (self.path / colour_name, self.path / depth_name)
            for image in images:
                if not image.is_file():
                    msg = (
                        f"{path}: line {line} lists {image}, which is missing; re-copy the dataset."
                    )
                    raise IngestError(msg)
            pairs.append((stamp_ns(stamp, path, line), *images))
        return pairs, len(colour)

    def describe(self) -> dict[str, Any]:
        described = super().describe()
        if (self.path / ASSOCIATED_FILE).is_file():
            described["pairs"] = ASSOCIATED_FILE
        return described
