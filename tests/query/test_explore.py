"""Where to look again: the viewpoint chooser on hand-made floors (free space with clearance,
the most uncertain place first, views spread apart, N respected, deterministic, no view
through a wall), the uncertainty of hand-made maps, the camera and goal poses as real ROS 2
``geometry_msgs/PoseStamped`` messages (rosbags' typestore), and ``care explore`` end to
end on a small fused store without ground truth."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from scipy import ndimage

from care_maps.core.errors import QueryError
from care_maps.fuse.layout import GridLayout
from care_maps.query.explore import (
    ExploreConfig,
    Uncertainty,
    cell_uncertainty,
    choose_views,
    contested,
    look_at,
    object_cells,
    rank_scores,
)
from care_maps.query.explore_store import camera_pose_stamped
from care_maps.query.goals import FreeSpace, Goal
from care_maps.query.map import CandidateMap
from care_maps.query.paths import Roadmap

ROS = get_typestore(Stores.ROS2_HUMBLE)
CELL = 0.05
SHAPE = (120, 80)  # a 6 x 4 m floor
LAYOUT = GridLayout(CELL, (0.0, 0.0), SHAPE)
CLEARANCE = 0.2


def _floor(walls: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(obstacle, heights, stand) of a room with boxes at the places of :data:`PLACES`
    (0.5 m tall) and ``walls`` (2.5 m); stand: free cells keeping the clearance."""
    obstacle = np.zeros(SHAPE, bool) if walls is None else walls.copy()
    heights = np.where(obstacle, 2.5, 0.0)
    obstacle[[0, -1], :] = obstacle[:, [0, -1]] = True  # the room's walls
    heights[obstacle] = 2.5
    for x, y in PLACES:
        i, j = int(x / CELL), int(y / CELL)
        obstacle[i - 3 : i + 3, j - 3 : j + 3] = True
        heights[i - 3 : i + 3, j - 3 : j + 3] = 0.5
    ix, iy = (a.reshape(-1) for a in np.indices(SHAPE))
    space = FreeSpace.from_cells(LAYOUT, ix, iy, obstacle.reshape(-1))
    return obstacle, heights, Roadmap.from_free_space(space, CLEARANCE).passable


PLACES = ((1.5, 1.0), (4.5, 1.0), (1.5, 3.0), (4.5, 3.0))
"""Box centres (m)."""


def _interest(weights: tuple[float, ...]) -> np.ndarray:
    """Uncertainty on the boxes: ``weights[i]`` on the cells of box i."""
    interest = np.zeros(SHAPE)
    for (x, y), w in zip(PLACES, weights, strict=True):
        i, j = int(x / CELL), int(y / CELL)
        interest[i - 3 : i + 3, j - 3 : j + 3] = w
    return interest


def _centre(view) -> np.ndarray:
    return np.array(view.position)


def test_views_stand_in_free_space_and_look_at_the_most_uncertain_place_first() -> None:
    obstacle, heights, stand = _floor()
    config = ExploreConfig(views=3, spacing=1.0)
    views = choose_views(
        _interest((0.2, 1.0, 0.5, 0.0)), heights, stand, LAYOUT, camera_height=1.4, config=config
    )
    assert len(views) == 3
    clearance = ndimage.distance_transform_edt(~obstacle) * CELL
    for view in views:
        ix, iy = (int(v / CELL) for v in view.position)
        assert stand[ix, iy]
        assert clearance[ix, iy] >= CLEARANCE - 1e-9
        dist = math.dist(view.position, view.target[:2])
        assert config.min_range <= dist <= config.max_range
        assert view.yaw == pytest.approx(
            math.atan2(view.target[1] - view.position[1], view.target[0] - view.position[0])
        )
    targets = [min(range(4), key=lambda i: math.dist(PLACES[i], v.target[:2])) for v in views]
    assert targets == [1, 2, 0]  # by uncertainty; the box with none is never looked at
    assert all(
        math.dist(PLACES[t], v.target[:2]) < 0.3 for t, v in zip(targets, views, strict=True)
    )
    assert views[0].target[2] == pytest.approx(0.5)  # the box's top


