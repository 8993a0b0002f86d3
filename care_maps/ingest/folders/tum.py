"""TUM RGB-D sequences as downloaded (``rgbd_dataset_freiburg1_desk/``).

```
FOLDER/
  rgb.txt           "timestamp filename" per colour image (rgb/*.png, 640x480 8-bit RGB)
  depth.txt         "timestamp filename" per depth image (depth/*.png, 16-bit, 5000 = 1 m)
  groundtruth.txt   "timestamp tx ty tz qx qy qz qw": the colour camera's optical centre and
                    orientation in the motion-capture world, about 100 Hz
  intrinsics.json   optional: our generic layout's camera file, overrides the calibration
```

From the benchmark's own pages (cvg.cit.tum.de/data/datasets/rgbd-dataset: file formats,
intrinsic calibration) and its ``associate.py``:

- Timing: stamps are seconds since the epoch, read exactly to nanoseconds. Colour and depth
  are associated as ``associate.py`` does: the pairs closer than ``--max-dt`` (its default
  0.02 s too), closest first, each image used once. A colour image without depth is dropped
  (``no_depth``).
- Poses: camera-to-world of the colour camera's optical frame (the benchmark's tools
  back-project with x right, y down, z forward), interpolated at the colour stamp (linear
  translation, slerp), as TF would between samples. A colour image whose nearest ground-truth
  sample is farther than ``--max-dt`` (the motion capture lost the camera) is dropped
  (``no_pose``), as are stamps that fall on a non-finite sample.
- Depth: registered to colour by the OpenNI driver, 1:1 pixels; 5000 per metre.
- Intrinsics: the benchmark's calibrated colour camera of the sensor the folder's name gives
  (``freiburg1``, ``freiburg2``, ``freiburg3``, or their short forms ``fr1``..``fr3`` as in
  ``fr3_livingroom``), lens distortion included (removed at ingest from colour and depth
  alike, so their pixels stay paired). ``intrinsics.json`` overrides it, ``--intrinsics``
  overrides both (``--intrinsics primesense``: the ROS default, fx = fy = 525, cx = 319.5,
  cy = 239.5, that the benchmark's own conversion code applies to every sequence). A folder
  whose name gives no sensor and that has neither is refused: its camera is unknown, and a
  default camera that is wrong by 2% in focal length bends every wall of the map without a
  word.

ETH3D SLAM and Bonn RGB-D Dynamic ship the same lists (:mod:`care_maps.ingest.folders.eth3d`,
:mod:`care_maps.ingest.folders.bonn`); this layout leaves their folders to them.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame
from care_maps.ingest.folders.base import DatasetLayout, FolderLayout, FolderOptions, FolderView
from care_maps.ingest.folders.files import (
    Intrinsics,
    numbers,
    pose_from_tum,
    read_colour_kept,
    read_depth,
    stamp_ns,
    table,
)
from care_maps.ingest.folders.generic import INTRINSICS_FILE, TUM_POSE_COLUMNS, read_intrinsics_json
from care_maps.ingest.intrinsics import NAMED_CAMERAS, NamedCamera
from care_maps.ingest.undistort import NO_DISTORTION, Distortion, parse_distortion

__all__ = ["CALIBRATIONS", "DEPTH_SCALE", "TumLayout", "associate", "sensor_in_name"]

DEPTH_SCALE = 5000.0
"""Depth value of one metre in TUM's depth PNGs."""
_SENSORS = (NamedCamera.FREIBURG1, NamedCamera.FREIBURG2, NamedCamera.FREIBURG3)
CALIBRATIONS: dict[NamedCamera, tuple[Intrinsics, Distortion]] = {
    sensor: (
        Intrinsics.of(NAMED_CAMERAS[sensor], f"TUM {sensor}"),
        parse_distortion(
            NAMED_CAMERAS[sensor].distortion_model, NAMED_CAMERAS[sensor].distortion, sensor
        ),
    )
    for sensor in _SENSORS
}
"""The benchmark's calibrated colour cameras by sensor (:data:`care_maps.ingest.intrinsics.NAMED_CAMERAS`,
from its intrinsic calibration page). freiburg3's images were rectified before release."""
_SENSOR_NAME = re.compile(r"(?<![a-z0-9])(?:freiburg|fr)([1-3])(?![0-9])")
"""A sensor in a folder's name: ``freiburg1`` (the benchmark's names) or ``fr1`` (the short
form papers and SLAM configs use, ``fr3_livingroom``), not inside a longer word or number."""
_LISTS = {"rgb": "rgb.txt", "depth": "depth.txt"}
GROUNDTRUTH_FILE = "groundtruth.txt"


def sensor_in_name(name: str) -> NamedCamera | None:
    """The TUM sensor a folder's name gives, if any."""
    found = _SENSOR_NAME.search(name.lower())
    return _SENSORS[int(found.group(1)) - 1] if found else None


