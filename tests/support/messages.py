"""ROS 2 messages built through rosbags' own type store (ROS 2 Humble), independently of
``care_maps.ingest.write``: encodings and broken messages our own writer never produces.

Each builder returns the type store's message instance; its fields can be set afterwards
(``msg.step = ...``) to make a message the builders do not.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping, Sequence
from typing import ClassVar, Final, Protocol, TypeAlias

import numpy as np
from PIL import Image
from rosbags.typesys import Stores, get_typestore

CAMERA_FRAME: Final = "camera_optical_frame"
"""The frame id the builders stamp images, camera infos and headers with by default."""


class Message(Protocol):
    """A rosbags message: an instance of a class its type store made, fields by name."""

    __msgtype__: ClassVar[str]


MessageTypes: TypeAlias = Mapping[str, Callable[..., Message]]
"""A type store's message classes by type name (``"sensor_msgs/msg/Image"``)."""

TS: Final = get_typestore(Stores.ROS2_HUMBLE)
"""The ROS 2 type store every message here is built and serialised with."""
T: Final[MessageTypes] = TS.types

Vector: TypeAlias = Sequence[float] | np.ndarray
"""Three (a translation) or four (an x, y, z, w quaternion) numbers."""


def header(t_ns: int, frame_id: str = CAMERA_FRAME) -> Message:
    stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def image_msg(
    t_ns: int,
    array: np.ndarray,
    encoding: str,
    frame_id: str = CAMERA_FRAME,
    *,
    size: int | None = None,
) -> Message:
    """A ``sensor_msgs/Image`` of ``array`` (its shape, its row stride as the step);
    ``size``: that many data bytes instead, zero-padded or cut (a broken image)."""
    data = np.ascontiguousarray(array)
    flat = data.view(np.uint8).reshape(-1)
    if size is not None:
        if size > flat.size:
            flat = np.concatenate([flat, np.zeros(size - flat.size, np.uint8)])
        flat = flat[:size]
    return T["sensor_msgs/msg/Image"](
        header=header(t_ns, frame_id),
        height=data.shape[0],
        width=data.shape[1],
        encoding=encoding,
        is_bigendian=0,
        step=int(data.strides[0]),
        data=flat,
    )


def compressed_msg(t_ns: int, data: bytes, fmt: str) -> Message:
    return T["sensor_msgs/msg/CompressedImage"](
        header=header(t_ns), format=fmt, data=np.frombuffer(data, np.uint8)
    )


def camera_info_msg(
    t_ns: int,
    K: np.ndarray,
    w: int,
    h: int,
    *,
    distortion_model: str = "plumb_bob",
    d: Vector | None = None,
) -> Message:
    """A ``sensor_msgs/CameraInfo`` of the 3x3 ``K`` (P = [K | 0]); ``d``: the lens's
    coefficients (default five zeros)."""
    roi = T["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    P = np.zeros((3, 4))
    P[:, :3] = K
    return T["sensor_msgs/msg/CameraInfo"](
        header=header(t_ns),
        height=h,
        width=w,
        distortion_model=distortion_model,
        d=np.zeros(5) if d is None else np.asarray(d, np.float64),
        k=np.asarray(K, np.float64).ravel(),
        r=np.eye(3).ravel(),
        p=P.ravel(),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def tf_msg(t_ns: int, parent: str, child: str, xyz: Vector, quat_xyzw: Vector) -> Message:
    """A ``tf2_msgs/TFMessage`` of the one transform ``parent`` -> ``child``."""
    tr = T["geometry_msgs/msg/Transform"](
        translation=T["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
        rotation=T["geometry_msgs/msg/Quaternion"](
            x=quat_xyzw[0], y=quat_xyzw[1], z=quat_xyzw[2], w=quat_xyzw[3]
        ),
    )
    ts = T["geometry_msgs/msg/TransformStamped"](
        header=header(t_ns, parent), child_frame_id=child, transform=tr
    )
    return T["tf2_msgs/msg/TFMessage"](transforms=[ts])


def odometry_msg(t_ns: int, T_parent_child: np.ndarray, parent: str, child: str) -> Message:
    """A nav_msgs/Odometry placing ``child`` at the 4x4 ``T_parent_child`` (zero twist)."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(T_parent_child)[:3, :3]).as_quat()
    x, y, z = np.asarray(T_parent_child)[:3, 3]
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z)),
        orientation=T["geometry_msgs/msg/Quaternion"](
            x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])
        ),
    )
    zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    twist = T["geometry_msgs/msg/TwistWithCovariance"](
        twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
    )
    return T["nav_msgs/msg/Odometry"](
        header=header(t_ns, parent),
        child_frame_id=child,
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=twist,
    )


def png_bytes(array: np.ndarray) -> bytes:
    """``array`` as a PNG file's bytes (PIL)."""
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


def jpeg_bytes(array: np.ndarray) -> bytes:
    """``array`` as a JPEG file's bytes (PIL, quality 90)."""
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="JPEG", quality=90)
    return buf.getvalue()
