"""Matterport3D's undistorted frames of one house (scan), as the dataset's download script
fetches them and ``unzip`` unpacks them (github.com/niessner/Matterport,
``data_organization.md``).

```
<house>/undistorted_camera_parameters/<house>.conf   cameras and poses of every image
<house>/undistorted_color_images/<uuid>_i<camera>_<yaw>.jpg   colour, 1280x1024
<house>/undistorted_depth_images/<uuid>_d<camera>_<yaw>.png   16-bit depth, 0.25 mm a unit
<house>/region_segmentations/, house_segmentations/  ground truth (:mod:`care_maps.truth.formats.matterport`)
```

Each type is one zip (``v1/scans/<house>/<type>.zip``) holding ``<house>/<type>/...``, so the
three places an unzip leaves a type are all read: ``<house>/<type>/`` (the layout above),
``<house>/<house>/<type>/`` (unzipped where the download put it) and
``<house>/<type>/<house>/<type>/`` (each zip unzipped into a folder named after it).

The ``.conf`` file (``data_organization.md``, "undistorted_camera_parameters"; read as
Matterport's own ``RGBDConfiguration::ReadFile`` does) is a list of commands:
``intrinsics_matrix fx 0 cx 0 fy cy 0 0 1`` sets the camera of the ``scan`` lines after it,
``scan <depth image> <colour image> <16 numbers>`` is one view; ``n_images`` counts them.

- Poses: the 16 numbers are a row-major camera-to-world matrix of a camera that looks along
  -z with y up (OpenGL's convention), in metres, in the house's frame (z up, the frame of
  the region meshes). Ours is that matrix times ``diag(1, -1, -1, 1)``: x right, y down,
  z forward.
- Intrinsics: the conf's image coordinates start at the *bottom*-left corner with pixel
  centres at ``i + 0.5`` (``data_organization.md``: "all images have their origins in the
  bottom-left"; Matterport's GAPS code reads images bottom row first and casts the ray of
  pixel (ix, iy) through (ix + 0.5, iy + 0.5)). On the image as stored (top row first,
  centres at integers) the principal point is ``(cx - 0.5, height - 0.5 - cy)``, a few pixels
  from the conf's own ``cy`` (509.2 becomes 514.3 at 1024 rows).
- Depth: z distance in units of 0.25 mm (a value of 4000 is one metre), 0 = no reading,
  pixel-aligned with the undistorted colour image of the same camera and yaw (same size,
  same intrinsics).
- Timing: a tripod scanner keeps no times and its views come in panoramas, metres apart.
  Views are stamped one second apart in the conf's order, so the speed bound
  (``--max-speed``, 50 m/s by default) passes panoramas up to 50 m apart.
- Labels: none per image; ground truth is the house's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame
from care_maps.ingest.folders.base import DatasetLayout, FolderLayout, FolderOptions, FolderView
from care_maps.ingest.folders.files import Intrinsics, numbers, read_colour_kept, read_depth, table

__all__ = ["OPENGL_TO_OPTICAL", "MatterportLayout"]

COLOUR_FOLDER = "undistorted_color_images"
DEPTH_FOLDER = "undistorted_depth_images"
CAMERA_FOLDER = "undistorted_camera_parameters"
CONF_SUFFIX = ".conf"
DEPTH_QUARTER_MILLIMETRES = 4000.0
"""Depth value of one metre in Matterport's depth PNGs (0.25 mm a unit)."""
VIEW_PERIOD_NS = 1_000_000_000
"""Stamp step between consecutive views (the dataset has no times; see the module)."""
OPENGL_TO_OPTICAL = np.diag([1.0, -1.0, -1.0, 1.0])
"""Right factor taking a camera-to-world pose of an OpenGL camera (y up, looking along -z)
to the same camera's optical frame (y down, z forward)."""
_HOMOGENEOUS_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_INTRINSICS = "intrinsics_matrix"
_SCAN = "scan"
_N_IMAGES = "n_images"
_DOWNLOAD_HINT = "download it with Matterport's download_mp.py (--type undistorted_camera_parameters undistorted_color_images undistorted_depth_images) and unzip each zip"