def test_views_are_spread_apart_n_is_respected_and_the_choice_is_deterministic() -> None:
    _, heights, stand = _floor()
    interest = _interest((1.0, 1.0, 1.0, 1.0))
    config = ExploreConfig(views=4, spacing=1.5)
    views = choose_views(interest, heights, stand, LAYOUT, camera_height=1.4, config=config)
    assert len(views) == 4
    for a in range(4):
        for b in range(a):
            assert np.linalg.norm(_centre(views[a]) - _centre(views[b])) >= 1.5 - 1e-9
    again = choose_views(interest, heights, stand, LAYOUT, camera_height=1.4, config=config)
    assert [(v.position, v.yaw, v.target) for v in again] == [
        (v.position, v.yaw, v.target) for v in views
    ]
    for n in (1, 2):
        few = choose_views(
            interest, heights, stand, LAYOUT, camera_height=1.4,
            config=ExploreConfig(views=n, spacing=1.5),
        )  # fmt: skip
        assert len(few) == n
    one = choose_views(
        _interest((0.0, 1.0, 0.0, 0.0)), heights, stand, LAYOUT, camera_height=1.4,
        config=ExploreConfig(views=5, fov_deg=170 - 1e-9, max_range=6.0),
    )  # fmt: skip
    assert 1 <= len(one) < 5  # what is left to see runs out before the budget
    nothing = choose_views(np.zeros(SHAPE), heights, stand, LAYOUT, camera_height=1.4)
    assert nothing == []


def test_no_view_through_a_wall() -> None:
    """A wall at x = 3 m with no door: the box at (4.5, 1) is seen from its own side."""
    walls = np.zeros(SHAPE, bool)
    walls[60, :] = True
    _, heights, stand = _floor(walls)
    # the side of the wall away from the box is nearer and just as free
    stand = stand.copy()
    stand[61:, :] &= np.indices(SHAPE)[0][61:, :] > 100  # only far behind the box
    views = choose_views(
        _interest((0.0, 1.0, 0.0, 0.0)), heights, stand, LAYOUT, camera_height=1.4,
        config=ExploreConfig(views=1),
    )  # fmt: skip
    assert len(views) == 1
    assert views[0].position[0] > 3.0


def test_rasters_of_another_shape_are_refused() -> None:
    _, heights, stand = _floor()
    with pytest.raises(QueryError, match="interest raster"):
        choose_views(np.zeros((3, 3)), heights, stand, LAYOUT, camera_height=1.4)


