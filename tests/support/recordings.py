"""Hand-built recordings, written through the real writers (rosbags for ROS 1 bags and
rosbag2, mcap for a plain MCAP file) from ``(topic, t_ns, message)`` lists, independently of
``care_maps.ingest.write``: encodings and broken recordings our own writer never produces.

:func:`write_bag` is the one writer; the rest build message lists for it.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from enum import StrEnum
from pathlib import Path
from typing import Any, Final, TypeAlias

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore
from scipy.spatial.transform import Rotation

from care_maps.core.frames import Frame

from .frames import K_SMALL
from .messages import (
    TS,
    Message,
    MessageTypes,
    T,
    Vector,
    camera_info_msg,
    header,
    image_msg,
    tf_msg,
)

Stamped: TypeAlias = tuple[str, int, Message]
"""One message of a recording: ``(topic, log time in ns, message)``."""

MCAP_LIBRARY: Final = "care-maps tests"
"""What a plain MCAP file written here names as its writer."""


class Container(StrEnum):
    """The file a recording is written to."""

    ROS1 = "ros1"
    """A ROS 1 bag (rosbags' rosbag1 writer; messages as ROS 1 Noetic's)."""
    ROS2 = "ros2"
    """A rosbag2 directory, MCAP storage (rosbags' rosbag2 writer, version 9)."""
    MCAP = "mcap"
    """A plain MCAP file, ROS 2 profile, CDR messages (mcap's writer)."""


def write_bag(
    path: Path,
    messages: Sequence[Stamped],
    container: Container = Container.ROS2,
    *,
    library: str = MCAP_LIBRARY,
) -> Path:
    """``(topic, t_ns, message)`` into a recording of ``container`` at ``path`` through its
    real writer, each topic's connection made at its first message; ``library``: the MCAP
    header's writer name (a plain MCAP file only)."""
    if container is Container.ROS2:
        _write_rosbag2(path, messages)
    elif container is Container.ROS1:
        _write_ros1(path, messages)
    else:
        _write_mcap(path, messages, library)
    return path


def _write_rosbag2(path: Path, messages: Sequence[Stamped]) -> None:
    from rosbags.interfaces import Connection
    from rosbags.rosbag2 import StoragePlugin, Writer

    conns: dict[str, Connection] = {}
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic, t, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=TS)
            writer.write(conns[topic], t, bytes(TS.serialize_cdr(msg, msg.__msgtype__)))


@functools.cache
def ros1_typestore() -> Typestore:
    """ROS 1 Noetic's type store, with ``tf2_msgs/TFMessage`` (Noetic's has tf's only)."""
    store = get_typestore(Stores.ROS1_NOETIC)
    if "tf2_msgs/msg/TFMessage" not in store.fielddefs:
        store.register(
            get_types_from_msg(
                "geometry_msgs/TransformStamped[] transforms\n", "tf2_msgs/msg/TFMessage"
            )
        )
    return store


def as_ros1(msg: Message, store: Typestore) -> Message:
    """The ROS 1 message with ``msg``'s (ROS 2) values: fields by name (CameraInfo's ``K``
    is ROS 2's ``k``), a header with a sequence number."""
    cls: Any = store.types[msg.__msgtype__]
    values: dict[str, object] = {}
    for f in dataclasses.fields(cls):
        if f.name == "seq":
            values[f.name] = 0
            continue
        value = getattr(msg, f.name) if hasattr(msg, f.name) else getattr(msg, f.name.lower())
        if hasattr(value, "__msgtype__"):
            value = as_ros1(value, store)
        elif isinstance(value, list):
            value = [as_ros1(v, store) if hasattr(v, "__msgtype__") else v for v in value]
        values[f.name] = value
    made: Message = cls(**values)
    return made