def type_folder(house: Path, name: str) -> Path | None:
    """Where one download type of ``house`` was unzipped (the three places of the module),
    or None."""
    house = Path(house)
    nested = sorted(p for p in (house / name).glob(f"*/{name}") if p.is_dir())
    for candidate in (*nested[:1], house / house.name / name, house / name):
        if candidate.is_dir():
            return candidate
    return None


@dataclass(frozen=True)
class _Camera:
    """One ``intrinsics_matrix`` line, in the conf's bottom-left image coordinates."""

    fx: float
    fy: float
    cx: float
    cy: float
    line: int

    def on_image(self, height: int, source: str) -> Intrinsics:
        """The camera on an image of ``height`` rows as stored (top row first, pixel centres
        at integers)."""
        return Intrinsics(self.fx, self.fy, self.cx - 0.5, height - 0.5 - self.cy, source=source)


class MatterportLayout(FolderLayout):
    """A Matterport3D house's undistorted frames (see the module)."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.MATTERPORT
    world_frame: ClassVar[str] = "matterport_world"
    own_camera_axes: ClassVar[str] = "an OpenGL camera (y up, looking along -z)"

    @classmethod
    def detect(cls, path: Path) -> bool:
        cameras = type_folder(path, CAMERA_FOLDER)
        has_conf = cameras is not None and next(cameras.glob(f"*{CONF_SUFFIX}"), None) is not None
        return has_conf and type_folder(path, COLOUR_FOLDER) is not None

    def __init__(self, path: Path, *, max_dt: float, options: FolderOptions | None = None) -> None:
        super().__init__(path, max_dt=max_dt, options=options)
        self._camera_of: dict[Path, _Camera] = {}
        self._conf_path: Path | None = None

    def _folder(self, name: str) -> Path:
        found = type_folder(self.path, name)
        if found is None:
            msg = f"{self.path / name}: missing, and not in {self.path.name}/{name}/ nor {name}/<house>/{name}/ either; {_DOWNLOAD_HINT}."
            raise IngestError(msg)
        return found

    def _conf(self) -> Path:
        if self._conf_path is None:
            self._conf_path = self._find_conf()
        return self._conf_path

    def _find_conf(self) -> Path:
        folder = self._folder(CAMERA_FOLDER)
        confs = sorted(folder.glob(f"*{CONF_SUFFIX}"))
        named = [p for p in confs if p.stem in (self.path.name, folder.parent.name)]
        if len(confs) == 1 or named:
            return (named or confs)[0]
        names = ", ".join(p.name for p in confs) or "none"
        msg = f"{folder}: {names}: expected one <house>{CONF_SUFFIX}; {_DOWNLOAD_HINT}."
        raise IngestError(msg)

    def _scans(self) -> list[tuple[int, _Camera, str, str, np.ndarray]]:
        """``(line, camera, depth name, colour name, pose)`` of every ``scan`` line, the pose
        still in the conf's convention."""
        path = self._conf()
        scans, camera, declared = [], None, None
        for line, fields in table(path, tuple(range(1, 20)), "Matterport camera commands"):
            command = fields[0]
            if command == _INTRINSICS:
                values = numbers(fields[1:], path, line)
                if len(values) != 9:
                    msg = f"{path}: line {line}: {_INTRINSICS} has {len(values)} numbers, expected 9 (fx 0 cx 0 fy cy 0 0 1); re-copy the file."
                    raise IngestError(msg)
                camera = _Camera(values[0], values[4], values[2], values[5], line)
            elif command == _SCAN:
                if len(fields) != 19:
                    msg = f"{path}: line {line}: a scan line has {len(fields)} fields, expected 19 (scan, depth image, colour image, 16 numbers); re-copy the file."
                    raise IngestError(msg)
                if camera is None:
                    msg = f"{path}: line {line}: a scan before any {_INTRINSICS} line, so its camera is unknown; re-copy the file."
                    raise IngestError(msg)
                pose = numbers(fields[3:], path, line).reshape(4, 4)
                scans.append((line, camera, fields[1], fields[2], pose))
            elif command == _N_IMAGES:
                declared = (line, fields[1] if len(fields) > 1 else "")
        if declared is not None and declared[1] != str(len(scans)):
            msg = f"{path}: line {declared[0]} declares {declared[1]} images but the file has {len(scans)} scan lines; the file is truncated, re-copy it."
            raise IngestError(msg)
        return scans

    def views(self) -> list[FolderView]:
        self.dropped.clear()
        self._camera_of.clear()
        path = self._conf()
        colour_folder, depth_folder = self._folder(COLOUR_FOLDER), self._folder(DEPTH_FOLDER)
        views = []
        for index, (line, camera, depth_name, colour_name, pose) in enumerate(self._scans()):
            colour, depth = colour_folder / colour_name, depth_folder / depth_name
            if not colour.is_file():
                msg = f"{colour}: missing, but {path.name} line {line} lists it; {_DOWNLOAD_HINT}."
                raise IngestError(msg)
            if not np.isfinite(pose).all():
                self.dropped["no_pose"] += 1
                continue
            if not np.allclose(pose[3], _HOMOGENEOUS_ROW):
                msg = f"{path}: line {line}: last row {pose[3].tolist()} is not 0 0 0 1, so the matrix is not a pose; re-copy the file."
                raise IngestError(msg)
            if not depth.is_file():
                self.dropped["no_depth"] += 1
                continue
            self._camera_of[colour] = camera
            stamp = index * VIEW_PERIOD_NS
            optical = self.file_pose(pose) @ OPENGL_TO_OPTICAL
            views.append(FolderView(stamp, colour, depth, optical))
        if not views:
            msg = f"{path}: no scan line has a finite pose and both images; {_DOWNLOAD_HINT}."
            raise IngestError(msg)
        return views

    def load(self, view: FolderView) -> Frame:
        if view.colour not in self._camera_of:
            self.views()  # a layout that has not listed its views yet
        camera = self._camera_of.get(view.colour)
        if camera is None:
            msg = f"{view.colour}: no scan line of {self._conf()} lists this image."
            raise IngestError(msg)
        rgb, jpeg = read_colour_kept(view.colour)
        depth = read_depth(view.depth, self.scale(DEPTH_QUARTER_MILLIMETRES))
        if depth.shape != rgb.shape[:2]:
            msg = f"{view.depth}: {depth.shape[1]}x{depth.shape[0]} depth for a {rgb.shape[1]}x{rgb.shape[0]} colour image {view.colour.name}; undistorted depth and colour share one size, re-copy the house."
            raise IngestError(msg)
        source = f"{self._conf().name} line {camera.line}"
        K = self.camera(camera.on_image(rgb.shape[0], source))[0].K
        return Frame(view.stamp_ns, rgb, depth, K, view.cam_to_world, rgb_jpeg=jpeg)

    def describe(self) -> dict[str, Any]:
        def relative(folder: Path) -> str:
            return folder.relative_to(self.path).as_posix()

        return {
            "colour": relative(self._folder(COLOUR_FOLDER)),
            "depth": relative(self._folder(DEPTH_FOLDER)),
            "poses": relative(self._conf()),
            "depth_scale": self.scale(DEPTH_QUARTER_MILLIMETRES),
            "pose": "conf matrix @ diag(1, -1, -1, 1)",
            **({"intrinsics": self.camera()[0].as_json()} if self.options.intrinsics is not None
               else {"principal_point": "(cx - 0.5, height - 0.5 - cy)"}),
        }  # fmt: skip
