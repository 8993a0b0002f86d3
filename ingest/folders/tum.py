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
  (``freiburg1``, ``freiburg2``, ``freiburg3``), lens distortion included (removed at ingest
  from colour and depth alike, so their pixels stay paired); a folder whose name gives none
  takes the ROS default the benchmark's own conversion code uses for every sequence
  (fx = fy = 525, cx = 319.5, cy = 239.5). ``intrinsics.json`` overrides both.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from care.errors import IngestError
from care.frames import Frame
from ingest.folders.base import DatasetLayout, FolderLayout, FolderView
from ingest.folders.files import (
    PRIMESENSE,
    Intrinsics,
    numbers,
    pose_from_tum,
    read_colour_kept,
    read_depth,
    stamp_ns,
    table,
)
from ingest.folders.generic import INTRINSICS_FILE, TUM_POSE_COLUMNS, read_intrinsics_json
from ingest.undistort import NO_DISTORTION, Distortion, undistort

__all__ = ["CALIBRATIONS", "DEPTH_SCALE", "ROS_DEFAULT", "TumLayout", "associate"]

DEPTH_SCALE = 5000.0
"""Depth value of one metre in TUM's depth PNGs."""
ROS_DEFAULT = Intrinsics(**PRIMESENSE, source="TUM/ROS default")
"""The intrinsics TUM's conversion code applies to every sequence."""
CALIBRATIONS: dict[str, tuple[Intrinsics, Distortion]] = {
    "freiburg1": (
        Intrinsics(517.3, 516.5, 318.6, 255.3, width=640, height=480, source="TUM freiburg1"),
        Distortion("plumb_bob", (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    ),
    "freiburg2": (
        Intrinsics(520.9, 521.0, 325.1, 249.7, width=640, height=480, source="TUM freiburg2"),
        Distortion("plumb_bob", (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    ),
    "freiburg3": (
        Intrinsics(535.4, 539.2, 320.1, 247.6, width=640, height=480, source="TUM freiburg3"),
        NO_DISTORTION,
    ),
}
"""The benchmark's calibrated colour cameras by sensor (its intrinsic calibration page; D is
OpenCV's k1 k2 p1 p2 k3). freiburg3's images were rectified before release."""
_LISTS = {"rgb": "rgb.txt", "depth": "depth.txt"}
GROUNDTRUTH_FILE = "groundtruth.txt"


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
    """A TUM RGB-D sequence folder (see the module)."""

    kind: ClassVar[DatasetLayout] = DatasetLayout.TUM
    world_frame: ClassVar[str] = "tum_world"

    @classmethod
    def detect(cls, path: Path) -> bool:
        return all((Path(path) / name).is_file() for name in _LISTS.values())

    def __init__(self, path: Path, *, max_dt: float) -> None:
        super().__init__(path, max_dt=max_dt)
        self._camera: tuple[Intrinsics, Distortion, float] | None = None

    def _calibration(self) -> tuple[Intrinsics, Distortion, float]:
        if self._camera is None:
            override = self.path / INTRINSICS_FILE
            name = self.path.resolve().name.lower()
            sensor = next((s for s in CALIBRATIONS if s in name), None)
            if override.is_file():
                camera, scale = read_intrinsics_json(override, default_scale=DEPTH_SCALE)
                self._camera = (camera, NO_DISTORTION, scale)
            elif sensor is not None:
                self._camera = (*CALIBRATIONS[sensor], DEPTH_SCALE)
            else:
                self._camera = (ROS_DEFAULT, NO_DISTORTION, DEPTH_SCALE)
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

    def _groundtruth(self) -> tuple[np.ndarray, np.ndarray]:
        """Stamps (N,) and poses (N, 4, 4) of the ground truth, sorted, non-finite rows out."""
        path = self.path / GROUNDTRUTH_FILE
        rows = table(path, TUM_POSE_COLUMNS, "timestamp tx ty tz qx qy qz qw")
        stamps, poses = [], []
        for line, fields in rows:
            pose = pose_from_tum(numbers(fields[1:], path, line), path, line)
            if np.isfinite(pose).all():
                stamps.append(stamp_ns(fields[0], path, line))
                poses.append(pose)
        if not stamps:
            msg = f"{path}: no finite pose; the sequence has no usable ground truth."
            raise IngestError(msg)
        order = np.argsort(stamps, kind="stable")
        stamps_sorted = np.asarray(stamps, np.int64)[order]
        if (np.diff(stamps_sorted) == 0).any():
            msg = f"{path}: two poses at one stamp; fix or re-copy the file."
            raise IngestError(msg)
        return stamps_sorted, np.asarray(poses)[order]

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
        rotations = Rotation.from_matrix(poses[:, :3, :3])
        if len(stamps) > 1:
            out[:, :3, :3] = Slerp(base, rotations)(t).as_matrix()
        else:
            out[:, :3, :3] = rotations.as_matrix()[0]
        return out, valid

    def views(self) -> list[FolderView]:
        self._calibration()
        colour_stamps, colour = self._list("rgb")
        depth_stamps, depth = self._list("depth")
        pairs = associate(colour_stamps, depth_stamps, round(self.max_dt * 1e9))
        times = np.array([colour_stamps[i] for i, _ in pairs], np.int64)
        poses, valid = self._poses_at(times) if len(times) else (np.zeros((0, 4, 4)), [])
        lost = {"no_depth": len(colour) - len(pairs), "no_pose": len(pairs) - int(np.sum(valid))}
        self.dropped.update({reason: n for reason, n in lost.items() if n})
        views = [
            FolderView(int(colour_stamps[i]), colour[i], depth[j], poses[k])
            for k, (i, j) in enumerate(pairs)
            if valid[k]
        ]
        return sorted(views, key=lambda v: v.stamp_ns)

    def load(self, view: FolderView) -> Frame:
        camera, lens, scale = self._calibration()
        decoded, jpeg = read_colour_kept(view.colour)
        rgb = decoded
        fix = f"give the camera in {self.path / INTRINSICS_FILE} (docs/inputs.md)"
        camera.check_size(rgb.shape[1], rgb.shape[0], view.colour, fix)
        depth = read_depth(view.depth, scale)
        if depth.shape == rgb.shape[:2]:
            rgb = undistort(rgb, camera.K, lens, blend=True)
            depth = undistort(depth, camera.K, lens, blend=False)
        kept = jpeg if rgb is decoded else None  # undistorted: other pixels than the file's
        return Frame(view.stamp_ns, rgb, depth, camera.K.copy(), view.cam_to_world, rgb_jpeg=kept)

    def describe(self) -> dict[str, Any]:
        camera, lens, scale = self._calibration()
        return {
            "colour": _LISTS["rgb"], "depth": _LISTS["depth"], "poses": GROUNDTRUTH_FILE,
            "intrinsics": camera.as_json(), "distortion": lens.as_json(), "depth_scale": scale,
        }  # fmt: skip

    def distortions(self) -> list[Distortion]:
        lens = self._calibration()[1]
        return [] if lens.is_zero else [lens]
