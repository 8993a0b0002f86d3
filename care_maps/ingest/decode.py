"""ROS messages (as rosbags deserialises them, ROS 1 or ROS 2) to numpy arrays.

Every decoder takes the topic name only to put it in error messages. Image encodings follow
``sensor_msgs/image_encodings.h``; depth follows REP 118 (16-bit in millimetres, 32-bit
float in metres). ``compressedDepth`` is image_transport's format: a 12-byte header
(int32 format, float32 quantisation a, b) followed by a PNG.
"""

from __future__ import annotations

import io
import re
import struct
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from care_maps.core.errors import IngestError
from care_maps.ingest.undistort import Distortion, parse_distortion

if TYPE_CHECKING:
    from PIL import Image

__all__ = [
    "COLOUR_ENCODINGS",
    "DEPTH_ENCODINGS",
    "LABEL_ENCODINGS",
    "StampedTransform",
    "camera_info",
    "decode_colour",
    "decode_colour_kept",
    "decode_depth",
    "decode_label",
    "distortion",
    "image_size",
    "pose_sample",
    "stamp_ns",
    "transforms",
]

COLOUR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8")
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")
LABEL_ENCODINGS = ("16UC1", "mono16", "mono8", "8UC1", "32SC1")

_CHANNELS = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "8UC1": 1}
_DTYPES = {
    "rgb8": "u1",
    "bgr8": "u1",
    "rgba8": "u1",
    "bgra8": "u1",
    "mono8": "u1",
    "8UC1": "u1",
    "16UC1": "u2",
    "mono16": "u2",
    "32FC1": "f4",
    "32SC1": "i4",
}


def stamp_ns(msg: Any, fallback: int) -> int:
    """Header stamp in ns; ``fallback`` (the bag's log time) when the header has none."""
    header = getattr(msg, "header", None)
    if header is None:
        return int(fallback)
    t = int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec)
    return t if t > 0 else int(fallback)


def image_size(msg: Any) -> tuple[int, int] | None:
    """(width, height) of a raw Image; None for a CompressedImage (known after decoding)."""
    if hasattr(msg, "width") and hasattr(msg, "encoding"):
        return int(msg.width), int(msg.height)
    return None


def _raw_array(msg: Any, topic: str, allowed: tuple[str, ...]) -> tuple[np.ndarray, str]:
    """(H, W[, C]) array of a raw sensor_msgs/Image, honouring ``step`` and endianness."""
    enc = str(msg.encoding)
    if enc not in allowed:
        msg_ = (
            f"topic {topic}: image encoding {enc!r} is not supported here "
            f"(supported: {', '.join(allowed)}); convert it or pick another topic."
        )
        raise IngestError(msg_)
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    dtype = np.dtype(_DTYPES[enc]).newbyteorder(">" if msg.is_bigendian else "<")
    channels = _CHANNELS.get(enc, 1)
    data = np.asarray(msg.data, dtype=np.uint8)
    row_bytes = w * channels * dtype.itemsize
    if step < row_bytes or data.size != h * step:
        msg_ = (
            f"topic {topic}: image data has {data.size} bytes, expected {h} rows of step "
            f"{step} >= {row_bytes} ({h * step} bytes) for {w}x{h} {enc}; the message is corrupt."
        )
        raise IngestError(msg_)
    rows = data[: h * step].reshape(h, step)[:, :row_bytes]
    arr = np.ascontiguousarray(rows).view(dtype).reshape(h, w, channels)
    return arr.astype(dtype.newbyteorder("=")), enc


def _is_compressed(msg: Any) -> bool:
    return hasattr(msg, "format") and not hasattr(msg, "encoding")


def _open_compressed(data: bytes, topic: str, fmt: str) -> Image.Image:
    from PIL import Image, UnidentifiedImageError  # here: a query or --help decodes nothing

    try:
        img = Image.open(io.BytesIO(data))
        img.load()
    except UnidentifiedImageError as err:  # its text names the in-memory file's address
        head = data[:4].hex(" ") or "empty"
        msg = f"topic {topic}: cannot decode compressed image of format {fmt!r} ({len(data)} bytes starting {head}: not an image PIL can identify); the message is corrupt or in an unsupported codec."
        raise IngestError(msg) from err
    except (OSError, SyntaxError, ValueError) as err:
        msg = f"topic {topic}: cannot decode compressed image of format {fmt!r} ({_stable(err)}); the message is corrupt or in an unsupported codec."
        raise IngestError(msg) from err
    return img


