"""Which topics of a recording hold colour, depth, camera info, poses and labels.

Auto-detection goes by message type first and topic name second (the names RealSense,
Azure Kinect, ZED and our own writer use); every choice can be overridden with a flag.
The choice is a :class:`TopicSelection`, shown by ``care topics REC`` and recorded in the
store's meta.json.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from care_maps.core.errors import IngestError
from care_maps.ingest.readers import TopicInfo

__all__ = [
    "CAMERA_INFO_TYPES",
    "IMAGE_TYPES",
    "POSE_TYPES",
    "TF_TYPES",
    "TopicSelection",
    "depth_camera_info",
    "pose_topics",
    "registered_depth_topics",
    "select_topics",
]

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
CAMERA_INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
POSE_TYPES = ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped")
STRING_TYPE = "std_msgs/msg/String"

_DEPTH_WORDS = ("depth",)
_NOT_COLOUR_WORDS = (
    "depth",
    "instance",
    "class",
    "label",
    "mask",
    "infra",
    "/ir",
    "disparity",
    "confidence",
    "segment",
)
_COLOUR_WORDS = ("color", "colour", "rgb")
_EXTRA_SUFFIXES = {"instance": "/instance", "class": "/class"}
_CLASS_NAMES_SUFFIX = "/class_names"


@dataclass(frozen=True)
class TopicSelection:
    """The topics ingest reads (None where a role has no topic)."""

    rgb: str
    depth: str
    camera_info: str | None
    """None where the intrinsics are given (``--intrinsics``) instead."""
    tf: tuple[str, ...] = ()
    """TF topics; those named ``*tf_static`` are static (latched), and so is a transform
    on the others whose samples never change (:meth:`care_maps.ingest.tf.TFBuffer.freeze_unchanging`)."""
    pose_source: str | None = None
    """An Odometry or PoseStamped topic giving the pose, instead of or on top of TF."""
    extras: dict[str, str] = field(default_factory=dict)
    """Label images by extras key (``instance``, ``class``) of sample-world recordings."""
    class_names: str | None = None
    """std_msgs/String with a JSON list of class names indexing the ``class`` image."""

    def as_dict(self) -> dict[str, object]:
        return {
            "rgb": self.rgb,
            "depth": self.depth,
            "camera_info": self.camera_info,
            "tf": list(self.tf),
            "pose_source": self.pose_source,
            "extras": dict(self.extras),
            "class_names": self.class_names,
        }


def _listing(topics: Mapping[str, TopicInfo]) -> str:
    return ", ".join(f"{t.name} ({t.msgtype}, {t.count} msgs)" for t in topics.values()) or "none"


def _common_prefix(a: str, b: str) -> int:
    """Number of leading topic-name components two topics share."""
    n = 0
    for x, y in zip(a.strip("/").split("/"), b.strip("/").split("/"), strict=False):
        if x != y:
            break
        n += 1
    return n


def _colour_score(t: TopicInfo) -> tuple[int, ...]:
    name = t.name.lower()
    return (
        any(w in name for w in _COLOUR_WORDS),
        t.msgtype == IMAGE_TYPES[0],  # raw before compressed: lossless
        "rect" in name,
        t.count,
    )


def _depth_score(t: TopicInfo, rgb: str) -> tuple[int, ...]:
    name = t.name.lower()
    return (
        "aligned" in name or "registered" in name,  # registered to colour
        t.msgtype == IMAGE_TYPES[0],
        _common_prefix(name, rgb.lower()),
        t.count,
    )


def _check(
    topics: Mapping[str, TopicInfo], name: str, types: tuple[str, ...], flag: str, path: str
) -> str:
    info = topics.get(name)
    if info is None:
        msg = f"{path}: {flag} {name}: no such topic; topics present: {_listing(topics)}."
        raise IngestError(msg)
    if info.msgtype not in types:
        msg = f"{path}: {flag} {name} has type {info.msgtype}, expected {' or '.join(types)}; pick a topic of that type."
        raise IngestError(msg)
    return name


def _pick_rgb(topics: Mapping[str, TopicInfo], path: str) -> str:
    images = [t for t in topics.values() if t.msgtype in IMAGE_TYPES]
    if not images:
        msg = f"{path}: no image topic (sensor_msgs/Image or CompressedImage); topics present: {_listing(topics)}. Record the camera, or pass --rgb TOPIC."
        raise IngestError(msg)
    colour = [t for t in images if not any(w in t.name.lower() for w in _NOT_COLOUR_WORDS)]
    if not colour:
        msg = f"{path}: no colour image topic among the image topics {', '.join(t.name for t in images)} (they look like depth or labels); pass --rgb TOPIC."
        raise IngestError(msg)
    return max(colour, key=_colour_score).name


def _pick_depth(topics: Mapping[str, TopicInfo], rgb: str, path: str) -> str:
    depth = [
        t
        for t in topics.values()
        if t.msgtype in IMAGE_TYPES
        and t.name != rgb
        and any(w in t.name.lower() for w in _DEPTH_WORDS)
    ]
    if not depth:
        msg = f"{path}: no depth image topic (an Image or CompressedImage topic named *depth*); topics present: {_listing(topics)}. Pass --depth TOPIC."
        raise IngestError(msg)
    return max(depth, key=lambda t: _depth_score(t, rgb)).name


def _pick_camera_info(topics: Mapping[str, TopicInfo], rgb: str, path: str) -> str:
    infos = [t for t in topics.values() if t.msgtype in CAMERA_INFO_TYPES]
    if not infos:
        msg = f"{path}: no camera info topic (sensor_msgs/CameraInfo) for {rgb}; topics present: {_listing(topics)}. Record camera_info, pass --camera-info TOPIC, or give the intrinsics with --intrinsics fx,fy,cx,cy (or a camera_info YAML)."
        raise IngestError(msg)
    # The info beside the colour image: longest common prefix, then not a depth camera's.
    return max(
        infos,
        key=lambda t: (_common_prefix(t.name, rgb), "depth" not in t.name.lower(), t.count),
    ).name


def select_topics(
    topics: Mapping[str, TopicInfo],
    *,
    path: str = "recording",
    rgb: str | None = None,
    depth: str | None = None,
    camera_info: str | None = None,
    pose_source: str | None = None,
    intrinsics: bool = False,
) -> TopicSelection:
    """Auto-detect each role's topic unless its override is given (then check it exists);
    with ``intrinsics`` given, no camera info topic is read."""
    rgb = _check(topics, rgb, IMAGE_TYPES, "--rgb", path) if rgb else _pick_rgb(topics, path)
    depth = (
        _check(topics, depth, IMAGE_TYPES, "--depth", path)
        if depth
        else _pick_depth(topics, rgb, path)
    )
    if camera_info:
        camera_info = _check(topics, camera_info, CAMERA_INFO_TYPES, "--camera-info", path)
    elif not intrinsics:
        camera_info = _pick_camera_info(topics, rgb, path)
    if pose_source:
        _check(topics, pose_source, POSE_TYPES, "--pose-source", path)
    tf = tuple(sorted(t.name for t in topics.values() if t.msgtype in TF_TYPES and t.count > 0))
    moving_tf = [name for name in tf if not name.rstrip("/").endswith("tf_static")]
    if not moving_tf and not pose_source and (candidates := pose_topics(topics)):
        # TF holds no moving transform (none at all, or only the static chain of a robot
        # whose motion is on nav_msgs/Odometry, REP 105): the pose topic is what moves;
        # the static chain places the camera on the body it moves
        pose_source = candidates[0]
    extras = {
        key: t.name
        for key, suffix in _EXTRA_SUFFIXES.items()
        for t in topics.values()
        if t.msgtype == IMAGE_TYPES[0] and t.name.endswith(suffix)
    }
    class_names = next(
        (
            t.name
            for t in topics.values()
            if t.msgtype == STRING_TYPE and t.name.endswith(_CLASS_NAMES_SUFFIX)
        ),
        None,
    )
    return TopicSelection(rgb, depth, camera_info, tf, pose_source, extras, class_names)


def depth_camera_info(topics: Mapping[str, TopicInfo], sel: TopicSelection) -> str | None:
    """The depth sensor's own camera info, where the depth topic has one: the CameraInfo
    topic, other than the colour camera's, that shares more of its name with the depth topic
    than with the colour topic (``/camera/depth/camera_info`` beside
    ``/camera/depth/image_raw``; an ``aligned_depth_to_color`` topic's info is the colour
    camera's and so matches it)."""
    own = [
        t
        for t in topics.values()
        if t.msgtype in CAMERA_INFO_TYPES
        and t.name != sel.camera_info
        and _common_prefix(t.name, sel.depth) > _common_prefix(t.name, sel.rgb)
    ]
    if not own:
        return None
    return max(own, key=lambda t: (_common_prefix(t.name, sel.depth), t.count)).name


def registered_depth_topics(topics: Mapping[str, TopicInfo], rgb: str) -> list[str]:
    """Depth image topics whose names say they are registered to the colour camera."""
    return sorted(
        t.name
        for t in topics.values()
        if t.msgtype in IMAGE_TYPES
        and t.name != rgb
        and any(w in t.name.lower() for w in ("aligned", "registered"))
    )


def pose_topics(topics: Mapping[str, TopicInfo]) -> list[str]:
    """Odometry / PoseStamped topics with messages, candidates for ``--pose-source``:
    Odometry first (a robot's motion estimate), then by message count."""
    found = [t for t in topics.values() if t.msgtype in POSE_TYPES and t.count > 0]
    found.sort(key=lambda t: (POSE_TYPES.index(t.msgtype), -t.count, t.name))
    return [t.name for t in found]
