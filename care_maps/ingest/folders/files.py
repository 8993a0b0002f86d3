"""Reading a dataset folder's own files: image lists, images, text tables, stamps, poses.

Every reader here fails with one :class:`care_maps.core.errors.IngestError` line that names the file
(and the line of a text file) and what to do, never a traceback: a dataset as downloaded is
bad input like any recording.
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.geometry.transforms import quaternion_to_matrix
from care_maps.ingest.conventions import QuaternionOrder
from care_maps.ingest.intrinsics import NAMED_CAMERAS, CameraIntrinsics, NamedCamera

if TYPE_CHECKING:
    from PIL import Image

__all__ = [
    "DEPTH_MILLIMETRES",
    "IMAGE_SUFFIXES",
    "MAX_STAMP_SECONDS",
    "PINHOLE_KEYS",
    "PRIMESENSE",
    "Intrinsics",
    "image_files",
    "json_file",
    "natural_key",
    "numbers",
    "pose_from_tum",
    "read_colour",
    "read_colour_kept",
    "read_depth",
    "stamp_ns",
    "table",
]

DEPTH_MILLIMETRES = 1000.0
"""Depth value of one metre in millimetre PNGs (Redwood, Open3D, our generic layout)."""
PINHOLE_KEYS = ("fx", "fy", "cx", "cy")
"""The pinhole parameters (pixels) a camera file names, as :class:`Intrinsics` takes them."""
PRIMESENSE = NAMED_CAMERAS[NamedCamera.PRIMESENSE]
"""The PrimeSense / Kinect default camera (Open3D's ``PrimeSenseDefault``), as
:data:`care_maps.ingest.intrinsics.NAMED_CAMERAS` states it."""
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
"""Colour image files a folder may hold (Open3D's reconstruction system reads the first two)."""
MAX_STAMP_SECONDS = 1e11
"""Largest stamp, in seconds, a dataset's text file may hold (the year 5138): epoch
nanoseconds (1.7e18) or microseconds (1.7e15) written where seconds belong lie far above."""
_SIXTEEN_BIT_GREY = ("I;16", "I;16B", "I;16L", "I;16N", "I")
"""Pillow's modes of a 16-bit single-channel PNG; ``convert("RGB")`` clips them at 255."""
_UINT16_MAX = 65535


def natural_key(path: Path) -> tuple[Any, ...]:
    """Sort key that orders ``frame2`` before ``frame10`` (numbers compared as numbers), as the
    datasets' own loaders sort their file lists."""
    parts = re.split(r"(\d+)", path.name)
    return tuple(int(p) if p.isdigit() else p for p in parts)


def image_files(
    folder: Path, suffixes: Iterable[str] = IMAGE_SUFFIXES, pattern: str = "*"
) -> list[Path]:
    """The images in ``folder`` matching ``pattern`` with one of ``suffixes``, naturally sorted."""
    wanted = tuple(s.lower() for s in suffixes)
    found = [p for p in folder.glob(pattern) if p.is_file() and p.suffix.lower() in wanted]
    return sorted(found, key=natural_key)


def _open(path: Path) -> Image.Image:
    from PIL import Image, UnidentifiedImageError  # at first image: not at the CLI's start

    if not path.is_file():
        msg = f"{path}: no such image; the dataset folder is incomplete (re-copy it)."
        raise IngestError(msg)
    try:
        image = Image.open(path)
        image.load()
    except (OSError, UnidentifiedImageError, ValueError) as err:
        msg = (
            f"{path}: cannot read the image ({err}); the file is truncated or corrupt, re-copy it."
        )
        raise IngestError(msg) from err
    return image


def _rgb(image: Image.Image, path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an opened image. A 16-bit grey image (``I;16``; a PNG read as
    ``I`` holds the same 0..65535) is scaled to 8 bit, ``round(v * 255 / 65535)``, and
    replicated to three channels: Pillow's own conversion clips every value above 255, which
    makes such an image all white."""
    if image.mode not in _SIXTEEN_BIT_GREY:
        return np.asarray(image.convert("RGB"))
    values = np.asarray(image).astype(np.int64)
    if values.size and (values.min() < 0 or values.max() > _UINT16_MAX):
        msg = f"{path}: a {image.mode} colour image with values {values.min()}..{values.max()}, beyond 16 bits; write the colour images as 8-bit RGB."
        raise IngestError(msg)
    grey = np.round(values * (255 / _UINT16_MAX)).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=-1)


def read_colour(path: Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a colour image file (16-bit grey scaled, :func:`_rgb`)."""
    with _open(path) as image:
        return _rgb(image, path)


def read_colour_kept(path: Path) -> tuple[np.ndarray, bytes | None]:
    """:func:`read_colour`, and the file's own bytes when it is a JPEG: the store keeps
    those instead of encoding the image again (:attr:`care_maps.core.frames.Frame.rgb_jpeg`)."""
    with _open(path) as image:
        rgb = _rgb(image, path)
        jpeg = image.format == "JPEG"
    return rgb, path.read_bytes() if jpeg else None


def read_depth(path: Path, scale: float, invalid: int | None = None) -> np.ndarray:
    """(H, W) float32 metres of a 16-bit depth PNG whose value ``scale`` is one metre; 0, and
    ``invalid`` where a dataset marks missing depth with another value, read as no depth."""
    with _open(path) as image:
        mode = image.mode
        values = np.asarray(image)
    if values.ndim != 2 or values.dtype.kind not in "ui" or mode in ("L", "P", "1"):
        msg = f"{path}: a {mode} image of shape {values.shape}, not a 16-bit single-channel depth image; the folder's depth/ holds something else (check the layout with care topics)."
        raise IngestError(msg)
    depth = (values.astype(np.float32) / np.float32(scale)).astype(np.float32)
    if invalid is not None:
        depth[values == invalid] = 0.0
    return depth


def table(path: Path, columns: int | tuple[int, ...], what: str) -> list[tuple[int, list[str]]]:
    """``(line number, fields)`` of each row of a whitespace-separated text file, without blank
    lines and ``#`` comments; every row must have one of ``columns`` fields. ``what`` says
    what the file should hold, for the error."""
    if not path.is_file():
        msg = f"{path}: missing; the folder needs it ({what})."
        raise IngestError(msg)
    wanted = (columns,) if isinstance(columns, int) else columns
    rows = []
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        msg = f"{path}: cannot read it as text ({err}); re-copy the file."
        raise IngestError(msg) from err
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.replace(",", " ").split()
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) not in wanted:
            counts = " or ".join(str(n) for n in wanted)
            msg = f"{path}: line {number} has {len(fields)} fields, expected {counts} ({what}); fix or re-copy the file."
            raise IngestError(msg)
        rows.append((number, fields))
    return rows


def numbers(fields: list[str], path: Path, line: int) -> np.ndarray:
    """The fields of one row as float64 (``nan`` and ``inf`` kept: a lost pose reads as one)."""
    try:
        return np.array([float(f) for f in fields], np.float64)
    except ValueError as err:
        msg = f"{path}: line {line} is not all numbers ({err}); fix or re-copy the file."
        raise IngestError(msg) from err


def stamp_ns(text: str, path: Path, line: int) -> int:
    """Seconds written as a decimal (``1305031102.175304``) to integer nanoseconds, exactly:
    a float64 of epoch seconds keeps only about a quarter of a microsecond."""
    try:
        value = Decimal(text)
    except InvalidOperation as err:
        msg = f"{path}: line {line}: {text!r} is not a time in seconds; fix or re-copy the file."
        raise IngestError(msg) from err
    if not value.is_finite():
        msg = f"{path}: line {line}: time {text!r} is not finite; fix or re-copy the file."
        raise IngestError(msg)
    if abs(value) > MAX_STAMP_SECONDS:
        msg = f"{path}: line {line}: time {text} is beyond {MAX_STAMP_SECONDS:.0e} s (the year 5138): the stamps look like nanoseconds (or microseconds); write seconds (e.g. 1305031102.175304)."
        raise IngestError(msg)
    return int((value * 1_000_000_000).to_integral_value())


def pose_from_tum(
    values: np.ndarray, path: Path, line: int, order: QuaternionOrder = QuaternionOrder.XYZW
) -> np.ndarray:
    """(4, 4) pose of ``tx ty tz`` and a quaternion in ``order`` (TUM's ``qx qy qz qw`` by
    default); non-finite values give a non-finite pose (a view the reader drops as unposed),
    a zero quaternion is an error (no rotation at all)."""
    pose = np.full((4, 4), np.nan)
    if not np.isfinite(values).all():
        return pose
    quaternion = values[3:] if order is QuaternionOrder.XYZW else np.roll(values[3:], -1)
    if np.linalg.norm(quaternion) < 1e-6:
        msg = f"{path}: line {line}: quaternion {values[3:].tolist()} is zero, not a rotation; fix or re-copy the file."
        raise IngestError(msg)
    pose = np.eye(4)
    pose[:3, :3] = quaternion_to_matrix(quaternion)
    pose[:3, 3] = values[:3]
    return pose


def json_file(path: Path, what: str) -> dict[str, Any]:
    """A JSON object file, or one line naming it."""
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        msg = f"{path}: cannot read it as JSON ({err}); it should hold {what}."
        raise IngestError(msg) from err
    if not isinstance(data, dict):
        msg = f"{path}: not a JSON object; it should hold {what}."
        raise IngestError(msg)
    return data


class Intrinsics:
    """A pinhole camera as a dataset states it: K, the image size it is for (0: any) and where
    it came from (a file name relative to the folder, or the dataset's published values)."""

    def __init__(self, fx: float, fy: float, cx: float, cy: float, *, width: int = 0,
                 height: int = 0, source: str) -> None:  # fmt: skip
        self.K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], np.float64)
        self.width, self.height, self.source = int(width), int(height), source
        self._first: tuple[int, int, Path] | None = None
        if not (np.isfinite(self.K).all() and fx > 0 and fy > 0):
            msg = f"{source}: intrinsics fx {fx}, fy {fy}, cx {cx}, cy {cy} are not a camera (focal lengths must be finite and positive); fix the file."
            raise IngestError(msg)

    @classmethod
    def of(cls, camera: CameraIntrinsics, source: str) -> Intrinsics:
        """The pinhole part of a :class:`care_maps.ingest.intrinsics.CameraIntrinsics` (its lens is
        the caller's to keep)."""
        return cls(camera.fx, camera.fy, camera.cx, camera.cy, width=camera.width,
                   height=camera.height, source=source)  # fmt: skip

    def check_size(self, width: int, height: int, image: Path, fix: str) -> None:
        """Refuse images of another size than the intrinsics are for: K would put every
        pixel's ray in the wrong place. ``fix`` names the file that gives the right ones.
        Intrinsics for any size (none stated) take the first image's: one K cannot be the
        camera of two image sizes, so a later image of another size is refused too."""
        if self.width and self.height and (width, height) != (self.width, self.height):
            msg = f"{image}: {width}x{height} image, but the intrinsics ({self.source}) are for {self.width}x{self.height}; {fix}."
            raise IngestError(msg)
        if self._first is None:
            self._first = (width, height, image)
        first_w, first_h, first = self._first
        if (width, height) != (first_w, first_h):
            msg = f"{image}: {width}x{height} image, but the first view {first.name} is {first_w}x{first_h} and the intrinsics ({self.source}) state no size; all views share one camera: resize the images to one size, or state the size the camera is for ({fix})."
            raise IngestError(msg)

    def as_json(self) -> dict[str, Any]:
        K = self.K
        return {
            "fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]),
            "cy": float(K[1, 2]), "width": self.width, "height": self.height,
            "source": self.source,
        }  # fmt: skip
