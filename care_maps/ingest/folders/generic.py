"""Our documented folder layout, for frames from anywhere else (docs/inputs.md):

```
FOLDER/
  rgb/NAME.png|jpg      colour images; their names sort in time order (8-bit RGB, or 16-bit
                        grey, scaled to 8 bit)
  depth/NAME.png        16-bit depth registered to the colour image, same NAME
  poses.txt             one line per colour image, in name order:
                        stamp tx ty tz qx qy qz qw (TUM trajectory format: seconds, metres,
                        camera-to-world of the optical frame x right, y down, z forward)
  intrinsics.json       {"fx", "fy", "cx", "cy"[, "width", "height"][, "depth_scale"]
                         [, "poses": "world-to-camera"][, "quaternion_order": "wxyz"]}
```

``depth_scale`` is the depth value of one metre (default 1000: millimetres). The TUM
trajectory format is the one SLAM systems and ``evo`` write, so a trajectory estimated
elsewhere drops in as it is. A trajectory in another convention says so in
``intrinsics.json``: ``"poses": "world-to-camera"`` (extrinsics, as COLMAP and many SfM
exports write them: every pose is inverted as read) and ``"quaternion_order": "wxyz"``
(``qw qx qy qz``, Eigen's and COLMAP's order); ``--pose-convention`` and
``--quaternion-order`` say the same and win over the file. ``--intrinsics`` replaces the
file's camera (the file may then be left out: depth in millimetres).

Without ``width`` and ``height`` every view must have the size of the first: one K is the
camera of one image size. Stamps are seconds; a stamp beyond 1e11 s is refused as written in
nanoseconds or microseconds.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, ClassVar

from care_maps.core.config import member
from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame
from care_maps.ingest.conventions import PoseConvention, QuaternionOrder
from care_maps.ingest.folders.base import DatasetLayout, FolderLayout, FolderOptions, FolderView
from care_maps.ingest.folders.files import (
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
POSES_FIELD = "poses"
"""The ``intrinsics.json`` field naming the poses' :class:`care_maps.ingest.conventions.PoseConvention`."""
QUATERNION_FIELD = "quaternion_order"
"""The ``intrinsics.json`` field naming the pose lines' :class:`care_maps.ingest.conventions.QuaternionOrder`."""
_WHAT = 'the camera as {"fx", "fy", "cx", "cy"} and optionally "width", "height", "depth_scale"'


def _camera_values(path: Path, data: dict[str, Any]) -> tuple[dict[str, float], dict[str, int]]:
    """The pinhole numbers and image size of an ``intrinsics.json``, refused in one line
    naming the file and the field when missing, not numbers, or not a camera."""
    try:
        values = {k: float(data[k]) for k in PINHOLE_KEYS}
        size = {k: int(data.get(k, 0)) for k in ("width", "height")}
    except (KeyError, TypeError, ValueError, OverflowError) as err:
        msg = f"{path}: {err!r} missing or not a number; it should hold {_WHAT}."
        raise IngestError(msg) from err
    bad = [k for k, v in values.items() if not math.isfinite(v)]
    bad += [k for k in ("fx", "fy") if k not in bad and values[k] <= 0]
    bad += [k for k, v in size.items() if v < 0]
    if bad:
        fields_ = ", ".join(f"{k} {data[k]!r}" for k in bad)
        msg = f"{path}: {fields_}: not a camera (fx and fy must be finite and positive, cx and cy finite, width and height not negative); fix those fields."
        raise IngestError(msg)
    return values, size


def _intrinsics(values: dict[str, float], size: dict[str, int], source: str) -> Intrinsics:
    """The camera of :func:`_camera_values`' numbers."""
    return Intrinsics(
        fx=values["fx"], fy=values["fy"], cx=values["cx"], cy=values["cy"],
        width=size["width"], height=size["height"], source=source,
    )  # fmt: skip


def read_intrinsics_json(
    path: Path, *, default_scale: float = DEPTH_MILLIMETRES
) -> tuple[Intrinsics, float]:
    """The intrinsics and depth scale of an ``intrinsics.json`` (this layout's, also accepted
    beside a TUM sequence to override its published calibration, where a missing
    ``depth_scale`` is TUM's, ``default_scale``)."""
    data = json_file(path, _WHAT)
    values, size = _camera_values(path, data)
    return _intrinsics(values, size, path.name), _depth_scale(path, data, default_scale)