def _stable(err: BaseException) -> str:
    """An error's text without the memory addresses some carry (``<... at 0x7f...>``), so
    the same input gives the same line on every run."""
    return re.sub(r" at 0x[0-9a-f]+", "", str(err)) or type(err).__name__


def _not_empty(image: np.ndarray, topic: str, what: str) -> np.ndarray:
    """``image``, or one line if it has no pixel (a 0x0 message): said as such, not as a
    size that differs from the other stream's."""
    if image.shape[0] == 0 or image.shape[1] == 0:
        msg = f"topic {topic}: a {what} image is {image.shape[1]}x{image.shape[0]}, empty; the message is corrupt (remove it from the recording or pick another topic)."
        raise IngestError(msg)
    return image


def decode_colour(msg: Any, topic: str) -> np.ndarray:
    """(H, W, 3) uint8 RGB from an Image (rgb8, bgr8, rgba8, bgra8, mono8) or a JPEG/PNG."""
    return decode_colour_kept(msg, topic)[0]


def decode_colour_kept(msg: Any, topic: str) -> tuple[np.ndarray, bytes | None]:
    """:func:`decode_colour`, and the message's own bytes when they are a JPEG: the store
    keeps those instead of encoding the image again (:attr:`care_maps.core.frames.Frame.rgb_jpeg`)."""
    rgb, jpeg = _decode_colour(msg, topic)
    return _not_empty(rgb, topic, "colour"), jpeg


def _decode_colour(msg: Any, topic: str) -> tuple[np.ndarray, bytes | None]:
    if _is_compressed(msg):
        fmt = str(msg.format)
        data = bytes(np.asarray(msg.data, np.uint8))
        img = _open_compressed(data, topic, fmt)
        # Pillow's decoding, the one the store reads JPEGs back with (care_maps.core.codecs)
        return np.asarray(img.convert("RGB")), data if img.format == "JPEG" else None
    arr, enc = _raw_array(msg, topic, COLOUR_ENCODINGS)
    if enc in ("bgr8", "bgra8"):
        arr = arr[..., 2::-1]
    elif enc == "mono8":
        arr = np.repeat(arr, 3, axis=2)
    return np.ascontiguousarray(arr[..., :3]), None


def _compressed_depth(msg: Any, topic: str) -> np.ndarray:
    fmt = str(msg.format)
    data = bytes(np.asarray(msg.data, np.uint8))
    if len(data) < 12:
        msg_ = f"topic {topic}: compressedDepth message of {len(data)} bytes, shorter than its 12-byte header; the message is corrupt."
        raise IngestError(msg_)
    _, quant_a, quant_b = struct.unpack("<iff", data[:12])
    img = np.asarray(_open_compressed(data[12:], topic, fmt))
    if fmt.split(";")[0].strip() == "32FC1":
        # image_transport stores inverse depth quantised: value = a / depth + b.
        v = img.astype(np.float32)
        with np.errstate(divide="ignore"):
            depth = np.where(v > 0, quant_a / (v - quant_b), 0.0)
        return np.nan_to_num(depth.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    return img.astype(np.float32) * np.float32(0.001)


MILLIMETRES = 1000.0
"""Depth value of one metre in 16-bit depth images (REP 118: ``16UC1`` millimetres)."""


def decode_depth(msg: Any, topic: str, scale: float | None = None) -> np.ndarray:
    """(H, W) float32 metres, 0 where invalid (NaN, inf, 0, negative). ``scale``: the depth
    value of one metre (``--depth-scale``) instead of the encoding's own (1000 for 16-bit
    images, 1 for ``32FC1``): a driver that writes other units under a standard encoding."""
    if _is_compressed(msg):
        fmt = str(msg.format)
        if "compresseddepth" in fmt.lower():
            depth = _compressed_depth(msg, topic)
            own = 1.0 if fmt.split(";")[0].strip() == "32FC1" else MILLIMETRES
            if scale is not None:  # back to the values as written, then the given units
                depth = depth * np.float32(own / scale)
        else:
            img = np.asarray(_open_compressed(bytes(np.asarray(msg.data, np.uint8)), topic, fmt))
            if img.ndim != 2 or img.dtype.kind not in "ui" or img.dtype.itemsize < 2:
                msg_ = f"topic {topic}: compressed depth of format {fmt!r} is not a 16-bit single-channel image; use compressedDepth or 16-bit PNG."
                raise IngestError(msg_)
            depth = img.astype(np.float32) / np.float32(scale or MILLIMETRES)
    else:
        arr, enc = _raw_array(msg, topic, DEPTH_ENCODINGS)
        arr = arr[..., 0]
        if scale is None:
            depth = arr.astype(np.float32) if enc == "32FC1" else arr.astype(np.float32) * 0.001
        else:
            depth = arr.astype(np.float32) / np.float32(scale)
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0)
    return _not_empty(depth.astype(np.float32), topic, "depth")


