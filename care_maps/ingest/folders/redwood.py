"""ICL-NUIM / Redwood as Open3D's reconstruction system reads them.

```
FOLDER/
  image/ (or rgb/, color/)  colour images (.jpg, .png), natural name order
  depth/                    16-bit PNG depth in millimetres, registered to colour, same order
  trajectory.log            one pose per colour image: a metadata line of three integers,
                            then a 4x4 camera-to-world matrix (rows)
  camera_intrinsic.json     optional: Open3D's PinholeCameraIntrinsic JSON
```

- Poses: the Redwood log format (redwood-data.org/indoor/fileformat.html): the matrix maps a
  point from the camera's coordinates to the world's, and the camera is Open3D's pinhole
  camera, x right, y down, z forward: our optical frame, as it is. The metadata's third
  number is the 1-based frame number; poses are taken in file order, one per image.
- Intrinsics: ``--intrinsics`` when given, else ``camera_intrinsic.json`` (``intrinsic_matrix``
  column-major, as Open3D writes it), else Open3D's PrimeSense default (fx = fy = 525,
  cx = 319.5, cy = 239.5 at 640x480): the camera the ICL-NUIM renders were made with and the
  one Open3D's reconstruction system reads Redwood's scans with when the folder names none,
  so for this dataset it is the published camera, not a guess.
- Depth: millimetres (Open3D's ``depth_scale`` 1000). Timing: none; 30 Hz by frame index.
"""

from __future__ import annotations

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
    PRIMESENSE,
    Intrinsics,
    image_files,
    json_file,
    numbers,
    read_colour_kept,
    read_depth,
    table,
)

__all__ = ["RedwoodLayout"]

COLOUR_FOLDERS = ("image", "rgb", "color")
"""Colour folder names, in the order Open3D's reconstruction system tries them."""
TRAJECTORY_FILE = "trajectory.log"
INTRINSIC_FILE = "camera_intrinsic.json"
_HOMOGENEOUS_ROW = np.array([0.0, 0.0, 0.0, 1.0])


class RedwoodLayout(FolderLayout):
    """Colour and depth folders with an Open3D / Redwood ``trajectory.log`` (see the module)."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.REDWOOD
    world_frame: ClassVar[str] = "redwood_world"

    @classmethod
    def detect(cls, path: Path) -> bool:
        path = Path(path)
        has_colour = any((path / name).is_dir() for name in COLOUR_FOLDERS)
        return has_colour and (path / "depth").is_dir() and (path / TRAJECTORY_FILE).is_file()

    def __init__(self, path: Path, *, max_dt: float, options: FolderOptions | None = None) -> None:
        super().__init__(path, max_dt=max_dt, options=options)
        self._camera: Intrinsics | None = None

    def _colour_folder(self) -> Path:
        for name in COLOUR_FOLDERS:
            if (self.path / name).is_dir():
                return self.path / name
        msg = f"{self.path}: no colour folder ({', '.join(n + '/' for n in COLOUR_FOLDERS)}); a Redwood folder holds its colour images in one."
        raise IngestError(msg)

    def _intrinsics(self) -> Intrinsics:
        if self._camera is None:
            given = self.options.intrinsics is not None
            self._camera = self.camera()[0] if given else self._own_intrinsics()
        return self._camera

    def _own_intrinsics(self) -> Intrinsics:
        path = self.path / INTRINSIC_FILE
        if not path.is_file():
            return Intrinsics.of(PRIMESENSE, "Open3D PrimeSense default")
        data = json_file(path, "Open3D's camera intrinsic: width, height, intrinsic_matrix")
        try:
            K = np.asarray(data["intrinsic_matrix"], np.float64).reshape(3, 3).T  # column-major
            width, height = int(data["width"]), int(data["height"])
        except (KeyError, TypeError, ValueError) as err:
            msg = f"{path}: no width, height and 9-number intrinsic_matrix ({err!r}); write it as Open3D's PinholeCameraIntrinsic JSON."
            raise IngestError(msg) from err
        return Intrinsics(K[0, 0], K[1, 1], K[0, 2], K[1, 2], width=width, height=height,
                          source=INTRINSIC_FILE)  # fmt: skip

    def _poses(self) -> list[np.ndarray]:
        path = self.path / TRAJECTORY_FILE
        rows = table(path, (3, 4), "a metadata line of 3 integers and 4 matrix rows per pose")
        poses = []
        for start in range(0, len(rows), 5):
            block = rows[start : start + 5]
            shape = [len(fields) for _, fields in block]
            if shape != [3, 4, 4, 4, 4]:
                msg = f"{path}: line {block[0][0]}: a pose is a metadata line of 3 numbers and 4 rows of 4, found rows of {shape}; fix or re-copy the file."
                raise IngestError(msg)
            matrix = np.stack([numbers(fields, path, line) for line, fields in block[1:]])
            if np.isfinite(matrix).all() and not np.allclose(matrix[3], _HOMOGENEOUS_ROW):
                msg = f"{path}: line {block[4][0]}: last row {matrix[3].tolist()} is not 0 0 0 1, so the matrix is not a pose; fix or re-copy the file."
                raise IngestError(msg)
            poses.append(self.file_pose(matrix))
        return poses

    def views(self) -> list[FolderView]:
        self._intrinsics()
        colour = image_files(self._colour_folder())
        depth = image_files(self.path / "depth", (".png",))
        poses = self._poses()
        counts = {"colour images": len(colour), "depth images": len(depth), "poses": len(poses)}
        if len(set(counts.values())) != 1:
            found = ", ".join(f"{n} {what}" for what, n in counts.items())
            msg = f"{self.path}: {found} in {self._colour_folder().name}/, depth/ and {TRAJECTORY_FILE}; a Redwood folder has one of each per frame (re-copy the dataset)."
            raise IngestError(msg)
        return [
            FolderView(nominal_stamp_ns(i), c, d, pose)
            for i, (c, d, pose) in enumerate(zip(colour, depth, poses, strict=True))
        ]

    def load(self, view: FolderView) -> Frame:
        camera = self._intrinsics()
        rgb, jpeg = read_colour_kept(view.colour)
        fix = f"give the camera in {self.path / INTRINSIC_FILE} (Open3D's PinholeCameraIntrinsic JSON)"
        camera.check_size(rgb.shape[1], rgb.shape[0], view.colour, fix)
        depth = read_depth(view.depth, self.scale(DEPTH_MILLIMETRES))
        return Frame(view.stamp_ns, rgb, depth, camera.K.copy(), view.cam_to_world, rgb_jpeg=jpeg)

    def describe(self) -> dict[str, Any]:
        return {
            "colour": f"{self._colour_folder().name}/", "depth": "depth/",
            "poses": TRAJECTORY_FILE, "intrinsics": self._intrinsics().as_json(),
            "depth_scale": self.scale(DEPTH_MILLIMETRES),
        }  # fmt: skip