def has_tum_lists(path: Path) -> bool:
    """Whether ``path`` holds TUM's image lists (as TUM, ETH3D and Bonn folders do)."""
    return all((Path(path) / name).is_file() for name in _LISTS.values())


def associate(first: np.ndarray, second: np.ndarray, max_dt_ns: int) -> list[tuple[int, int]]:
    """Index pairs ``(i, j)`` of stamps no more than ``max_dt_ns`` apart, the closest pairs
    first and each stamp used once (``associate.py``'s rule), in ``first``'s order."""
    order = np.argsort(second, kind="stable")
    sorted_second = second[order]
    candidates = []
    for i, t in enumerate(first):
        lo = np.searchsorted(sorted_second, t - max_dt_ns, side="left")
        hi = np.searchsorted(sorted_second, t + max_dt_ns, side="right")
        candidates += [
            (abs(int(sorted_second[k]) - int(t)), i, int(order[k])) for k in range(lo, hi)
        ]
    used_first: set[int] = set()
    used_second: set[int] = set()
    pairs = []
    for _, i, j in sorted(candidates):
        if i not in used_first and j not in used_second:
            used_first.add(i)
            used_second.add(j)
            pairs.append((i, j))
    return sorted(pairs)


class TumLayout(FolderLayout):
    """A TUM RGB-D sequence folder (see the module). Layouts of datasets that ship TUM's
    lists subclass it and say, by :meth:`marks`, which folders are theirs."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.TUM
    world_frame: ClassVar[str] = "tum_world"
    pose_lines: ClassVar[bool] = True

    @classmethod
    def marks(cls, path: Path) -> bool:
        """What tells this dataset's folders from the others with TUM's lists (TUM: any)."""
        return True

    @classmethod
    def detect(cls, path: Path) -> bool:
        # one layout per folder: TUM's own leaves to its variants the folders they mark
        variants = (sub for sub in cls.__subclasses__() if sub.marks(Path(path)))
        return has_tum_lists(path) and cls.marks(Path(path)) and next(variants, None) is None

    def __init__(self, path: Path, *, max_dt: float, options: FolderOptions | None = None) -> None:
        super().__init__(path, max_dt=max_dt, options=options)
        self._camera: tuple[Intrinsics, Distortion, float] | None = None

    def own_camera(self) -> tuple[Intrinsics, Distortion, float]:
        """The folder's camera and depth scale without ``--intrinsics``: ``intrinsics.json``,
        else the sensor the folder's name gives, else refused (see the module)."""
        override = self.path / INTRINSICS_FILE
        if override.is_file():
            camera, scale = read_intrinsics_json(override, default_scale=DEPTH_SCALE)
            return camera, NO_DISTORTION, scale
        sensor = sensor_in_name(self.path.resolve().name)
        if sensor is None:
            msg = f"{self.path}: the folder's name names no TUM sensor (freiburg1, freiburg2, freiburg3, or fr1..fr3), so its camera is unknown; give it with --intrinsics (fx,fy,cx,cy, or primesense for the ROS default TUM's tools use, or freiburg1..3), or write it into {override.name} (docs/inputs.md)."
            raise IngestError(msg)
        return (*CALIBRATIONS[sensor], DEPTH_SCALE)

    def own_depth_scale(self) -> float:
        """The depth scale when ``--intrinsics`` replaces the camera: ``intrinsics.json``'s,
        else the dataset's."""
        override = self.path / INTRINSICS_FILE
        if override.is_file():
            return read_intrinsics_json(override, default_scale=DEPTH_SCALE)[1]
        return DEPTH_SCALE

    def _calibration(self) -> tuple[Intrinsics, Distortion, float]:
        if self._camera is None:
            if self.options.intrinsics is not None:
                camera, lens = self.camera()
                scale = self.own_depth_scale()
            else:
                own, own_lens, scale = self.own_camera()
                camera, lens = self.camera(own, own_lens)
            self._camera = (camera, lens, self.scale(scale))
        return self._camera

    def _list(self, key: str) -> tuple[np.ndarray, list[Path]]:
        path = self.path / _LISTS[key]
        rows = table(path, 2, "timestamp filename per image")
        stamps = np.array([stamp_ns(f[0], path, line) for line, f in rows], np.int64)
        files = [self.path / f[1] for _, f in rows]
        for (line, _), file in zip(rows, files, strict=True):
            if not file.is_file():
                msg = f"{path}: line {line} lists {file}, which is missing; re-copy the sequence."
                raise IngestError(msg)
        if len(np.unique(stamps)) != len(stamps):
            msg = f"{path}: two images at one stamp; fix or re-copy the file."
            raise IngestError(msg)
        return stamps, files

    def gt_pose(self, pose: np.ndarray) -> np.ndarray:
        """A ground-truth sample as the camera's optical pose (the file's conventions,
        :meth:`FolderLayout.file_pose`); a variant whose ground truth is of another body
        converts it here."""
        return self.file_pose(pose)

    def _groundtruth(self) -> tuple[np.ndarray, np.ndarray]:
        """Stamps (N,) and poses (N, 4, 4) of the ground truth, sorted, non-finite rows out."""
        path = self.path / GROUNDTRUTH_FILE
        rows = table(path, TUM_POSE_COLUMNS, "timestamp tx ty tz qx qy qz qw")
        order = self.quaternion_order()
        stamps, poses = [], []
        for line, fields in rows:
            pose = pose_from_tum(numbers(fields[1:], path, line), path, line, order)
            if np.isfinite(pose).all():
                stamps.append(stamp_ns(fields[0], path, line))
                poses.append(self.gt_pose(pose))
        if not stamps:
            msg = f"{path}: no finite pose; the sequence has no usable ground truth."
            raise IngestError(msg)
        order_ = np.argsort(stamps, kind="stable")
        stamps_sorted = np.asarray(stamps, np.int64)[order_]
        if (np.diff(stamps_sorted) == 0).any():
            msg = f"{path}: two poses at one stamp; fix or re-copy the file."
            raise IngestError(msg)
        return stamps_sorted, np.asarray(poses)[order_]

    def _poses_at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 4, 4) ground-truth poses at ``times`` and an (N,) mask of those with a sample
        within ``max_dt`` (interpolated between the samples around each time)."""
        stamps, poses = self._groundtruth()
        last = len(stamps) - 1
        after = np.clip(np.searchsorted(stamps, times), 0, last)
        before = np.clip(after - 1, 0, last)
        gap = np.minimum(np.abs(times - stamps[before]), np.abs(times - stamps[after]))
        valid = gap <= round(self.max_dt * 1e9)
        # times from the first sample, in integers first: epoch nanoseconds as float64 keep
        # only a quarter of a microsecond
        t = (np.clip(times, stamps[0], stamps[-1]) - stamps[0]).astype(np.float64)
        base = (stamps - stamps[0]).astype(np.float64)
        out = np.repeat(np.eye(4)[None], len(times), axis=0)
        for axis in range(3):
            out[:, axis, 3] = np.interp(t, base, poses[:, axis, 3])
        from scipy.spatial.transform import Rotation, Slerp  # here: not at the CLI's start-up

        rotations = Rotation.from_matrix(poses[:, :3, :3])
        if len(stamps) > 1:
            out[:, :3, :3] = Slerp(base, rotations)(t).as_matrix()
        else:
            out[:, :3, :3] = rotations.as_matrix()[0]
        return out, valid

    def pairs(self) -> tuple[list[tuple[int, Path, Path]], int]:
        """``(colour stamp, colour image, depth image)`` of each colour image with its
        depth, and how many colour images the lists hold: associated as ``associate.py``
        does (a variant that ships its associations reads them instead)."""
        colour_stamps, colour = self._list("rgb")
        depth_stamps, depth = self._list("depth")
        pairs = associate(colour_stamps, depth_stamps, round(self.max_dt * 1e9))
        return [(int(colour_stamps[i]), colour[i], depth[j]) for i, j in pairs], len(colour)

    def views(self) -> list[FolderView]:
        self._calibration()
        pairs, n_colour = self.pairs()
        times = np.array([stamp for stamp, _, _ in pairs], np.int64)
        poses, valid = (
            self._poses_at(times) if len(times) else (np.zeros((0, 4, 4)), np.zeros(0, bool))
        )
        lost = {"no_depth": n_colour - len(pairs), "no_pose": len(pairs) - int(np.sum(valid))}
        self.dropped.update({reason: n for reason, n in lost.items() if n})
        views = [
            FolderView(stamp, colour, depth, poses[k])
            for k, (stamp, colour, depth) in enumerate(pairs)
            if valid[k]
        ]
        return sorted(views, key=lambda v: v.stamp_ns)

    def camera_fix(self) -> str:
        """What to do when the images are not the camera's size."""
        return f"give the camera with --intrinsics or in {self.path / INTRINSICS_FILE} (docs/inputs.md)"

    def load(self, view: FolderView) -> Frame:
        camera, _, scale = self._calibration()
        rgb, jpeg = read_colour_kept(view.colour)
        camera.check_size(rgb.shape[1], rgb.shape[0], view.colour, self.camera_fix())
        depth = read_depth(view.depth, scale)
        return Frame(view.stamp_ns, rgb, depth, camera.K.copy(), view.cam_to_world, rgb_jpeg=jpeg)

    def describe(self) -> dict[str, Any]:
        camera, lens, scale = self._calibration()
        return {
            "colour": _LISTS["rgb"], "depth": _LISTS["depth"], "poses": GROUNDTRUTH_FILE,
            "intrinsics": camera.as_json(), "distortion": lens.as_json(), "depth_scale": scale,
        }  # fmt: skip

    def lens(self) -> Distortion:
        return self._calibration()[1]