def test_look_at_is_a_level_optical_camera() -> None:
    eye, target = np.array([1.0, 2.0, 1.5]), np.array([3.0, 1.0, 0.4])
    pose = look_at(eye, target)
    R = pose[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    forward = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(R[:, 2], forward, atol=1e-12)  # z forward
    assert R[2, 0] == pytest.approx(0.0)  # x right, level
    assert R[2, 1] > 0 or forward[2] < 0  # y down: image "down" points toward the floor
    np.testing.assert_allclose(pose[:3, 3], eye)
    down = look_at(eye, eye - [0, 0, 1])
    np.testing.assert_allclose(down[:3, 2], [0, 0, -1], atol=1e-12)


def _map(entropy, pwkl, stderr, views, top, positions, vocabulary=("wall", "chair", "table")):
    n = len(entropy)
    d = len(vocabulary)
    return CandidateMap(
        kind="grid", vocabulary=vocabulary, text=np.eye(d, dtype=np.float32), logit_scale=10.0,
        features=np.eye(d, dtype=np.float32)[np.asarray(top)], log_norm=np.zeros(n, np.float32),
        top_classes=np.asarray(top, np.int16)[:, None], entropy=np.asarray(entropy, np.float32),
        stderr=np.asarray(stderr, np.float32), pwkl=np.asarray(pwkl, np.float32),
        num_views=np.asarray(views, np.int32), positions=np.asarray(positions, np.float32),
        cell_size=CELL,
    )  # fmt: skip


def test_uncertainty_ranks_the_measures_over_object_cells() -> None:
    inf = np.inf
    cmap = _map(
        entropy=[0.1, 0.5, 0.9, 2.0], pwkl=[0.2, 0.3, inf, 9.0], stderr=[0.01, 0.02, inf, 5.0],
        views=[9, 5, 1, 1], top=[1, 2, 1, 0], positions=[[0, 0, 0], [2, 0, 0], [4, 0, 0], [6, 0, 0]],
    )  # fmt: skip
    assert object_cells(cmap).tolist() == [True, True, True, False]  # "wall" is the shell
    measures = (Uncertainty.ENTROPY, Uncertainty.PWKL, Uncertainty.STDERR, Uncertainty.FEW_VIEWS)
    u = cell_uncertainty(cmap, ExploreConfig(measures=measures))
    np.testing.assert_allclose(u, [0.0, 0.5, 1.0, 0.0])  # the wall counts for nothing
    assert rank_scores(np.array([3.0, 1.0, 3.0, 2.0])).tolist() == [1.0, 0.0, 1.0, 1 / 3]
    assert rank_scores(np.array([4.0, 4.0])).tolist() == [0.0, 0.0]


def test_contested_classes_mark_their_rival_places() -> None:
    """Chair: two equally likely places 2 m apart; table: one clear place."""
    vocabulary = ("wall", "chair", "table")
    features = np.array([[0, 1, 0], [0, 1, 0], [0, 0, 1], [0, 0.3, 0.7]], np.float32)
    features /= np.linalg.norm(features, axis=1, keepdims=True)
    scale = 10.0
    logits = scale * features @ np.eye(3)
    lnorm = np.log(np.exp(logits).sum(axis=1))
    cmap = CandidateMap(
        kind="grid", vocabulary=vocabulary, text=np.eye(3, dtype=np.float32), logit_scale=scale,
        features=features, log_norm=lnorm.astype(np.float32),
        top_classes=np.argsort(-logits, axis=1).astype(np.int16),
        entropy=np.zeros(4, np.float32), stderr=np.zeros(4, np.float32),
        pwkl=np.zeros(4, np.float32), num_views=np.full(4, 3, np.int32),
        positions=np.array([[0, 0, 0], [2, 0, 0], [4, 0, 0], [4.3, 0, 0]], np.float32),
    )  # fmt: skip
    score = contested(cmap, np.ones(4, bool), k=4, radius=1.0)
    assert score[0] == pytest.approx(score[1])  # equal rivals, equal shares
    assert score[0] > 0.2
    assert score[2] < 0.05 * score[0]  # the table's clear winner
    assert score[3] < 0.05 * score[0]  # a poor chair, and beside the table's winner
    assert contested(cmap, np.ones(4, bool), k=1, radius=1.0).tolist() == [0.0] * 4


def test_settings_are_checked() -> None:
    assert ExploreConfig(measures=("entropy", "few_views")).measures == (
        Uncertainty.ENTROPY, Uncertainty.FEW_VIEWS,
    )  # fmt: skip
    with pytest.raises(QueryError, match="measures"):
        ExploreConfig(measures=("loudness",))
    with pytest.raises(QueryError, match="measures"):
        ExploreConfig(measures=())
    with pytest.raises(QueryError, match="views"):
        ExploreConfig(views=0)
    with pytest.raises(QueryError, match="min_range"):
        ExploreConfig(min_range=3.0, max_range=2.0)
    with pytest.raises(QueryError, match="camera_height"):
        ExploreConfig(camera_height=-1.0)


def _message(msgtype: str, data):
    """``data`` as a ROS 2 message of ``msgtype``: a field it lacks or misnames fails here."""
    fields = {}
    for name, (node, kind) in ROS.fielddefs[msgtype][1]:
        assert name in data, (msgtype, name)
        value = data[name]
        fields[name] = _message(kind, value) if node.name == "NAME" else value
    assert set(data) == set(fields), msgtype
    msg = ROS.types[msgtype](**fields)
    assert len(ROS.serialize_cdr(msg, msgtype)) > 0
    return msg


def test_camera_poses_are_pose_stamped_in_the_goals_frame_and_the_world() -> None:
    """A map frame of its own (y-down world): the camera pose in ``care_map`` and, composed
    with the published transform, in the world frame."""
    map_from_world = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 1.3], [0, 0, 0, 1.0]])
    camera = look_at([1.0, 2.0, 1.4], [2.0, 2.5, 0.5])
    goal = Goal(3, "care_map", 1_700_000_000_250_000_000, (2.0, 2.5, 0.5), (1.0, 2.0, 0.0), 0.46,
                True, 0.4, map_from_world, "camera_init")  # fmt: skip
    mapped = camera_pose_stamped(goal, camera)
    world = camera_pose_stamped(goal, camera, in_world=True)
    for pose in (mapped, world):
        _message("geometry_msgs/msg/PoseStamped", json.loads(json.dumps(pose)))
    assert mapped["header"] == {"frame_id": "care_map",
                                "stamp": {"sec": 1_700_000_000, "nanosec": 250_000_000}}  # fmt: skip
    assert world["header"]["frame_id"] == "camera_init"
    p = world["pose"]["position"]
    want = np.linalg.solve(map_from_world, camera)[:3, 3]
    np.testing.assert_allclose([p["x"], p["y"], p["z"]], want, atol=1e-12)


# -- care explore on a fused store ---------------------------------------------------------

BOXES = {"steady": ((-0.6, 0.6), (-0.1, 1.1)), "unsure": ((2.4, -1.0), (2.9, -0.5))}
"""Box footprints ((x0, y0), (x1, y1)), 0.5 m tall: one seen as a chair from every view,
one seen as a chair from half the views and as a table from the others."""


