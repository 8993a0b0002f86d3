"""Colour camera intrinsics given by hand, for recordings without a (right) camera info.

``--intrinsics`` takes four numbers, ``fx,fy,cx,cy`` (pixels, a pinhole camera with
rectified images), the name of a published camera (:data:`NAMED_CAMERAS`: ``primesense``,
``freiburg1``, ``freiburg2``, ``freiburg3``), or a calibration file:

- a ROS camera_info YAML as ``camera_calibration`` and ``camera_info_manager`` write it
  (``image_width``, ``image_height``, ``camera_matrix.data`` row-major,
  ``distortion_model``, ``distortion_coefficients.data``), or the same keys in JSON;
- Open3D's ``PinholeCameraIntrinsic`` JSON (``width``, ``height``, ``intrinsic_matrix``
  column-major), as Redwood and many RGB-D datasets ship it.

The file is read once, into a :class:`CameraIntrinsics` of numbers: the store records the
values it was built with, not a path, so editing the file makes the store stale.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.ingest.undistort import Distortion, parse_distortion

__all__ = ["NAMED_CAMERAS", "CameraIntrinsics", "NamedCamera"]

_JSON = ".json"
_YAML_SUFFIXES = (".yaml", ".yml")
_FLAG = "--intrinsics"
_FORMS = (
    "fx,fy,cx,cy in pixels, a camera's name (primesense, freiburg1, freiburg2, freiburg3), "
    "or a camera_info YAML/JSON file (image_width, image_height, camera_matrix, "
    "distortion_model, distortion_coefficients) or an Open3D intrinsics JSON"
)


class NamedCamera(StrEnum):
    """A published camera ``--intrinsics`` takes by name (:data:`NAMED_CAMERAS`)."""

    PRIMESENSE = "primesense"
    """The PrimeSense / Kinect default: Open3D's ``PrimeSenseDefault`` and the ROS default
    that TUM RGB-D's own conversion code applies to every sequence."""
    FREIBURG1 = "freiburg1"
    """TUM RGB-D's calibrated colour camera of the freiburg1 Kinect."""
    FREIBURG2 = "freiburg2"
    """TUM RGB-D's calibrated colour camera of the freiburg2 Kinect."""
    FREIBURG3 = "freiburg3"
    """TUM RGB-D's freiburg3 Asus Xtion (its images were rectified before release: no D)."""


