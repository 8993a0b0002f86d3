"""Fixtures of the ingest tests: synthetic frames, real RGB-D data, hand-built bags, a CLI runner.

Hand-built bags go through ``rosbags.rosbag2.Writer`` (a real writer) with messages
made here, independently of ``care_maps.ingest.write``, to test encodings and broken recordings
that our own writer never produces.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from care_maps.core.encoders import Encoder, l2_normalise
from care_maps.core.frames import Frame
from care_maps.geometry.transforms import quaternion_to_matrix

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
K_SMALL = np.array([[40.0, 0.0, 16.0], [0.0, 40.0, 12.0], [0.0, 0.0, 1.0]])


def smooth_rgb(i: int, h: int = 24, w: int = 32) -> np.ndarray:
    u, v = np.meshgrid(np.arange(w) * 255 // w, np.arange(h) * 255 // h)
    return np.stack([u, v, np.full_like(u, (40 * i) % 256)], axis=-1).astype(np.uint8)


def synthetic_frames(
    n: int = 6, h: int = 24, w: int = 32, dt_ns: int = 100_000_000, extras: bool = False
) -> list[Frame]:
    """A camera sliding and turning in front of a tilted plane."""
    frames = []
    for i in range(n):
        pose = np.eye(4)
        angle = 0.05 * i
        pose[:3, :3] = quaternion_to_matrix(
            np.array([0.0, np.sin(angle / 2), 0.0, np.cos(angle / 2)])
        )
        pose[:3, 3] = [0.1 * i, -0.05 * i, 1.2]
        u = np.arange(w, dtype=np.float32)[None, :]
        depth = np.broadcast_to(1.5 + 0.01 * u + 0.02 * i, (h, w)).astype(np.float32).round(3)
        ex = {}
        if extras:
            ex = {
                "instance": (np.arange(h * w).reshape(h, w) % 7).astype(np.uint16),
                "class": np.full((h, w), 1 + i % 2, np.uint16),
            }
        frames.append(
            Frame(10**9 + i * dt_ns, smooth_rgb(i, h, w), depth, K_SMALL.copy(), pose, ex)
        )
    return frames


class TinyEncoder(Encoder):
    """A real (non-mock) encoder: per 4x4-pixel cell, the L2-normalised mean colour plus 1.

    Text side: a fixed colour per class name, so the test can check the cached embeddings.
    """

    name = "tiny"
    version = "1"
    dim = 4

    def __init__(self) -> None:
        self.prepared_with: tuple[str, ...] | None = None

    def prepare(self, context) -> None:
        self.prepared_with = context.label_names

    def encode_views(self, frames) -> np.ndarray:
        maps = []
        for f in frames:
            h, w = f.height // 4, f.width // 4
            cells = f.rgb[: h * 4, : w * 4].reshape(h, 4, w, 4, 3).mean(axis=(1, 3)) / 255.0
            maps.append(np.concatenate([cells, np.ones((h, w, 1))], axis=-1))
        return l2_normalise(np.asarray(maps, np.float32))

    def encode_text(self, names) -> np.ndarray:
        emb = np.array([[len(n), 1.0, 0.0, 1.0] for n in names], np.float32)
        return l2_normalise(emb)


# -- hand-built recordings ---------------------------------------------------------------


def header(t_ns: int, frame_id: str = "camera_optical_frame"):
    stamp = T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
    return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def image_msg(t_ns: int, array: np.ndarray, encoding: str, frame_id: str = "camera_optical_frame"):
    data = np.ascontiguousarray(array)
    return T["sensor_msgs/msg/Image"](
        header=header(t_ns, frame_id),
        height=data.shape[0],
        width=data.shape[1],
        encoding=encoding,
        is_bigendian=0,
        step=int(data.strides[0]),
        data=data.view(np.uint8).reshape(-1),
    )


def compressed_msg(t_ns: int, data: bytes, fmt: str):
    return T["sensor_msgs/msg/CompressedImage"](
        header=header(t_ns), format=fmt, data=np.frombuffer(data, np.uint8)
    )


def camera_info_msg(t_ns: int, K: np.ndarray, w: int, h: int):
    roi = T["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    P = np.zeros((3, 4))
    P[:, :3] = K
    return T["sensor_msgs/msg/CameraInfo"](
        header=header(t_ns),
        height=h,
        width=w,
        distortion_model="plumb_bob",
        d=np.zeros(5),
        k=np.asarray(K, np.float64).ravel(),
        r=np.eye(3).ravel(),
        p=P.ravel(),
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def tf_msg(t_ns: int, parent: str, child: str, xyz, quat_xyzw):
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


def odometry_msg(t_ns: int, T_parent_child: np.ndarray, parent: str, child: str):
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
    import io

    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


def jpeg_bytes(array: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="JPEG", quality=90)
    return buf.getvalue()


def write_bag(path: Path, messages: list[tuple[str, int, object]]) -> Path:
    """A rosbag2 (mcap storage) of ``(topic, t_ns, message)`` through rosbags' Writer."""
    conns: dict[str, object] = {}
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic, t, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=TS)
            writer.write(conns[topic], t, bytes(TS.serialize_cdr(msg, msg.__msgtype__)))
    return path


