"""Goals a robot stack can use as they are: the frame they are in, and the static transform
to publish where that frame is not in the recording's TF tree.

Checked against independent references: the TransformStamped and PoseStamped JSON are built
into real ROS 2 messages by rosbags' typestore (so every field name and type is the message
definition's) and serialised; the published transform composed with the map-frame goal by
hand with scipy's rotations gives the world-frame goal; the static_transform_publisher
command is read back with the flags of tf2_ros (ROS 2 Humble and later)."""

from __future__ import annotations

import shlex

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from care_maps.core.mapframe import MapFrame, map_from_up
from care_maps.query.goals import GoalConfig, GoalMaker
from care_maps.query.map import CandidateMap
from care_maps.query.publish import (
    MAP_FRAME_ID,
    frame_plan,
    map_server_command,
    static_transform_command,
    transform_stamped,
)

STORE = get_typestore(Stores.ROS2_HUMBLE)


def _message(msgtype: str, data: dict):
    """``data`` as a ROS 2 message of ``msgtype``: a field it lacks or misnames fails here."""
    cls = STORE.types[msgtype]
    fields = {}
    for name, value in data.items():
        inner = STORE.fielddefs[msgtype][1]
        kind = dict(inner)[name]
        if isinstance(value, dict):
            sub = kind[1][0] if isinstance(kind[1], tuple) else kind[1]
            fields[name] = _message(sub, value)
        else:
            fields[name] = value
    assert set(fields) == {n for n, _ in STORE.fielddefs[msgtype][1]}, msgtype
    return cls(**fields)


def _matrix(translation: dict, rotation: dict) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat([rotation[k] for k in "xyzw"]).as_matrix()
    out[:3, 3] = [translation[k] for k in "xyz"]
    return out


Y_DOWN = MapFrame(
    map_from_up(np.array([0.0, -1.0, 0.0]), -1.3), (0.0, -1.0, 0.0), -1.3, "floor plane"
)
"""A SLAM world with y down (the first camera's frame), the floor 1.3 m below the camera."""
Z_UP = MapFrame(map_from_up(np.array([0.0, 0.0, 1.0]), 0.4), (0.0, 0.0, 1.0), 0.4, "floor plane")
"""A REP 105 world (z up) whose floor lies at z = 0.4."""


def _one_candidate_map(position) -> CandidateMap:
    return CandidateMap(
        kind="grid", vocabulary=("chair",), text=np.ones((1, 2), np.float32), logit_scale=1.0,
        features=np.ones((1, 2), np.float32), log_norm=np.zeros(1, np.float32),
        top_classes=np.zeros((1, 1), np.int16), entropy=np.zeros(1, np.float32),
        stderr=np.zeros(1, np.float32), pwkl=np.zeros(1, np.float32),
        num_views=np.ones(1, np.int32), positions=np.array([position], np.float64),
    )  # fmt: skip


def test_a_z_up_world_gets_its_goals_in_the_world_frame() -> None:
    plan = frame_plan(Z_UP, "odom")
    assert (plan.frame_id, plan.publish) == ("odom", False)
    maker = GoalMaker(
        "odom", 7, None, GoalConfig(), None, "odom", np.linalg.inv(Z_UP.map_from_world)
    )
    goal = maker.goal(_one_candidate_map((1.5, -2.0, 0.3)), 0)
    pose = goal.pose_stamped()
    assert pose["header"]["frame_id"] == "odom"
    position = pose["pose"]["position"]
    assert (position["x"], position["y"]) == pytest.approx((1.5, -2.0))
    assert position["z"] == pytest.approx(0.3 + 0.4)  # map z above the floor, floor at 0.4
    _message("geometry_msgs/msg/PoseStamped", pose)