@dataclass(frozen=True)
class CameraIntrinsics:
    """A pinhole colour camera: focal lengths and principal point in pixels, and the lens
    distortion its images still have."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int = 0
    """Image width the calibration is for (0: any, not checked against the images)."""
    height: int = 0
    """Image height the calibration is for (0: any)."""
    distortion_model: str = ""
    """ROS distortion model name (``plumb_bob``, ``equidistant``, ...); '' with no D."""
    distortion: tuple[float, ...] = ()
    """D of ``distortion_model``; empty or all zero for rectified images."""

    def __post_init__(self) -> None:
        numbers = {"fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy}
        bad = {k: v for k, v in numbers.items() if not math.isfinite(v)}
        if bad or self.fx <= 0 or self.fy <= 0:
            msg = f"{_FLAG}: fx, fy must be > 0 and cx, cy finite, got {numbers}."
            raise IngestError(msg)
        if self.width < 0 or self.height < 0:
            msg = f"{_FLAG}: image size {self.width}x{self.height} must not be negative."
            raise IngestError(msg)
        object.__setattr__(self, "distortion", tuple(float(v) for v in self.distortion))
        # a D that cannot be applied is refused here, not in the middle of an ingest
        parse_distortion(self.distortion_model, self.distortion, _FLAG)

    @property
    def K(self) -> np.ndarray:  # noqa: N802 -- the camera matrix's own name
        """(3, 3) camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def lens(self) -> Distortion:
        """The distortion removed from the images (:mod:`care_maps.ingest.undistort`)."""
        return parse_distortion(self.distortion_model, self.distortion, _FLAG)

    @classmethod
    def from_text(cls, text: str) -> CameraIntrinsics:
        """``fx,fy,cx,cy``, a camera's name or a calibration file's path (the forms in the
        module's doc)."""
        named = {str(name): camera for name, camera in NAMED_CAMERAS.items()}
        if text.strip().lower() in named:
            return named[text.strip().lower()]
        path = Path(text).expanduser()
        if path.suffix.lower() in (_JSON, *_YAML_SUFFIXES) or path.is_file():
            return cls.from_file(path)
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) != 4:
            msg = f"{_FLAG} {text!r}: expected {_FORMS}."
            raise IngestError(msg)
        fx, fy, cx, cy = values
        return cls(fx, fy, cx, cy)

    @classmethod
    def from_file(cls, path: Path) -> CameraIntrinsics:
        """A camera_info YAML/JSON or an Open3D intrinsics JSON."""
        import yaml

        path = Path(path)
        try:
            text = path.read_text()
            # JSON by its own parser: JSON with tabs (as Open3D writes it) is not YAML
            data = json.loads(text) if path.suffix.lower() == _JSON else yaml.safe_load(text)
        except (OSError, ValueError, yaml.YAMLError) as err:
            msg = f"{_FLAG} {path}: cannot read it ({err}); give {_FORMS}."
            raise IngestError(msg) from err
        try:
            return cls._from_mapping(data)
        except (KeyError, TypeError, ValueError) as err:
            msg = f"{_FLAG} {path}: not a calibration this reads ({type(err).__name__}: {err}); give {_FORMS}."
            raise IngestError(msg) from err
        except IngestError as err:
            msg = f"{_FLAG} {path}: {err}"
            raise IngestError(msg) from err

    @classmethod
    def _from_mapping(cls, data: Any) -> CameraIntrinsics:
        if not isinstance(data, dict):
            msg = "the file holds no mapping"
            raise TypeError(msg)
        d: tuple[float, ...]
        if "intrinsic_matrix" in data:  # Open3D: column-major
            K = np.asarray(data["intrinsic_matrix"], np.float64).reshape(3, 3).T
            size = (int(data.get("width", 0)), int(data.get("height", 0)))
            model, d = "", ()
        else:  # ROS camera_info
            K = np.asarray(_matrix_data(data["camera_matrix"]), np.float64).reshape(3, 3)
            size = (int(data.get("image_width", 0)), int(data.get("image_height", 0)))
            model = str(data.get("distortion_model") or "")
            d = tuple(_matrix_data(data.get("distortion_coefficients") or {"data": []}))
        if K[0, 1] != 0 or K[1, 0] != 0 or K[2].tolist() != [0.0, 0.0, 1.0]:
            msg = f"camera matrix {K.ravel().tolist()} is not [fx 0 cx; 0 fy cy; 0 0 1] (skew or a projective last row is not supported)"
            raise ValueError(msg)
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], *size, model, d)


def _matrix_data(entry: Any) -> list[float]:
    """The values of a camera_info YAML matrix (``{rows, cols, data}``) or a plain list."""
    values = entry["data"] if isinstance(entry, dict) else entry
    return [float(v) for v in values]


_TUM_SIZE = (640, 480)
NAMED_CAMERAS: dict[NamedCamera, CameraIntrinsics] = {
    NamedCamera.PRIMESENSE: CameraIntrinsics(525.0, 525.0, 319.5, 239.5, *_TUM_SIZE),
    NamedCamera.FREIBURG1: CameraIntrinsics(
        517.3, 516.5, 318.6, 255.3, *_TUM_SIZE,
        "plumb_bob", (0.2624, -0.9531, -0.0054, 0.0026, 1.1633),
    ),
    NamedCamera.FREIBURG2: CameraIntrinsics(
        520.9, 521.0, 325.1, 249.7, *_TUM_SIZE,
        "plumb_bob", (0.2312, -0.7849, -0.0033, -0.0001, 0.9172),
    ),
    NamedCamera.FREIBURG3: CameraIntrinsics(535.4, 539.2, 320.1, 247.6, *_TUM_SIZE),
}  # fmt: skip
"""The cameras ``--intrinsics`` takes by name, at 640x480: the PrimeSense default
(fx = fy = 525, cx = 319.5, cy = 239.5) and TUM RGB-D's calibrated colour cameras
(cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats, "Intrinsic Camera Calibration of
the Kinect"; D is OpenCV's k1 k2 p1 p2 k3). The one source of these numbers: the TUM and
Redwood layouts take theirs from here."""
