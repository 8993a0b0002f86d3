"""Lens distortion removed at ingest: images resampled onto the pinhole camera of K.

Every later stage (back-projection, fusion, a view's feature map laid on the world) assumes
the pinhole model of K, so a camera info's non-zero D is applied once, here, with OpenCV's own
models: ``plumb_bob`` and ``rational_polynomial`` (Brown-Conrady,
``cv2.initUndistortRectifyMap``), ``equidistant`` and ``fisheye`` (Kannala-Brandt,
``cv2.fisheye.initUndistortRectifyMap``). The new camera matrix is K itself, so the stored
intrinsics stay K. Colour is interpolated bilinearly; depth and labels take the nearest pixel
(a blend of two depths across an edge is a point in mid-air, a blend of two ids another id).
Pixels that see outside the recorded image become 0: black, invalid depth, no label.

All-zero D (any model, or none) means rectified images, as ROS's ``image_geometry`` reads
it: nothing changes, the images pass through as they are and OpenCV is not imported. The
remap tables are made once per (model, D, K, size).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, NamedTuple

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.runtime.threads import Work, thread_count

__all__ = [
    "FISHEYE_MODELS",
    "MODELS",
    "NO_DISTORTION",
    "PINHOLE_MODELS",
    "Distortion",
    "parse_distortion",
    "undistort",
]

PINHOLE_MODELS = ("plumb_bob", "rational_polynomial")
"""ROS names of the Brown-Conrady model: D = (k1, k2, p1, p2[, k3[, k4, k5, k6]])."""
FISHEYE_MODELS = ("equidistant", "fisheye")
"""ROS (and driver) names of the Kannala-Brandt model: D = (k1, k2, k3, k4)."""
MODELS = PINHOLE_MODELS + FISHEYE_MODELS

_MAX_COEFFICIENTS = {**dict.fromkeys(PINHOLE_MODELS, 14), **dict.fromkeys(FISHEYE_MODELS, 4)}
_OPENCV_LENGTHS = (4, 5, 8, 12, 14)
"""Lengths ``cv2.initUndistortRectifyMap`` accepts; D is zero-padded to the next one."""


class Distortion(NamedTuple):
    """A camera info's ``distortion_model`` and D, as recorded."""

    model: str
    coefficients: tuple[float, ...]

    @property
    def is_zero(self) -> bool:
        """True when D is empty or all zero: the images are already pinhole images."""
        return not any(self.coefficients)

    def as_json(self) -> dict[str, Any]:
        return {"model": self.model, "D": list(self.coefficients)}


NO_DISTORTION = Distortion("", ())


def parse_distortion(model: str, coefficients: Any, topic: str | None) -> Distortion:
    """The distortion of a camera info; one line naming ``topic`` when it cannot be applied
    (an unknown model with non-zero D, a non-finite or too long D)."""
    d = np.asarray([] if coefficients is None else coefficients, np.float64).ravel()
    lens = Distortion(str(model), tuple(float(v) for v in d))
    if not np.isfinite(d).all():
        msg = f"topic {topic}: camera_info D = {list(lens.coefficients)} has non-finite values; fix the calibration or record zero D for rectified images."
        raise IngestError(msg)
    if lens.is_zero:
        return lens
    if lens.model not in MODELS:
        msg = f"topic {topic}: camera_info distortion_model {lens.model!r} with non-zero D = {list(lens.coefficients)} is not supported (supported: {', '.join(MODELS)}); record rectified images with zero D (e.g. image_proc's image_rect) or a calibration in a supported model."
        raise IngestError(msg)
    used = int(np.flatnonzero(d)[-1]) + 1
    if used > _MAX_COEFFICIENTS[lens.model]:
        msg = f"topic {topic}: camera_info D = {list(lens.coefficients)} has {used} coefficients, {lens.model!r} takes at most {_MAX_COEFFICIENTS[lens.model]}; fix the calibration."
        raise IngestError(msg)
    return lens


def _opencv_coefficients(lens: Distortion) -> np.ndarray:
    """D zero-padded (or its trailing zeros cut) to a length OpenCV takes for the model."""
    d = np.asarray(lens.coefficients, np.float64)
    used = int(np.flatnonzero(d)[-1]) + 1
    lengths = (4,) if lens.model in FISHEYE_MODELS else _OPENCV_LENGTHS
    n = next(n for n in lengths if n >= used)
    out = np.zeros(n)
    out[:used] = d[:used]
    return out


@lru_cache(maxsize=1)
def _opencv() -> Any:
    """``cv2``, imported on first use (recordings without distortion never pay for it) with
    its pool at the process's thread count, as :mod:`care_maps.runtime.threads` sizes the others (a remap
    gains nothing from a second thread on a busy machine; its result is the same)."""
    import cv2

    cv2.setNumThreads(thread_count(Work.DEFAULT))
    return cv2


@lru_cache(maxsize=8)
def _maps(
    lens: Distortion, k: tuple[float, ...], width: int, height: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fixed-point remap tables from each pinhole pixel to where the lens put it: bilinear
    (coordinates, fractions) and nearest (coordinates rounded)."""
    cv2 = _opencv()

    K = np.asarray(k, np.float64).reshape(3, 3)
    d = _opencv_coefficients(lens)
    size = (width, height)
    if lens.model in FISHEYE_MODELS:
        mx, my = cv2.fisheye.initUndistortRectifyMap(K, d, np.eye(3), K, size, cv2.CV_32FC1)
    else:
        mx, my = cv2.initUndistortRectifyMap(K, d, np.eye(3), K, size, cv2.CV_32FC1)
    xy, fraction = cv2.convertMaps(mx, my, cv2.CV_16SC2)
    nearest, _ = cv2.convertMaps(mx, my, cv2.CV_16SC2, nninterpolation=True)
    return xy, fraction, nearest


def undistort(image: np.ndarray, K: np.ndarray, lens: Distortion, *, blend: bool) -> np.ndarray:
    """``image`` (H, W[, C]) as the pinhole camera K would have seen it; ``blend``: bilinear
    interpolation (colour), else the nearest pixel (depth, labels). Zero D: ``image`` itself."""
    if lens.is_zero:
        return image
    cv2 = _opencv()

    h, w = image.shape[:2]
    xy, fraction, nearest = _maps(lens, tuple(np.asarray(K, np.float64).ravel().tolist()), w, h)
    if blend:
        out = cv2.remap(image, xy, fraction, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    else:
        out = cv2.remap(image, nearest, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
    return out.reshape(image.shape)