def _depth_scale(path: Path, data: dict[str, Any], default: float) -> float:
    try:
        scale = float(data.get("depth_scale", default))
    except (TypeError, ValueError, OverflowError) as err:
        msg = f"{path}: depth_scale {data.get('depth_scale')!r} is not a number; give the depth value of one metre (1000: millimetres) in the depth_scale field."
        raise IngestError(msg) from err
    # json reads Infinity and NaN: neither is a depth scale
    if not (math.isfinite(scale) and scale > 0):
        msg = f"{path}: depth_scale {scale} must be a finite positive number (the depth value of one metre, 1000 for millimetres); fix the depth_scale field."
        raise IngestError(msg)
    return scale


class GenericLayout(FolderLayout):
    """``rgb/``, ``depth/``, ``poses.txt`` and ``intrinsics.json`` (see the module)."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.GENERIC
    world_frame: ClassVar[str] = "world"
    pose_lines: ClassVar[bool] = True

    @classmethod
    def detect(cls, path: Path) -> bool:
        path = Path(path)
        # poses.txt is what no other layout holds (a TUM sequence has rgb/ and depth/ too, and
        # may hold an intrinsics.json)
        has_images = (path / "rgb").is_dir() and (path / "depth").is_dir()
        return has_images and (path / POSES_FILE).is_file()

    def __init__(self, path: Path, *, max_dt: float, options: FolderOptions | None = None) -> None:
        super().__init__(path, max_dt=max_dt, options=options)
        self._camera: tuple[Intrinsics, float] | None = None
        self._file: dict[str, Any] | None = None

    def _json(self) -> dict[str, Any]:
        """``intrinsics.json``'s fields; {} when ``--intrinsics`` is given and it is absent."""
        if self._file is None:
            path = self.path / INTRINSICS_FILE
            if path.is_file():
                self._file = json_file(path, _WHAT)
            elif self.options.intrinsics is not None:
                self._file = {}
            else:
                msg = f"{path}: missing; a generic dataset folder needs its camera there, or given with --intrinsics (docs/inputs.md)."
                raise IngestError(msg)
        return self._file

    def _intrinsics(self) -> tuple[Intrinsics, float]:
        if self._camera is None:
            path, data = self.path / INTRINSICS_FILE, self._json()
            scale = _depth_scale(path, data, DEPTH_MILLIMETRES)
            if self.options.intrinsics is not None:
                camera = self.camera()[0]
            else:
                values, size = _camera_values(path, data)
                camera = _intrinsics(values, size, INTRINSICS_FILE)
            self._camera = (camera, self.scale(scale))
        return self._camera

    def _file_field(self, name: str, enum: type[Any], default: Any) -> Any:
        value = self._json().get(name)
        if value is None:
            return default
        what = f"{self.path / INTRINSICS_FILE}: {name}"
        return member(enum, value, IngestError, what)

    def own_pose_convention(self) -> PoseConvention:
        return self._file_field(POSES_FIELD, PoseConvention, PoseConvention.CAMERA_TO_WORLD)

    def own_quaternion_order(self) -> QuaternionOrder:
        return self._file_field(QUATERNION_FIELD, QuaternionOrder, QuaternionOrder.XYZW)

    def views(self) -> list[FolderView]:
        self._intrinsics()
        colour = image_files(self.path / "rgb")
        poses_path = self.path / POSES_FILE
        rows = table(poses_path, TUM_POSE_COLUMNS, "stamp tx ty tz qx qy qz qw per colour image")
        if len(rows) != len(colour):
            msg = f"{poses_path}: {len(rows)} poses for {len(colour)} colour images in rgb/; give one pose per image, in the images' name order."
            raise IngestError(msg)
        order = self.quaternion_order()
        views = []
        for image, (line, fields) in zip(colour, rows, strict=True):
            values = numbers(fields, poses_path, line)
            depth = self.path / "depth" / f"{image.stem}.png"
            if not depth.is_file():
                msg = f"{depth}: missing; every colour image rgb/{image.name} needs its depth image depth/{image.stem}.png."
                raise IngestError(msg)
            pose = self.file_pose(pose_from_tum(values[1:], poses_path, line, order))
            views.append(FolderView(stamp_ns(fields[0], poses_path, line), image, depth, pose))
        return views

    def load(self, view: FolderView) -> Frame:
        camera, scale = self._intrinsics()
        rgb, jpeg = read_colour_kept(view.colour)
        fix = f"fix {INTRINSICS_FILE}'s fx, fy, cx, cy and its width and height fields"
        camera.check_size(rgb.shape[1], rgb.shape[0], view.colour, fix)
        depth = read_depth(view.depth, scale)
        return Frame(view.stamp_ns, rgb, depth, camera.K.copy(), view.cam_to_world, rgb_jpeg=jpeg)

    def describe(self) -> dict[str, Any]:
        camera, scale = self._intrinsics()
        return {
            "colour": "rgb/", "depth": "depth/", "poses": POSES_FILE,
            "intrinsics": camera.as_json(), "depth_scale": scale,
        }  # fmt: skip