def rgbd_messages(
    rgb: Callable[[int, int], object] | None,
    depth: Callable[[int, int], object] | None,
    *,
    n: int = 3,
    info: bool = True,
    tf: bool = True,
    w: int = 32,
    h: int = 24,
) -> list[tuple[str, int, object]]:
    """Messages of a small RGB-D recording; ``rgb(i, t)``/``depth(i, t)`` build the images."""
    out: list[tuple[str, int, object]] = []
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


# -- real RGB-D data ---------------------------------------------------------------------


def load_livingroom(root: Path, count: int) -> list[Frame]:
    """The first ``count`` frames of livingroom1_clean_micro with their Redwood-log poses."""
    lines = (root / "trajectory.log").read_text().split("\n")
    poses = []
    for k in range(count):
        rows = lines[5 * k + 1 : 5 * k + 5]
        poses.append(np.array([[float(x) for x in r.split()] for r in rows]))
    K = (
        np.array(json.loads((root / "camera_intrinsic.json").read_text())["intrinsic_matrix"])
        .reshape(3, 3)
        .T
    )
    frames = []
    for k in range(count):
        rgb = np.asarray(Image.open(root / "image" / f"{k:05d}.jpg").convert("RGB"))
        depth = np.asarray(Image.open(root / "depth" / f"{k:05d}.png")).astype(np.float32) / 1000.0
        frames.append(Frame(10**9 + k * 33_333_333, rgb, depth, K, poses[k]))
    return frames


def load_slambook(root: Path) -> list[Frame]:
    """slambook's 5 Kinect frames, poses ``tx ty tz qx qy qz qw`` (camera to world)."""
    K = np.array([[518.0, 0.0, 325.5], [0.0, 519.0, 253.5], [0.0, 0.0, 1.0]])
    frames = []
    for k, line in enumerate((root / "pose.txt").read_text().split("\n")[:5], start=1):
        v = np.array([float(x) for x in line.split()])
        pose = np.eye(4)
        pose[:3, :3] = quaternion_to_matrix(v[3:])
        pose[:3, 3] = v[:3]
        rgb = np.asarray(Image.open(root / "color" / f"{k}.png").convert("RGB"))
        depth = np.asarray(Image.open(root / "depth" / f"{k}.pgm")).astype(np.float32) / 1000.0
        frames.append(Frame(10**9 + k * 100_000_000, rgb, depth, K, pose))
    return frames


@pytest.fixture(scope="session")
def livingroom_root(shared_data: Path) -> Path:
    return shared_data / "rgbd" / "livingroom1_clean_micro"


@pytest.fixture(scope="session")
def slambook_root(shared_data: Path) -> Path:
    return shared_data / "rgbd" / "slambook_kinect5"


def frames_iter(frames: list[Frame]) -> Iterator[Frame]:
    yield from frames


@pytest.fixture(scope="session")
def h() -> SimpleNamespace:
    """The helpers above, for test modules (conftest is not importable under importlib mode)."""
    return SimpleNamespace(
        K_SMALL=K_SMALL,
        TS=TS,
        T=T,
        smooth_rgb=smooth_rgb,
        synthetic_frames=synthetic_frames,
        TinyEncoder=TinyEncoder,
        header=header,
        image_msg=image_msg,
        compressed_msg=compressed_msg,
        camera_info_msg=camera_info_msg,
        tf_msg=tf_msg,
        odometry_msg=odometry_msg,
        png_bytes=png_bytes,
        jpeg_bytes=jpeg_bytes,
        write_bag=write_bag,
        rgbd_messages=rgbd_messages,
        load_livingroom=load_livingroom,
        load_slambook=load_slambook,
    )
