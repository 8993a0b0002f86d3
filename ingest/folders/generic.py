"""Our documented folder layout, for frames from anywhere else (docs/inputs.md):

```
FOLDER/
  rgb/NAME.png|jpg      colour images; their names sort in time order
  depth/NAME.png        16-bit depth registered to the colour image, same NAME
  poses.txt             one line per colour image, in name order:
                        stamp tx ty tz qx qy qz qw (TUM trajectory format: seconds, metres,
                        camera-to-world of the optical frame x right, y down, z forward)
  intrinsics.json       {"fx", "fy", "cx", "cy"[, "width", "height"][, "depth_scale"]}
```

``depth_scale`` is the depth value of one metre (default 1000: millimetres). The TUM
trajectory format is the one SLAM systems and ``evo`` write, so a trajectory estimated
elsewhere drops in as it is.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

from care.errors import IngestError
from care.frames import Frame
from ingest.folders.base import DatasetLayout, FolderLayout, FolderView
from ingest.folders.files import (
    DEPTH_MILLIMETRES,
    PINHOLE_KEYS,
    Intrinsics,
    image_files,
    json_file,
    numbers,
    pose_from_tum,
    read_colour_kept,
    read_depth,
    stamp_ns,
    table,
)

__all__ = ["GenericLayout", "read_intrinsics_json"]

INTRINSICS_FILE = "intrinsics.json"
POSES_FILE = "poses.txt"
TUM_POSE_COLUMNS = 8
"""``stamp tx ty tz qx qy qz qw``."""


def read_intrinsics_json(
    path: Path, *, default_scale: float = DEPTH_MILLIMETRES
) -> tuple[Intrinsics, float]:
    """The intrinsics and depth scale of an ``intrinsics.json`` (this layout's, also accepted
    beside a TUM sequence to override its published calibration, where a missing
    ``depth_scale`` is TUM's, ``default_scale``)."""
    what = 'the camera as {"fx", "fy", "cx", "cy"} and optionally "width", "height", "depth_scale"'
    data = json_file(path, what)
    try:
        values = {k: float(data[k]) for k in PINHOLE_KEYS}
        size = {k: int(data.get(k, 0)) for k in ("width", "height")}
        scale = float(data.get("depth_scale", default_scale))
    except (KeyError, TypeError, ValueError) as err:
        msg = f"{path}: {err!r} missing or not a number; it should hold {what}."
        raise IngestError(msg) from err
    if not scale > 0:
        msg = f"{path}: depth_scale {scale} must be positive (the depth value of one metre)."
        raise IngestError(msg)
    return Intrinsics(**values, **size, source=path.name), scale


class GenericLayout(FolderLayout):
    """``rgb/``, ``depth/``, ``poses.txt`` and ``intrinsics.json`` (see the module)."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.GENERIC
    world_frame: ClassVar[str] = "world"

    @classmethod
    def detect(cls, path: Path) -> bool:
        path = Path(path)
        # poses.txt is what no other layout holds (a TUM sequence has rgb/ and depth/ too, and
        # may hold an intrinsics.json)
        has_images = (path / "rgb").is_dir() and (path / "depth").is_dir()
        return has_images and (path / POSES_FILE).is_file()

    def __init__(self, path: Path, *, max_dt: float) -> None:
        super().__init__(path, max_dt=max_dt)
        self._camera: tuple[Intrinsics, float] | None = None

    def _intrinsics(self) -> tuple[Intrinsics, float]:
        if self._camera is None:
            path = self.path / INTRINSICS_FILE
            if not path.is_file():
                msg = f"{path}: missing; a generic dataset folder needs its camera there (docs/inputs.md)."
                raise IngestError(msg)
            self._camera = read_intrinsics_json(path)
        return self._camera

    def views(self) -> list[FolderView]:
        self._intrinsics()
        colour = image_files(self.path / "rgb")
        poses_path = self.path / POSES_FILE
        rows = table(poses_path, TUM_POSE_COLUMNS, "stamp tx ty tz qx qy qz qw per colour image")
        if len(rows) != len(colour):
            msg = f"{poses_path}: {len(rows)} poses for {len(colour)} colour images in rgb/; give one pose per image, in the images' name order."
            raise IngestError(msg)
        views = []
        for image, (line, fields) in zip(colour, rows, strict=True):
            values = numbers(fields, poses_path, line)
            depth = self.path / "depth" / f"{image.stem}.png"
            if not depth.is_file():
                msg = f"{depth}: missing; every colour image rgb/{image.name} needs its depth image depth/{image.stem}.png."
                raise IngestError(msg)
            pose = pose_from_tum(values[1:], poses_path, line)
            views.append(FolderView(stamp_ns(fields[0], poses_path, line), image, depth, pose))
        return views

    def load(self, view: FolderView) -> Frame:
        camera, scale = self._intrinsics()
        rgb, jpeg = read_colour_kept(view.colour)
        camera.check_size(rgb.shape[1], rgb.shape[0], view.colour, f"fix {INTRINSICS_FILE}")
        depth = read_depth(view.depth, scale)
        return Frame(view.stamp_ns, rgb, depth, camera.K.copy(), view.cam_to_world, rgb_jpeg=jpeg)

    def describe(self) -> dict[str, Any]:
        camera, scale = self._intrinsics()
        return {
            "colour": "rgb/", "depth": "depth/", "poses": POSES_FILE,
            "intrinsics": camera.as_json(), "depth_scale": scale,
        }  # fmt: skip