def _write_ros1(path: Path, messages: Sequence[Stamped]) -> None:
    from rosbags.interfaces import Connection
    from rosbags.rosbag1 import Writer

    store = ros1_typestore()
    conns: dict[str, Connection] = {}
    with Writer(path) as writer:
        for topic, t, msg in messages:
            ros1 = as_ros1(msg, store)
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=store)
            writer.write(conns[topic], t, bytes(store.serialize_ros1(ros1, msg.__msgtype__)))


def _write_mcap(path: Path, messages: Sequence[Stamped], library: str) -> None:
    from mcap.writer import Writer

    with path.open("wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library=library)
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, t, msg in messages:
            kind = msg.__msgtype__
            if kind not in schemas:
                msgdef, _ = TS.generate_msgdef(kind, ros_version=2)
                schemas[kind] = writer.register_schema(kind, "ros2msg", msgdef.encode())
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "cdr", schemas[kind])
            data = bytes(TS.serialize_cdr(msg, kind))
            writer.add_message(channels[topic], log_time=t, data=data, publish_time=t)
        writer.finish()


# -- recordings ---------------------------------------------------------------------------

MakeImage: TypeAlias = Callable[[int, int], Message]
"""``make(i, t_ns)``: the ``i``-th image message, stamped ``t_ns``."""


def rgbd_messages(
    rgb: MakeImage | None,
    depth: MakeImage | None,
    *,
    n: int = 3,
    info: bool = True,
    tf: bool = True,
    w: int = 32,
    h: int = 24,
) -> list[Stamped]:
    """Messages of a small RGB-D recording; ``rgb(i, t)``/``depth(i, t)`` build the images."""
    out: list[Stamped] = []
    if tf:
        out.append(
            (
                "/tf_static",
                10**9,
                tf_msg(10**9, "map", "camera_optical_frame", (0.0, 0.0, 1.0), (0, 0, 0, 1)),
            )
        )
    for i in range(n):
        t = 10**9 + i * 100_000_000
        if info:
            out.append(("/camera/color/camera_info", t, camera_info_msg(t, K_SMALL, w, h)))
        if rgb is not None:
            out.append(("/camera/color/image_raw", t, rgb(i, t)))
        if depth is not None:
            out.append(("/camera/depth/image_raw", t, depth(i, t)))
    return out


DynamicTransform: TypeAlias = tuple[int, str, str, Vector, Vector]
"""``(stamp, parent, child, xyz, xyzw)``: one transform on /tf."""
MakeColour: TypeAlias = Callable[[MessageTypes, int, Message], Message]
"""``colour(types, stamp, header)``: a colour message made instead of the grey image."""


def grey_bag(
    path: Path,
    *,
    n: int = 3,
    w: int = 32,
    h: int = 24,
    quat: Vector = (0.0, 0.0, 0.0, 1.0),
    xyz: Vector = (0.0, 0.0, 1.0),
    tf_edges: tuple[tuple[str, str], ...] = (("map", "camera_optical_frame"),),
    rgb_bytes_delta: int = 0,
    stamps: list[int] | None = None,
    shades: list[int] | None = None,
    dynamic: Sequence[DynamicTransform] = (),
    colour: MakeColour | None = None,
) -> Path:
    """A small RGB-D rosbag2 (mcap storage): ``tf_edges`` on /tf_static (the last one gets
    ``quat``/``xyz``), rgb8 colour with ``rgb_bytes_delta`` bytes more (or fewer) than
    w x h x 3, 16UC1 depth, camera info; colour stamps ``stamps`` (default 100 ms apart),
    image i all grey level ``shades[i]`` (default 40 i); ``dynamic`` transforms
    ``(stamp, parent, child, xyz, quat)`` on /tf, one message each, logged at their stamp;
    ``colour(types, stamp, header)``, if given, makes each colour message instead (a
    CompressedImage, an empty Image, ...)."""
    K = np.array([40.0, 0, w / 2, 0, 40.0, h / 2, 0, 0, 1]).reshape(3, 3)
    info = camera_info_msg(10**9, K, w, h)
    messages: list[Stamped] = []
    for i, (parent, child) in enumerate(tf_edges):
        last = i == len(tf_edges) - 1
        messages.append(
            ("/tf_static", 10**9, tf_msg(10**9, parent, child, xyz if last else (0, 0, 0),
                                         quat if last else (0, 0, 0, 1)))
        )  # fmt: skip
    for t, parent, child, p, q in dynamic:
        messages.append(("/tf", t, tf_msg(t, parent, child, p, q)))
    stamps = stamps or [10**9 + i * 100_000_000 for i in range(n)]
    for i, t in enumerate(stamps):
        rgb = np.full((h, w, 3), (shades[i] if shades else 40 * i) % 256, np.uint8)
        depth = np.full((h, w), 1500, np.uint16)
        messages.append(("/camera/color/camera_info", t, info))
        made = colour(T, t, header(t)) if colour else None
        messages.append(
            (
                "/camera/color/image_raw",
                t,
                made or image_msg(t, rgb, "rgb8", size=h * w * 3 + rgb_bytes_delta),
            )
        )
        messages.append(("/camera/depth/image_raw", t, image_msg(t, depth, "16UC1")))
    return write_bag(path, messages)


