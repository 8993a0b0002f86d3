"""Write frames as a real robot recording: MCAP, rosbag2 (sqlite3 or mcap storage) or ROS 1.

Used by the sample world (its bundled recording) and by the tests, which round-trip real
data through every container format with the libraries a robot would use (``mcap`` for
single MCAP files, ``rosbags`` for bags), so ingest is tested against files it did not
write itself in spirit: every byte goes through the third-party serialisers.

Layout of a written recording (ROS conventions):

- ``/camera/color/image_raw`` sensor_msgs/Image ``rgb8`` (or ``.../compressed`` JPEG),
- ``/camera/depth/image_raw`` sensor_msgs/Image ``16UC1`` millimetres, registered to colour,
- ``/camera/color/camera_info`` sensor_msgs/CameraInfo (plumb_bob, zero distortion),
- ``/tf`` tf2_msgs/TFMessage ``map -> base_link`` per frame,
- ``/tf_static`` ``base_link -> camera_optical_frame`` once (latched / transient local),
- ``/camera/instance`` and ``/camera/class`` ``16UC1`` label images when frames carry them,
- ``/care/class_names`` std_msgs/String, a JSON list, once, when label names are given.

The camera frame is optical (x right, y down, z forward), so ``map -> base_link`` is
``cam_to_world @ inv(base_to_camera)``.
"""

from __future__ import annotations

import io
import json
import os
import shutil
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from PIL import Image

from care_maps.core.errors import IngestError
from care_maps.core.frames import DEFAULT_CAMERA_FRAME, DEFAULT_WORLD_FRAME, Frame
from care_maps.ingest.formats import RecordingFormat
from care_maps.ingest.typestores import ros1_typestore, ros2_typestore

if TYPE_CHECKING:
    from rosbags.typesys.store import Msg

__all__ = [
    "BASE_FRAME",
    "CAMERA_FRAME",
    "DEFAULT_BASE_TO_CAMERA",
    "TOPICS",
    "WORLD_FRAME",
    "write_recording",
]

WORLD_FRAME = DEFAULT_WORLD_FRAME
BASE_FRAME = "base_link"
CAMERA_FRAME = DEFAULT_CAMERA_FRAME

TOPICS = {
    "rgb": "/camera/color/image_raw",
    "rgb_compressed": "/camera/color/image_raw/compressed",
    "depth": "/camera/depth/image_raw",
    "camera_info": "/camera/color/camera_info",
    "tf": "/tf",
    "tf_static": "/tf_static",
    "instance": "/camera/instance",
    "class": "/camera/class",
    "class_names": "/care/class_names",
}
"""Topic names of recordings written here (and what ingest auto-detects first)."""