def decode_label(msg: Any, topic: str) -> np.ndarray:
    """(H, W) uint16 label image (instance or class ids)."""
    if _is_compressed(msg):
        img = np.asarray(_open_compressed(bytes(np.asarray(msg.data, np.uint8)), topic, msg.format))
        return img.astype(np.uint16)
    arr, _ = _raw_array(msg, topic, LABEL_ENCODINGS)
    return arr[..., 0].astype(np.uint16)


def camera_info(msg: Any, topic: str | None) -> tuple[np.ndarray, int, int]:
    """(K (3, 3), width, height) of a CameraInfo; ROS 1 names the matrix ``K``, ROS 2 ``k``."""
    k = getattr(msg, "k", None)
    if k is None:
        k = getattr(msg, "K", None)
    K = np.asarray(k, np.float64).reshape(3, 3) if k is not None else np.zeros((3, 3))
    if not (K[0, 0] > 0 and K[1, 1] > 0 and K[2, 2] == 1.0):
        msg_ = f"topic {topic}: camera_info field K/k = {K.ravel().tolist()} is not a valid pinhole matrix (fx, fy > 0, K[2,2] = 1); calibrate the camera, pass --camera-info, or give --intrinsics."
        raise IngestError(msg_)
    return K, int(msg.width), int(msg.height)


def distortion(msg: Any, topic: str | None) -> Distortion:
    """``distortion_model`` and D of a CameraInfo (ROS 1 ``D``, ROS 2 ``d``); one line when a
    non-zero D cannot be applied (:func:`care_maps.ingest.undistort.parse_distortion`)."""
    d = getattr(msg, "d", None)
    if d is None:
        d = getattr(msg, "D", None)
    return parse_distortion(str(getattr(msg, "distortion_model", "") or ""), d, topic)


class StampedTransform(NamedTuple):
    """``parent_from_child`` at ``stamp_ns``: translation (3,) metres, rotation (4,) xyzw."""

    parent: str
    child: str | None
    stamp_ns: int
    translation: np.ndarray
    rotation: np.ndarray


def _stamped(
    parent: str, child: str | None, t: int, translation: Any, rotation: Any
) -> StampedTransform:
    return StampedTransform(
        _strip(parent),
        None if child is None else _strip(child),
        t,
        np.array([translation.x, translation.y, translation.z], np.float64),
        np.array([rotation.x, rotation.y, rotation.z, rotation.w], np.float64),
    )


def transforms(msg: Any, fallback_ns: int) -> list[StampedTransform]:
    """The transforms of a TFMessage (``tf2_msgs`` or ROS 1 ``tf/tfMessage``)."""
    return [
        _stamped(
            ts.header.frame_id,
            ts.child_frame_id,
            stamp_ns(ts, fallback_ns),
            ts.transform.translation,
            ts.transform.rotation,
        )
        for ts in msg.transforms
    ]


def pose_sample(msg: Any, fallback_ns: int) -> StampedTransform:
    """The pose of an Odometry (child = its ``child_frame_id``) or PoseStamped (child None)."""
    odometry = hasattr(msg, "child_frame_id")
    pose = msg.pose.pose if odometry else msg.pose
    return _stamped(
        msg.header.frame_id,
        msg.child_frame_id if odometry else None,
        stamp_ns(msg, fallback_ns),
        pose.position,
        pose.orientation,
    )


def _strip(frame: str) -> str:
    """tf2 frame ids carry no leading slash (tf1 bags often have one)."""
    return str(frame).lstrip("/")