OPTICAL: Final = "camera_color_optical_frame"
"""The colour camera's optical frame, as realsense2_camera names it."""
BASE_TO_OPTICAL: Final = (
    (0.1, -0.02, 0.4),
    tuple(Rotation.from_euler("xz", [-90, -90], degrees=True).as_quat()),
)
"""``base_link -> camera_color_optical_frame``: 0.4 m up, the optical axes turned from the body's."""


def _matrix(xyz: Sequence[float], xyzw: Sequence[float]) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(xyzw).as_matrix()
    T[:3, 3] = xyz
    return T


def _xyz_xyzw(T: np.ndarray) -> tuple[Vector, Vector]:
    x, y, z = T[:3, 3]
    qx, qy, qz, qw = Rotation.from_matrix(T[:3, :3]).as_quat()
    return (float(x), float(y), float(z)), (float(qx), float(qy), float(qz), float(qw))


def robot_messages(
    frames: Sequence[Frame],
    *,
    rgb: str = "/camera/color/image_raw",
    frame: str = OPTICAL,
    world: str = "map",
    tf_lag_ns: int = 0,
    world_from_frames: np.ndarray | None = None,
) -> list[Stamped]:
    """``frames`` as a robot records them, in log-time order: ``world -> base_link`` on /tf
    (each logged ``tf_lag_ns`` after its stamp), ``base_link -> frame`` on /tf_static,
    colour (rgb8), depth (16UC1 mm) and camera info at each view. ``world_from_frames``:
    where the frames' own world lies in ``world`` (a run localised in another map);
    identity if None."""
    mount = _matrix(*BASE_TO_OPTICAL)
    offset = np.eye(4) if world_from_frames is None else np.asarray(world_from_frames)
    t0 = frames[0].stamp_ns
    msgs: list[Stamped] = [("/tf_static", t0, tf_msg(t0, "base_link", frame, *_xyz_xyzw(mount)))]
    for f in frames:
        t = f.stamp_ns
        base = offset @ f.cam_to_world @ np.linalg.inv(mount)
        info = camera_info_msg(t, f.K, f.width, f.height)
        info.header.frame_id = frame
        depth_mm = np.round(f.depth_m * 1000).astype(np.uint16)
        msgs += [
            ("/tf", t + tf_lag_ns, tf_msg(t, world, "base_link", *_xyz_xyzw(base))),
            ("/camera/color/camera_info", t, info),
            (rgb, t, image_msg(t, f.rgb, "rgb8", frame)),
            ("/camera/depth/image_raw", t, image_msg(t, depth_mm, "16UC1", frame)),
        ]
    msgs.sort(key=lambda m: m[1])
    return msgs