def test_a_y_down_world_publishes_the_map_frame_and_the_goal_composes() -> None:
    plan = frame_plan(Y_DOWN, "camera_init")
    assert (plan.frame_id, plan.world_frame, plan.publish) == (MAP_FRAME_ID, "camera_init", True)
    tf = transform_stamped(plan, stamp_ns=1_700_000_000_250_000_000)
    _message("geometry_msgs/msg/TransformStamped", tf)
    assert tf["header"]["frame_id"] == "camera_init"
    assert tf["child_frame_id"] == MAP_FRAME_ID
    assert tf["header"]["stamp"] == {"sec": 1_700_000_000, "nanosec": 250_000_000}
    world_from_map = _matrix(tf["transform"]["translation"], tf["transform"]["rotation"])
    # the map's up (+z) is the world's -y, and the map's floor lies 1.3 m along it
    np.testing.assert_allclose(world_from_map[:3, 2], [0.0, -1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(world_from_map @ [0, 0, 0, 1.0], [0, 1.3, 0, 1], atol=1e-12)

    maker = GoalMaker(MAP_FRAME_ID, 7, None, GoalConfig(), Y_DOWN.map_from_world, "camera_init")
    goal = maker.goal(_one_candidate_map((2.0, 1.0, 0.5)), 0)
    in_map = goal.pose_stamped()
    in_world = goal.as_dict()["world_pose_stamped"]
    assert in_map["header"]["frame_id"] == MAP_FRAME_ID
    assert in_world["header"]["frame_id"] == "camera_init"
    composed = world_from_map @ _matrix(in_map["pose"]["position"], in_map["pose"]["orientation"])
    want = _matrix(in_world["pose"]["position"], in_world["pose"]["orientation"])
    np.testing.assert_allclose(composed, want, atol=1e-9)


def test_the_static_transform_command_publishes_the_same_transform() -> None:
    plan = frame_plan(Y_DOWN, "camera_init", "semantic_map")
    words = shlex.split(static_transform_command(plan))
    assert words[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
    flags = dict(zip(words[4::2], words[5::2], strict=True))
    assert flags["--frame-id"] == "camera_init"
    assert flags["--child-frame-id"] == "semantic_map"
    tf = transform_stamped(plan)["transform"]
    t, q = tf["translation"], tf["rotation"]
    for key, value in (*t.items(), *(("q" + k, v) for k, v in q.items())):
        assert float(flags[f"--{key}"]) == pytest.approx(value, abs=1e-8)
    served = shlex.split(map_server_command("my maps/map.yaml", plan))
    assert "yaml_filename:=my maps/map.yaml" in served
    assert "frame_id:=semantic_map" in served


def test_naming_the_world_frame_gives_world_goals_even_where_it_is_tilted() -> None:
    plan = frame_plan(Y_DOWN, "camera_init", "camera_init")
    assert (plan.frame_id, plan.publish) == ("camera_init", False)
    plan = frame_plan(Z_UP, "odom", "care_map")
    assert plan.publish
    np.testing.assert_allclose(plan.world_from_frame, np.linalg.inv(Z_UP.map_from_world))


def test_batch_answers_name_their_goal_frame_and_give_the_world_goal() -> None:
    """A batch table's goal columns are in the goal frame its metadata names; composing the
    metadata's transform with a row's goal gives the goal's world-frame pose."""
    import json

    from care_maps.core.keys import GOAL_FRAME_KEY
    from care_maps.replan.batch import BatchConfig, BatchQuery, plan_batch

    maker = GoalMaker(MAP_FRAME_ID, 7, None, GoalConfig(), Y_DOWN.map_from_world, "camera_init")
    cmap = _one_candidate_map((2.0, 1.0, 0.5))
    table = plan_batch(cmap, [BatchQuery("chair")], BatchConfig(), goals=maker)
    frame = json.loads(table.schema.metadata[GOAL_FRAME_KEY])
    assert (frame["frame_id"], frame["world_frame"]) == (MAP_FRAME_ID, "camera_init")
    world_from_frame = np.asarray(frame["world_from_frame"]).reshape(4, 4)
    row = table.slice(0, 1).to_pylist()[0]
    goal = np.eye(4)
    yaw = row["goal_yaw"]
    goal[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    # an approach point is on the floor; without one the goal is the object itself
    goal[:3, 3] = [row["goal_x"], row["goal_y"], 0.0 if row["goal_approach"] else row["z"]]
    world = maker.goal(cmap, 0).as_dict()["world_pose_stamped"]["pose"]
    want = _matrix(world["position"], world["orientation"])
    np.testing.assert_allclose(world_from_frame @ goal, want, atol=1e-9)