_OPTICAL_FROM_BASE_AXES = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""Columns: the optical x (right), y (down), z (forward) axes in a REP-103 base frame."""

DEFAULT_BASE_TO_CAMERA = np.eye(4)
DEFAULT_BASE_TO_CAMERA[:3, :3] = _OPTICAL_FROM_BASE_AXES
DEFAULT_BASE_TO_CAMERA[:3, 3] = (0.2, 0.0, 1.0)
"""A realistic static mount: camera 0.2 m ahead of and 1.0 m above base_link, looking forward."""


def write_recording(
    path: Path,
    frames: Iterable[Frame],
    *,
    fmt: RecordingFormat | str,
    compressed_rgb: bool = False,
    base_to_camera: np.ndarray | None = None,
    label_names: Sequence[str] = (),
    depth_offset_ns: int = 0,
    ros2_storage: Literal["sqlite3", "mcap"] = "sqlite3",
) -> Path:
    """Stream ``frames`` into a new recording at ``path`` and return ``path``.

    Args:
        path: ``.mcap`` file (:attr:`RecordingFormat.MCAP`), rosbag2 directory (``ROS2``)
            or ``.bag`` (``ROS1``).
            Written to a temporary sibling and renamed at the end; an existing path is replaced.
        frames: synchronised frames; each is serialised and written as it arrives.
        fmt: container format.
        compressed_rgb: JPEG CompressedImage instead of a raw rgb8 Image.
        base_to_camera: static 4x4 ``base_link -> camera_optical_frame``; default
            :data:`DEFAULT_BASE_TO_CAMERA`.
        label_names: class names indexed by the ``class`` image, written as a JSON list.
        depth_offset_ns: depth stamp = colour stamp + offset (to test stamp matching).
        ros2_storage: storage plugin of a rosbag2 directory.
    """
    path = Path(path)
    if fmt not in set(RecordingFormat):
        msg = f"write_recording: unknown format {fmt!r}; choose {RecordingFormat.choices()}"
        raise IngestError(msg)
    mount = DEFAULT_BASE_TO_CAMERA if base_to_camera is None else np.asarray(base_to_camera)
    # A temporary sibling directory holding a file of the final name: rosbag2 names its
    # storage file after the bag directory, so the bag must be written under its own name.
    tmp_dir = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    _remove(tmp_dir)
    tmp_dir.mkdir(parents=True)
    tmp = tmp_dir / path.name
    try:
        sink = _make_sink(RecordingFormat(fmt), tmp, ros2_storage)
        try:
            _write_frames(sink, frames, mount, compressed_rgb, tuple(label_names), depth_offset_ns)
        except BaseException:
            sink.abort()
            raise
        sink.close()
        _remove(path)
        tmp.rename(path)
    finally:
        _remove(tmp_dir)
    return path


def _remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)


class _Sink:
    """One container format: named connections, serialised messages in, a file out."""

    ros1 = False

    def __init__(self) -> None:
        self.store = ros1_typestore() if self.ros1 else ros2_typestore()
        self.types = self.store.types
        self._conns: dict[str, Any] = {}

    def write(self, topic: str, msgtype: str, t_ns: int, msg: object) -> None:
        if topic not in self._conns:
            self._conns[topic] = self.connect(topic, msgtype)
        if self.ros1:
            data = self.store.serialize_ros1(msg, msgtype)
        else:
            data = self.store.serialize_cdr(msg, msgtype)
        self.put(self._conns[topic], t_ns, bytes(data))

    def connect(self, topic: str, msgtype: str) -> Any:
        raise NotImplementedError

    def put(self, conn: Any, t_ns: int, data: bytes) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def abort(self) -> None:
        """Best-effort release of open handles after a failure."""
        try:
            self.close()
        except Exception:  # the original error is what matters
            return


class _McapSink(_Sink):
    """A single MCAP file with ROS 2 CDR messages and ``ros2msg`` schemas (rerun reads it)."""

    def __init__(self, path: Path) -> None:
        from mcap.writer import Writer

        super().__init__()
        self._file = path.open("wb")
        self._writer = Writer(self._file)
        self._writer.start(profile="ros2", library="care-maps")
        self._schemas: dict[str, int] = {}

    def connect(self, topic: str, msgtype: str) -> int:
        if msgtype not in self._schemas:
            msgdef, _ = self.store.generate_msgdef(msgtype, ros_version=2)
            self._schemas[msgtype] = self._writer.register_schema(
                name=msgtype, encoding="ros2msg", data=msgdef.encode()
            )
        metadata = {}
        if topic == TOPICS["tf_static"]:
            metadata["offered_qos_profiles"] = _TRANSIENT_LOCAL_YAML
        return self._writer.register_channel(
            topic=topic, message_encoding="cdr", schema_id=self._schemas[msgtype], metadata=metadata
        )

    def put(self, conn: int, t_ns: int, data: bytes) -> None:
        self._writer.add_message(channel_id=conn, log_time=t_ns, data=data, publish_time=t_ns)

    def close(self) -> None:
        if not self._file.closed:
            try:
                self._writer.finish()
            finally:
                self._file.close()


_TRANSIENT_LOCAL_YAML = (
    "- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n"
    "  deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n"
    "  liveliness: 1\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n"
    "  avoid_ros_namespace_conventions: false"
)


class _Rosbag2Sink(_Sink):
    """A rosbag2 directory through ``rosbags.rosbag2.Writer``."""

    def __init__(self, path: Path, storage: str) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        super().__init__()
        plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}.get(storage)
        if plugin is None:
            msg = f"write_recording: unknown rosbag2 storage {storage!r}; choose sqlite3 or mcap"
            raise IngestError(msg)
        self._writer = Writer(path, version=Writer.VERSION_LATEST, storage_plugin=plugin)
        self._writer.open()
        self._open = True

    def connect(self, topic: str, msgtype: str) -> Any:
        qos = [_latched_qos()] if topic == TOPICS["tf_static"] else []
        return self._writer.add_connection(
            topic, msgtype, typestore=self.store, offered_qos_profiles=qos
        )

    def put(self, conn: Any, t_ns: int, data: bytes) -> None:
        self._writer.write(conn, t_ns, data)

    def close(self) -> None:
        if self._open:
            self._open = False
            self._writer.close()


def _latched_qos() -> Any:
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    zero = QosTime(0, 0)
    return Qos(
        QosHistory.KEEP_LAST,
        1,
        QosReliability.RELIABLE,
        QosDurability.TRANSIENT_LOCAL,
        zero,
        zero,
        QosLiveliness.AUTOMATIC,
        zero,
        False,
    )


class _Rosbag1Sink(_Sink):
    """A ROS 1 bag (v2.0) through ``rosbags.rosbag1.Writer``; /tf_static is latched."""

    ros1 = True

    def __init__(self, path: Path) -> None:
        from rosbags.rosbag1 import Writer

        super().__init__()
        self._writer = Writer(path)
        self._writer.open()
        self._open = True

    def connect(self, topic: str, msgtype: str) -> Any:
        latching = 1 if topic == TOPICS["tf_static"] else None
        return self._writer.add_connection(
            topic, msgtype, typestore=self.store, callerid="/care_maps", latching=latching
        )

    def put(self, conn: Any, t_ns: int, data: bytes) -> None:
        self._writer.write(conn, t_ns, data)

    def close(self) -> None:
        if self._open:
            self._open = False
            self._writer.close()


def _make_sink(fmt: RecordingFormat, path: Path, ros2_storage: str) -> _Sink:
    if fmt is RecordingFormat.MCAP:
        return _McapSink(path)
    if fmt is RecordingFormat.ROS2:
        return _Rosbag2Sink(path, ros2_storage)
    return _Rosbag1Sink(path)


class _Messages:
    """Builds typestore message objects, hiding the ROS 1 / ROS 2 field differences."""

    def __init__(self, sink: _Sink) -> None:
        self.t = sink.types
        self.ros1 = sink.ros1
        self._seq = 0

    def header(self, t_ns: int, frame_id: str) -> Msg:
        stamp = self.t["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        if self.ros1:
            self._seq += 1
            return self.t["std_msgs/msg/Header"](seq=self._seq, stamp=stamp, frame_id=frame_id)
        return self.t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def image(self, t_ns: int, array: np.ndarray, encoding: str) -> object:
        h, w = array.shape[:2]
        data = np.ascontiguousarray(array)
        return self.t["sensor_msgs/msg/Image"](
            header=self.header(t_ns, CAMERA_FRAME),
            height=h,
            width=w,
            encoding=encoding,
            is_bigendian=0,
            step=int(data.strides[0]),
            data=data.view(np.uint8).reshape(-1),
        )

    def compressed(self, t_ns: int, rgb: np.ndarray) -> object:
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="JPEG", quality=95)
        return self.t["sensor_msgs/msg/CompressedImage"](
            header=self.header(t_ns, CAMERA_FRAME),
            format="rgb8; jpeg compressed bgr8",
            data=np.frombuffer(buf.getvalue(), np.uint8),
        )

    def camera_info(self, t_ns: int, K: np.ndarray, w: int, h: int) -> object:
        K = np.asarray(K, np.float64)
        P = np.zeros((3, 4))
        P[:, :3] = K
        fields = {
            "D": np.zeros(5),
            "K": K.ravel().copy(),
            "R": np.eye(3).ravel(),
            "P": P.ravel(),
        }
        if not self.ros1:
            fields = {k.lower(): v for k, v in fields.items()}
        roi = self.t["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        return self.t["sensor_msgs/msg/CameraInfo"](
            header=self.header(t_ns, CAMERA_FRAME),
            height=h,
            width=w,
            distortion_model="plumb_bob",
            binning_x=0,
            binning_y=0,
            roi=roi,
            **fields,
        )

    def tf(self, t_ns: int, parent: str, child: str, T: np.ndarray) -> object:
        from care_maps.geometry.transforms import matrix_to_quaternion

        q = matrix_to_quaternion(np.asarray(T)[:3, :3])
        x, y, z = (float(v) for v in np.asarray(T)[:3, 3])
        transform = self.t["geometry_msgs/msg/Transform"](
            translation=self.t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
            rotation=self.t["geometry_msgs/msg/Quaternion"](
                x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])
            ),
        )
        stamped = self.t["geometry_msgs/msg/TransformStamped"](
            header=self.header(t_ns, parent), child_frame_id=child, transform=transform
        )
        return self.t["tf2_msgs/msg/TFMessage"](transforms=[stamped])

    def string(self, text: str) -> object:
        return self.t["std_msgs/msg/String"](data=text)


def _depth_mm(depth_m: np.ndarray) -> np.ndarray:
    d = np.nan_to_num(np.asarray(depth_m, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return np.clip(np.round(d * 1000.0), 0, 65535).astype(np.uint16)


def _write_frames(
    sink: _Sink,
    frames: Iterable[Frame],
    mount: np.ndarray,
    compressed_rgb: bool,
    label_names: tuple[str, ...],
    depth_offset_ns: int,
) -> None:
    m = _Messages(sink)
    base_from_camera_inv = np.linalg.inv(mount)
    first = True
    write: Callable[[str, str, int, object], None] = sink.write
    for frame in frames:
        t = int(frame.stamp_ns)
        if first:
            first = False
            write(
                TOPICS["tf_static"],
                "tf2_msgs/msg/TFMessage",
                t,
                m.tf(t, BASE_FRAME, CAMERA_FRAME, mount),
            )
            if label_names:
                write(
                    TOPICS["class_names"],
                    "std_msgs/msg/String",
                    t,
                    m.string(json.dumps(list(label_names))),
                )
        map_from_base = np.asarray(frame.cam_to_world, np.float64) @ base_from_camera_inv
        write(
            TOPICS["tf"],
            "tf2_msgs/msg/TFMessage",
            t,
            m.tf(t, WORLD_FRAME, BASE_FRAME, map_from_base),
        )
        write(
            TOPICS["camera_info"],
            "sensor_msgs/msg/CameraInfo",
            t,
            m.camera_info(t, frame.K, frame.width, frame.height),
        )
        if compressed_rgb:
            write(
                TOPICS["rgb_compressed"],
                "sensor_msgs/msg/CompressedImage",
                t,
                m.compressed(t, frame.rgb),
            )
        else:
            write(TOPICS["rgb"], "sensor_msgs/msg/Image", t, m.image(t, frame.rgb, "rgb8"))
        td = t + int(depth_offset_ns)
        write(
            TOPICS["depth"],
            "sensor_msgs/msg/Image",
            td,
            m.image(td, _depth_mm(frame.depth_m), "16UC1"),
        )
        for name in ("instance", "class"):
            extra = frame.extras.get(name)
            if extra is not None:
                write(
                    TOPICS[name],
                    "sensor_msgs/msg/Image",
                    t,
                    m.image(t, extra.astype(np.uint16), "16UC1"),
                )
