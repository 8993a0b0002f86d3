"""The frame goals and ``map.yaml`` are in, and what a robot stack must publish to use them.

A store's maps live in its gravity-aligned map frame (:class:`care_maps.core.mapframe.MapFrame`). A
navigation stack knows the recording's TF tree, in which that frame does not exist, so:

- when the map frame *is* the recording's world frame, or differs from it only by the
  floor's height (the world frame already has z up, REP 103/105: a ``map`` or ``odom``
  frame), goals and ``map.yaml`` are given in the world frame: x and y agree, and a 2-D
  goal or occupancy map needs no transform;
- otherwise (a SLAM or dataset world with y down, say) they are given in a frame of their
  own, ``care_map`` unless named, whose pose in the world frame is a static transform the
  user publishes: :func:`transform_stamped` (``geometry_msgs/TransformStamped`` JSON) and
  :func:`static_transform_command` (``tf2_ros static_transform_publisher``).

The map server publishes ``map.yaml`` in its ``frame_id`` parameter, so
:func:`map_server_command` names that too. Pure functions of the map frame: the CLI
(``care frame``) prints them.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from care_maps.core.frames import check_frame_id
from care_maps.core.mapframe import MapFrame
from care_maps.geometry.transforms import rotation_quaternion

__all__ = [
    "MAP_FRAME_ID",
    "FramePlan",
    "frame_plan",
    "map_server_command",
    "static_transform_command",
    "transform_stamped",
]

MAP_FRAME_ID = "care_map"
"""Default name of the map frame where it is not the recording's world frame."""


@dataclass(frozen=True)
class FramePlan:
    """Which frame goals and ``map.yaml`` are in, and whether it must be published."""

    frame_id: str
    """``header.frame_id`` of goals, the ``frame_id`` to serve ``map.yaml`` in."""
    world_frame: str
    """The recording's world frame (the TF parent of :attr:`frame_id` when published)."""
    world_from_frame: np.ndarray
    """(4, 4) pose of :attr:`frame_id` in the world frame."""
    publish: bool
    """:attr:`frame_id` is not in the recording's TF tree: publish :attr:`world_from_frame`
    as a static transform to use the goals and the map."""


def frame_plan(frame: MapFrame, world_frame: str, name: str | None = None) -> FramePlan:
    """Where goals go for a store with map frame ``frame`` and world ``world_frame``.

    ``name``: the frame a user wants the goals in. The world frame's own name gives goals in
    the world frame whatever it is (a 3-D pose where it is not z up); any other name is
    the map frame's, published under the world frame. Default: the world frame when it has
    z up, else :data:`MAP_FRAME_ID`.

    Both names go into the commands and goals a robot stack runs, so a name tf2 would reject
    is refused here (:func:`care_maps.core.frames.check_frame_id`), not printed for tf2 to refuse."""
    check_frame_id(world_frame)
    if name is not None:
        check_frame_id(name)
    aligned = frame.is_gravity_aligned
    if name is None:
        name = world_frame if aligned else MAP_FRAME_ID
    if name == world_frame:
        return FramePlan(world_frame, world_frame, np.eye(4), publish=False)
    return FramePlan(name, world_frame, np.linalg.inv(frame.map_from_world), publish=True)


def _translation_quaternion(matrix: np.ndarray) -> tuple[list[float], list[float]]:
    xyzw = rotation_quaternion(matrix[:3, :3])[0]
    return [float(v) for v in matrix[:3, 3]], [float(v) for v in xyzw]


def transform_stamped(plan: FramePlan, stamp_ns: int = 0) -> dict:
    """``geometry_msgs/TransformStamped`` JSON (ROS 2 field names): the map frame's pose in
    the world frame (``header.frame_id`` the parent, as TF has it)."""
    (x, y, z), (qx, qy, qz, qw) = _translation_quaternion(plan.world_from_frame)
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": plan.world_frame},
        "child_frame_id": plan.frame_id,
        "transform": {
            "translation": {"x": x, "y": y, "z": z},
            "rotation": {"x": qx, "y": qy, "z": qz, "w": qw},
        },
    }


def static_transform_command(plan: FramePlan) -> str:
    """The ROS 2 command that publishes :func:`transform_stamped` on ``/tf_static``."""
    (x, y, z), (qx, qy, qz, qw) = _translation_quaternion(plan.world_from_frame)
    values = {"x": x, "y": y, "z": z, "qx": qx, "qy": qy, "qz": qz, "qw": qw}
    args = " ".join(f"--{k} {v:.9g}" for k, v in values.items())
    return (
        f"ros2 run tf2_ros static_transform_publisher {args} "
        f"--frame-id {shlex.quote(plan.world_frame)} --child-frame-id {shlex.quote(plan.frame_id)}"
    )


def map_server_command(map_yaml: Path, plan: FramePlan) -> str:
    """The ROS 2 command that serves ``map_yaml`` in the plan's frame."""
    return (
        "ros2 run nav2_map_server map_server --ros-args "
        f"-p yaml_filename:={shlex.quote(str(map_yaml))} -p frame_id:={shlex.quote(plan.frame_id)}"
    )