def _explore_store(path: Path) -> Path:
    """A floor with two boxes seen from 2 m above by six cameras (z-up world), fused; the
    store has no ground truth."""
    from care_maps.core.frames import Frame
    from care_maps.core.store import EncoderInfo, StoreWriter
    from care_maps.fuse.grid import GridConfig, build_grid

    h, w, d = 48, 64, 8
    f = 24.0
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])
    text = np.eye(3, d, dtype=np.float32)  # floor, chair, table
    rng = np.random.default_rng(5)
    v, u = np.mgrid[0:h, 0:w]
    with StoreWriter(path, EncoderInfo("test", "1", d, ("floor", "chair", "table"))) as writer:
        for i in range(6):
            cx, cy = 0.5 * i, 0.0
            depth = np.full((h, w), 2.0, np.float32)
            label = np.zeros((h, w), int)
            x = cx + (u - K[0, 2]) / f * 1.5  # where each ray meets the boxes' tops
            y = cy - (v - K[1, 2]) / f * 1.5
            for name, ((x0, y0), (x1, y1)) in BOXES.items():
                inside = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
                depth[inside] = 1.5
                label[inside] = 1 if name == "steady" or i % 2 else 2
            feats = text[label] + 0.05 * rng.normal(size=(h, w, d)).astype(np.float32)
            feats /= np.linalg.norm(feats, axis=-1, keepdims=True)
            pose = np.eye(4)
            pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
            pose[:3, 3] = [cx, cy, 2.0]
            rgb = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
            writer.add(Frame(10**9 + i * 10**8, rgb, depth, K, pose), feats)
        writer.set_text(("floor", "chair", "table"), text)
        writer.commit({"source": "synthetic", "world_frame": "odom"})
    build_grid(path, GridConfig(cell_size=0.1, stride=1))
    return path


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _explore_store(tmp_path_factory.mktemp("explore") / "s")


@pytest.mark.slow
def test_care_explore_gives_goals_and_cameras_a_robot_reads(
    store: Path, tmp_path: Path, run_cli
) -> None:
    from care_maps.core.viz import rrd_entity_counts

    rrd = tmp_path / "explore.rrd"
    args = ("explore", store, "--views", "2", "--clearance", "0.2", "--min-range", "0.3")
    code, out, err = run_cli(*args, "--json", "--rrd", rrd)
    assert code == 0, err
    answer = json.loads(out)
    views = answer["views"]
    assert 1 <= len(views) <= 2
    (x0, y0), (x1, y1) = BOXES["unsure"]
    first = views[0]["target"]  # the box the views disagree on
    assert x0 - 0.1 <= first[0] <= x1 + 0.1
    assert y0 - 0.1 <= first[1] <= y1 + 0.1
    assert answer["goals"] == [v["goal"]["pose_stamped"] for v in views]
    for v in views:
        for pose in (v["goal"]["pose_stamped"], v["camera"]):
            _message("geometry_msgs/msg/PoseStamped", pose)
            assert pose["header"]["frame_id"] == "odom"
        assert "world_camera" not in v  # goals are in the world frame already
        cam = v["camera"]["pose"]["position"]
        assert cam["z"] == pytest.approx(v["camera_height"], abs=0.05)
        assert v["distance"] is not None  # reachable from the first camera
        assert v["goal"]["clearance"] >= 0.2 - 1e-6
    assert answer["start"] is not None
    counts = rrd_entity_counts(rrd)
    entities = {entity for entity, _ in counts}
    assert "/world/explore/view_1" in entities or "world/explore/view_1" in entities
    assert any("grid/uncertainty" in e for e in entities)

    code, out, err = run_cli(*args)
    assert code == 0, err
    assert "views over" in out
    assert "goal in 'odom'" in out


def test_care_explore_needs_a_grid(tmp_path: Path, run_cli) -> None:
    from care_maps.core.frames import Frame
    from care_maps.core.store import EncoderInfo, StoreWriter

    path = tmp_path / "bare"
    with StoreWriter(path, EncoderInfo("test", "1", 2, ("chair",))) as writer:
        K = np.array([[10.0, 0, 3.5], [0, 10.0, 2.5], [0, 0, 1]])
        frame = Frame(1, np.zeros((6, 8, 3), np.uint8), np.ones((6, 8), np.float32), K, np.eye(4))
        writer.add(frame, np.ones((1, 1, 2), np.float32))
        writer.commit({"source": "synthetic"})
    code, _, err = run_cli("explore", path)
    assert code == 1
    assert "care fuse grid" in err
    code, _, err = run_cli("explore", path, "--measures", "loudness")
    assert code == 2
    assert "contested" in err
