"""The rosbags type stores the writer and the readers share.

ROS 2 recordings (MCAP, rosbag2) use the Humble store; ROS 1 bags the Noetic store, which
lacks ``tf2_msgs/msg/TFMessage`` (ROS 1 TF moved to tf2_msgs in Indigo, but rosbags only
ships the ``tf`` package's definition), so we register it here once. Types a recording
carries that a store does not know are added from the recording's own definitions by the
readers (:func:`register_msgdef`). rosbags is imported when a store is first asked for
(0.01 s): the CLI's start and a query read no recording.
"""

from __future__ import annotations

from functools import cache
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = ["register_msgdef", "ros1_typestore", "ros2_typestore"]

_TF_MESSAGE_MSG = "geometry_msgs/TransformStamped[] transforms\n"


@cache
def ros2_typestore() -> Typestore:
    """ROS 2 Humble message types (shared, extended in place by :func:`register_msgdef`)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


@cache
def ros1_typestore() -> Typestore:
    """ROS 1 Noetic message types plus ``tf2_msgs/msg/TFMessage``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    if "tf2_msgs/msg/TFMessage" not in store.fielddefs:
        store.register(get_types_from_msg(_TF_MESSAGE_MSG, "tf2_msgs/msg/TFMessage"))
    return store


def register_msgdef(store: Typestore, msgtype: str, msgdef: str, fmt: str = "msg") -> bool:
    """Teach ``store`` a message type from a recording's embedded definition.

    Returns False when the definition cannot be parsed; the topic is then listed but its
    messages cannot be decoded (which is fine unless ingest needs that topic).
    """
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    if msgtype in store.fielddefs:
        return True
    try:
        types = get_types_from_idl(msgdef) if fmt == "idl" else get_types_from_msg(msgdef, msgtype)
        store.register(types)
    except Exception:  # any parse failure means "cannot decode this topic"
        return False
    return msgtype in store.fielddefs
