"""Paths on the map: distances and paths against networkx's Dijkstra on a graph built
apart (every cell a node, the moves added one by one from the whole grid's distance
transform), a hand-worked floor, the ``nav_msgs/Path`` JSON as a real ROS 2 message, and
``care query`` / ``care replan`` on a fused store."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import networkx as nx
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from scipy import ndimage

from care_maps.core.errors import QueryError
from care_maps.core.keys import GOAL_FRAME_KEY
from care_maps.fuse.layout import GridLayout
from care_maps.query import paths
from care_maps.query.goals import FreeSpace, Goal, GoalConfig, GoalMaker
from care_maps.query.paths import (
    TIED,
    PathConfig,
    Roadmap,
    Travel,
    nav_path,
    passable_squared_distance,
    path_length,
    walk,
)

STORE = get_typestore(Stores.ROS2_HUMBLE)
CELL = 0.1


def _space(obstacle: np.ndarray, seen: np.ndarray | None = None, cell: float = CELL) -> FreeSpace:
    """A free space of an (nx, ny) obstacle raster, every cell seen unless ``seen`` says."""
    ix, iy = (a.reshape(-1) for a in np.indices(obstacle.shape))
    keep = np.ones(ix.size, bool) if seen is None else seen.reshape(-1)
    layout = GridLayout(cell, (-1.0, 2.0), obstacle.shape)
    return FreeSpace.from_cells(layout, ix[keep], iy[keep], obstacle.reshape(-1)[keep])


def _rooms() -> np.ndarray:
    """A 3 x 2 m floor: a wall at x = 1.5 m with a 0.6 m door, and a closed room in a
    corner (walls all round, nothing gets in)."""
    obstacle = np.zeros((30, 20), bool)
    obstacle[15, :] = True
    obstacle[15, 8:14] = False  # the door
    obstacle[22:30, 12] = obstacle[22, 12:20] = True  # the closed room: x >= 2.3, y >= 3.3
    obstacle[29, 12:20] = obstacle[22:30, 19] = True
    return obstacle


def _networkx(space: FreeSpace, clearance: float) -> tuple[nx.Graph, np.ndarray]:
    """The 8-connected graph the robot moves on, built cell by cell from the whole grid's
    distance transform (the approach points' rule), with networkx."""
    metres = ndimage.distance_transform_edt(~space.blocked) * space.layout.cell_size
    if not space.blocked.any():
        metres = np.full(space.blocked.shape, np.inf)
    ok = space.free & (metres.astype(np.float32) >= clearance)
    graph = nx.Graph()
    nx_, ny_ = ok.shape
    size = space.layout.cell_size
    for x, y in zip(*np.nonzero(ok), strict=True):
        graph.add_node((x, y))
        for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
            u, v = x + dx, y + dy
            if not (0 <= u < nx_ and 0 <= v < ny_ and ok[u, v]):
                continue
            if dx and dy and not (ok[u, y] and ok[x, v]):  # no cutting a corner
                continue
            graph.add_edge((x, y), (u, v), weight=size * math.hypot(dx, dy))
    return graph, ok


def _centre(space: FreeSpace, cell: tuple[int, int]) -> tuple[float, float]:
    size, (ox, oy) = space.layout.cell_size, space.layout.origin
    return ox + (cell[0] + 0.5) * size, oy + (cell[1] + 0.5) * size


def _goal_at(space: FreeSpace, cell: tuple[int, int], **kw) -> Goal:
    x, y = _centre(space, cell)
    return Goal(0, "map", 5, (x + 0.3, y, 0.5), (x, y, 0.0), 0.0, True, 1.0, **kw)


def _check_against_networkx(space: FreeSpace, clearance: float, start_cell, seed: int) -> None:
    graph, ok = _networkx(space, clearance)
    roadmap = Roadmap.from_free_space(space, clearance)
    np.testing.assert_array_equal(roadmap.passable, ok)
    start = _centre(space, start_cell)
    travel = roadmap.travel(start, reach=0.0)
    want = nx.single_source_dijkstra_path_length(graph, start_cell) if ok[start_cell] else {}
    cells = np.argwhere(space.free)
    picks = np.random.default_rng(seed).choice(len(cells), min(60, len(cells)), replace=False)
    for cell in map(tuple, cells[picks]):
        goal = _goal_at(space, cell)
        got = travel.distance_to(goal)
        if cell not in want:
            assert got == math.inf, cell
            assert travel.waypoints(goal) is None
            continue
        assert got == pytest.approx(want[cell], abs=1e-9), cell
        points = travel.waypoints(goal)
        assert path_length(points) == pytest.approx(got, abs=1e-9)
        _assert_moves(space, ok, points)


def _assert_moves(space: FreeSpace, ok: np.ndarray, points: np.ndarray) -> None:
    """Each step of a path is one move of the graph: a neighbour, both ends passable, a
    diagonal with both cells beside it passable."""
    size, origin = space.layout.cell_size, np.asarray(space.layout.origin)
    cells = np.floor((points - origin) / size).astype(int)
    assert ok[tuple(cells.T)].all()
    for (x, y), (u, v) in itertools.pairwise(cells):
        assert max(abs(u - x), abs(v - y)) == 1
        if u != x and v != y:
            assert ok[u, y]
            assert ok[x, v]


@pytest.mark.parametrize("clearance", [0.0, 0.1, 0.2])
def test_distances_through_the_door_match_networkx(clearance: float) -> None:
    _check_against_networkx(_space(_rooms()), clearance, (3, 3), seed=int(clearance * 10))


@pytest.mark.parametrize("seed", range(4))
def test_generated_floors_match_networkx(seed: int) -> None:
    """Random clutter, walls with gaps, unseen patches and radii on the cell's edge."""
    rng = np.random.default_rng(seed)
    shape = tuple(rng.integers(25, 45, 2))
    obstacle = rng.random(shape) < rng.choice([0.01, 0.04, 0.1])
    obstacle[rng.integers(5, shape[0] - 5), :] = True
    obstacle[:, rng.integers(5, shape[1] - 5)] = True
    obstacle[rng.random(shape) < 0.15] = False  # gaps in the walls
    seen = rng.random(shape) > 0.05
    space = _space(obstacle, seen, cell=0.05)
    free = np.argwhere(space.free)
    start = tuple(free[rng.integers(len(free))])
    clearance = float(rng.choice([0.0, 0.05, 0.1, 0.15, 0.05 * math.sqrt(2)]))
    _check_against_networkx(space, clearance, start, seed)


def test_a_hand_worked_floor() -> None:
    """An open 10 x 10 floor of 0.1 m cells, one obstacle cell: from (0, 0) to (3, 4) is
    three diagonal moves and one straight; a goal 0.1 m from the obstacle is out of reach at
    0.15 m clearance; the closed room of :func:`_rooms` is out of reach, the far side of its
    wall is through the door."""
    obstacle = np.zeros((10, 10), bool)
    obstacle[8, 8] = True
    space = _space(obstacle)
    travel = Roadmap.from_free_space(space, 0.0).travel(_centre(space, (0, 0)), reach=0.0)
    assert travel.distance_to(_goal_at(space, (3, 4))) == pytest.approx(0.3 * math.sqrt(2) + 0.1)
    near = Roadmap.from_free_space(space, 0.15).travel(_centre(space, (0, 0)), reach=0.0)
    assert near.distance_to(_goal_at(space, (7, 8))) == math.inf  # 0.1 m from the obstacle
    assert near.distance_to(_goal_at(space, (6, 8))) < math.inf  # 0.2 m from it

    rooms = _space(_rooms())
    travel = Roadmap.from_free_space(rooms, 0.0).travel(_centre(rooms, (3, 3)), reach=0.0)
    assert travel.distance_to(_goal_at(rooms, (25, 16))) == math.inf  # inside the closed room
    # past the wall, through the door (cells y 8..13 of x = 15), entered straight: (3, 3) to
    # (14, 8) is 5 diagonal and 6 straight moves, 2 straight through the door, then (16, 8)
    # to (20, 3) 4 diagonal and 1 straight
    beyond = travel.distance_to(_goal_at(rooms, (20, 3)))
    assert beyond == pytest.approx(0.1 * (9 * math.sqrt(2) + 9))


def test_goals_without_an_approach_point_are_unreachable() -> None:
    space = _space(np.zeros((10, 10), bool))
    travel = Roadmap.from_free_space(space, 0.0).travel(_centre(space, (0, 0)), reach=0.0)
    goal = Goal(0, "map", 5, (0.0, 2.5, 0.4), (0.0, 2.5, 0.4), 0.0, False, None)
    assert travel.distance_to(goal) == math.inf
    assert travel.waypoints(goal) is None


def test_a_start_off_the_free_space_joins_the_nearest_passable_cell() -> None:
    obstacle = np.zeros((20, 20), bool)
    obstacle[8:12, 8:12] = True  # a table the hand-held camera starts above
    space = _space(obstacle)
    roadmap = Roadmap.from_free_space(space, 0.2)
    start = _centre(space, (10, 10))
    goal = _goal_at(space, (10, 2))
    travel = roadmap.travel(start, reach=1.0)
    entry = roadmap.centres([travel.source])[0]
    assert math.dist(entry, start) == pytest.approx(0.3)  # past the table's edge, 0.2 m off it
    points = travel.waypoints(goal)
    np.testing.assert_allclose(points[0], start)
    assert travel.distance_to(goal) == pytest.approx(path_length(points))
    stuck = roadmap.travel(start, reach=0.25)
    assert stuck.source is None
    assert stuck.distance_to(goal) == math.inf
    outside = roadmap.travel((50.0, 50.0), reach=1.0)
    assert outside.source is None


@pytest.mark.parametrize("cell", [0.05, 0.1, 0.03])
def test_the_robots_radius_keeps_the_approach_points_rule(cell: float) -> None:
    """A goal said to keep the clearance stands on a passable cell, whatever the radius
    (radii on a cell's edge, where float rounding decides, included)."""
    rng = np.random.default_rng(int(cell * 100))
    obstacle = rng.random((60, 50)) < 0.02
    space = _space(obstacle, cell=cell)
    for clearance in (0.0, cell, 2 * cell, 0.25, 0.3, cell * math.sqrt(5), 0.31):
        roadmap = Roadmap.from_free_space(space, clearance)
        config = GoalConfig(clearance=clearance, reach=1.0)
        for target in rng.uniform(0.0, 1.0, (20, 2)) * np.array(space.layout.shape) * cell:
            found = space.approach(tuple(target + space.layout.origin), config)
            if found is None:
                continue
            ix, iy = roadmap.cell_of(found[:2])
            assert roadmap.passable[ix, iy] == (found[2] >= np.float32(clearance))
        k = passable_squared_distance(clearance, cell)
        assert np.float32(math.sqrt(k) * cell) >= clearance
        assert k == 0 or np.float32(math.sqrt(k - 1) * cell) < clearance


def _message(msgtype: str, data):
    """``data`` as a ROS 2 message of ``msgtype``: a field it lacks or misnames fails here."""
    fields = {}
    for name, (node, kind) in STORE.fielddefs[msgtype][1]:
        assert name in data, (msgtype, name)
        value = data[name]
        if node.name == "NAME":
            fields[name] = _message(kind, value)
        elif node.name == "SEQUENCE":
            fields[name] = [_message(kind[0][1], v) for v in value]
        else:
            fields[name] = value
    assert set(data) == set(fields), msgtype
    return STORE.types[msgtype](**fields)


def test_nav_path_is_a_ros2_message_in_the_goals_frame() -> None:
    """In the world frame of a z-up recording whose floor lies at z = 0.4: the poses lie on
    the floor, face along the path, the last one is the goal's own pose."""
    space = _space(_rooms())
    travel = Roadmap.from_free_space(space, 0.1).travel(_centre(space, (3, 3)), reach=0.0)
    frame_from_map = np.eye(4)
    frame_from_map[2, 3] = 0.4
    goal = _goal_at(space, (20, 3), frame_from_map=frame_from_map)
    goal = Goal(0, "odom", 1_700_000_000_250_000_000, goal.target, goal.position, 0.7, True, 0.5,
                frame_from_map=frame_from_map)  # fmt: skip
    points = travel.waypoints(goal)
    path = nav_path(goal, points)
    msg = _message("nav_msgs/msg/Path", json.loads(json.dumps(path)))
    assert len(STORE.serialize_cdr(msg, "nav_msgs/msg/Path")) > 0
    assert path["header"]["frame_id"] == "odom"
    assert path["header"]["stamp"] == {"sec": 1_700_000_000, "nanosec": 250_000_000}
    poses = path["poses"]
    assert len(poses) == len(points)
    xyz = np.array([[p["pose"]["position"][k] for k in "xyz"] for p in poses])
    np.testing.assert_allclose(xyz[:, :2], points)
    np.testing.assert_allclose(xyz[:, 2], 0.4)
    assert poses[-1] == goal.pose_stamped()
    q = poses[0]["pose"]["orientation"]
    heading = 2 * math.atan2(q["z"], q["w"])
    step = points[1] - points[0]
    assert heading == pytest.approx(math.atan2(step[1], step[0]))


def test_path_settings_are_checked() -> None:
    with pytest.raises(QueryError, match="x,y"):
        PathConfig(start=(1.0, 2.0, 3.0))
    with pytest.raises(QueryError, match="x,y"):
        PathConfig(start=(1.0, math.nan))
    with pytest.raises(QueryError, match="reach"):
        PathConfig(start_reach=-1.0)


def _fused_store(path: Path) -> Path:
    """A floor with a box, seen from above by three cameras in a z-up world, fused."""
    from care_maps.core.frames import Frame
    from care_maps.core.store import EncoderInfo, StoreWriter
    from care_maps.fuse.grid import GridConfig, build_grid

    h, w, d = 24, 32, 4
    k = np.array([[20.0, 0, 15.5], [0, 20.0, 11.5], [0, 0, 1]])
    rng = np.random.default_rng(3)
    with StoreWriter(path, EncoderInfo("test", "1", d, ("chair", "table"))) as writer:
        for i in range(3):
            depth = np.full((h, w), 2.0, np.float32)
            depth[4:10, 5:12] = 1.5  # a box 0.5 m tall
            pose = np.eye(4)
            pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
            pose[:3, 3] = [0.3 + 0.05 * i, -0.2, 2.0]
            feats = rng.normal(size=(2, 2, d)).astype(np.float32)
            feats /= np.linalg.norm(feats, axis=-1, keepdims=True)
            rgb = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
            writer.add(Frame(10**9 + i * 10**8, rgb, depth, k, pose), feats)
        writer.set_text(("chair", "table"), np.eye(2, d, dtype=np.float32))
        writer.commit({"source": "synthetic", "world_frame": "odom"})
    build_grid(path, GridConfig(cell_size=0.2, stride=1))  # every cell of the floor seen
    return path


def test_cli_query_and_replan_give_the_path(tmp_path: Path, run_cli) -> None:
    from care_maps.core.store import Store

    store = _fused_store(tmp_path / "s")
    args = ("query", store, "chair", "--map", "grid", "--top", "4", "--clearance", "0.2")
    code, out, err = run_cli(*args, "--json", "--from", "-0.4,-0.5")
    assert code == 0, err
    answer = json.loads(out)
    assert answer["start"][:2] == [-0.4, -0.5]  # x, y, z in the goals' frame
    goals = GoalMaker.from_store(store, GoalConfig(clearance=0.2))
    travel = Roadmap.for_goals(goals).travel((-0.4, -0.5), PathConfig().start_reach)
    for row in answer["candidates"]:
        goal = goals.goal(_candidates(store), row["candidate"])
        want = travel.distance_to(goal)
        assert row["distance"] == (pytest.approx(want) if math.isfinite(want) else None)
    top = answer["candidates"][0]
    assert top["distance"] is not None
    assert answer["candidate"] == top["candidate"]  # the first attempt: reachable, it is offered
    assert answer["path_length"] == pytest.approx(top["distance"])
    path = answer["path"]
    _message("nav_msgs/msg/Path", path)
    assert path["header"] == top["goal"]["pose_stamped"]["header"]
    assert path["poses"][-1] == top["goal"]["pose_stamped"]
    first = path["poses"][0]["pose"]["position"]
    assert (first["x"], first["y"]) == pytest.approx((-0.4, -0.5))

    code, out, err = run_cli(*args)  # the table, from the recording's first pose
    assert code == 0, err
    assert "path m" in out
    code, out, err = run_cli(
        "replan", store, "chair", "--map", "grid", "--visited", "0", "--clearance", "0.2"
    )
    assert code == 0, err
    chosen = json.loads(out)
    x, y = Store(store).poses()[0][:2, 3]  # the first camera, on the floor
    assert chosen["start"][:2] == pytest.approx([x, y])
    travel = Roadmap.for_goals(goals).travel((x, y), PathConfig().start_reach)
    want = travel.distance_to(goals.goal(_candidates(store), chosen["candidate"]))
    assert math.isfinite(want)
    assert chosen["distance"] == pytest.approx(want)
    assert chosen["path_length"] == pytest.approx(want)
    _message("nav_msgs/msg/Path", chosen["path"])
    code, _, err = run_cli("query", store, "chair", "--from", "1,2,3")
    assert code == 2  # a bad option's value, named
    assert "--from" in err
    assert "x,y" in err


def _candidates(store: Path):
    from care_maps.query import load_map

    return load_map(store, "grid")


def test_distances_look_up_what_distance_to_gives() -> None:
    """Every goal at once: inside, outside the grid, and without an approach point."""
    space = _space(_rooms())
    travel = Roadmap.from_free_space(space, 0.0).travel(_centre(space, (3, 3)), 0.0)
    goals = [_goal_at(space, cell) for cell in [(5, 5), (25, 5), (25, 16), (0, 0)]]
    goals.append(Goal(0, "map", 5, (0.0, 0.0, 0.5), (0.0, 0.0, 0.5), 0.0, False, None))
    goals.append(Goal(0, "map", 5, (90.0, 0.0, 0.5), (90.0, 0.0, 0.0), 0.0, True, 1.0))
    want = [travel.distance_to(g) for g in goals]
    np.testing.assert_array_equal(travel.distances(goals), want)
    assert math.isinf(want[2])  # the closed room
    assert math.isinf(want[-1])  # off the grid
    assert travel.distances([]).shape == (0,)


def test_a_roadmap_keeps_its_last_searches(monkeypatch: pytest.MonkeyPatch) -> None:
    """The same start asks no second search; newer starts let the oldest go."""
    roadmap = Roadmap.from_free_space(_space(_rooms()), 0.0)
    searched = []
    search = Roadmap._search
    monkeypatch.setattr(
        Roadmap, "_search", lambda self, s, r: searched.append(s) or search(self, s, r)
    )
    first = roadmap.travel((0.0, 2.5), 0.5)
    assert roadmap.travel((0.0, 2.5), 0.5) is first
    assert len(searched) == 1
    with pytest.raises(ValueError, match="read-only"):  # shared: no caller changes it
        first.distance[0] = 0.0
    for x in (0.2, 0.4, 0.6, 0.8):
        roadmap.travel((x, 2.5), 0.5)
    assert roadmap.travel((0.0, 2.5), 0.5) is not first
    assert len(searched) == 6


def test_a_walk_drives_each_attempt_from_where_the_last_ended() -> None:
    """Against networkx: the first leg from the start, an unreachable attempt leaves the
    robot where it stood, the next leg starts at the last goal it reached."""
    space = _space(_rooms())
    graph, ok = _networkx(space, 0.0)
    roadmap = Roadmap.from_free_space(space, 0.0)
    cells = [(25, 5), (25, 16), (5, 15)]  # the far room, the closed room, back
    legs = walk(roadmap, _centre(space, (3, 3)), 0.0, [_goal_at(space, c) for c in cells])
    assert [leg.goal.position[:2] for leg in legs] == [_centre(space, c) for c in cells]
    near = nx.single_source_dijkstra_path_length(graph, (3, 3))
    assert legs[0].start == _centre(space, (3, 3))
    assert legs[0].length == pytest.approx(near[(25, 5)], abs=1e-9)
    assert legs[1].waypoints is None
    assert math.isinf(legs[1].length)
    assert legs[1].start == legs[2].start == pytest.approx(_centre(space, (25, 5)))
    back = nx.single_source_dijkstra_path_length(graph, (25, 5))
    assert legs[2].length == pytest.approx(back[(5, 15)], abs=1e-9)
    _assert_moves(space, ok, legs[2].waypoints)
    assert walk(roadmap, (0.0, 2.5), 0.0, []) == []


def _batch_answers(tmp_path: Path, run_cli, *start: str) -> tuple[object, str]:
    import pyarrow.parquet as pq

    store = tmp_path / "s" if (tmp_path / "s").is_dir() else _fused_store(tmp_path / "s")
    queries = tmp_path / "q.txt"
    queries.write_text("chair\ntable\nchair\n")
    out = tmp_path / f"a{len(list(tmp_path.glob('a*.parquet')))}.parquet"
    code, printed, err = run_cli(
        "query", store, "--map", "grid", "--batch", queries, "--out", out, "-k", "2",
        "--clearance", "0.2", *start,
    )  # fmt: skip
    assert code == 0, err
    return pq.read_table(out), printed


def test_cli_batch_gives_each_rows_distance_from_one_search(
    tmp_path: Path, run_cli, monkeypatch: pytest.MonkeyPatch
) -> None:
    searches = []
    search = Roadmap._search
    monkeypatch.setattr(
        Roadmap, "_search", lambda self, s, r: searches.append(s) or search(self, s, r)
    )
    table, _ = _batch_answers(tmp_path, run_cli, "--from", "-0.4,-0.5")
    assert searches == [(-0.4, -0.5)]  # one search for the whole batch
    frame = json.loads(table.schema.metadata[GOAL_FRAME_KEY])
    assert frame["path_start"] == [-0.4, -0.5]
    store = tmp_path / "s"
    goals = GoalMaker.from_store(store, GoalConfig(clearance=0.2))
    travel = Roadmap.for_goals(goals).travel((-0.4, -0.5), PathConfig().start_reach)
    cmap = _candidates(store)
    rows = table.to_pylist()
    assert any(r["reachable"] for r in rows)
    for row in rows:
        if row["candidate"] < 0:
            assert row["distance"] is None
            assert row["reachable"] is None
            continue
        want = travel.distance_to(goals.goal(cmap, row["candidate"]))
        assert row["reachable"] == math.isfinite(want)
        assert row["distance"] == (pytest.approx(want) if math.isfinite(want) else None)


def test_cli_batch_without_a_start_on_free_space_has_no_distances(tmp_path: Path, run_cli) -> None:
    table, printed = _batch_answers(tmp_path, run_cli, "--from", "50,50")
    assert "no paths" in printed
    assert set(table.column("distance").to_pylist()) == {None}
    assert set(table.column("reachable").to_pylist()) == {None}
    assert json.loads(table.schema.metadata[GOAL_FRAME_KEY])["path_start"] is None


def _strips(rrd: Path) -> dict[str, list]:
    """Each attempt's way in ``rrd``: entity path to its points."""
    from rerun.chunk import RrdReader

    out = {}
    for chunk in RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        if "LineStrips3D:strips" in batch.schema.names:
            out[str(chunk.entity_path)] = batch.column("LineStrips3D:strips").to_pylist()[0][0]
    return out


def test_cli_query_and_replan_draw_each_attempts_way(tmp_path: Path, run_cli) -> None:
    from care_maps.core.viz import rrd_entity_counts
    from care_maps.query.viz import ANSWER_ENTITY, attempt_entity

    store = _fused_store(tmp_path / "s")
    args = ("--map", "grid", "--clearance", "0.2", "--from", "-0.4,-0.5")
    code, out, err = run_cli(
        "query", store, "chair", *args, "--json", "--attempts", "2", "--rrd", tmp_path / "q.rrd"
    )
    assert code == 0, err
    answer = json.loads(out)  # stdout stays JSON: the file is named on stderr
    assert "q.rrd" in err
    strips = _strips(tmp_path / "q.rrd")
    first = strips[f"/{attempt_entity(1)}"]
    path = [
        (p["pose"]["position"]["x"], p["pose"]["position"]["y"]) for p in answer["path"]["poses"]
    ]
    np.testing.assert_allclose(np.array(first)[:, :2], path, atol=1e-5)  # the JSON's way
    assert set(strips) <= {f"/{attempt_entity(k)}" for k in (1, 2)}
    counts = rrd_entity_counts(tmp_path / "q.rrd")
    assert counts[(f"/{ANSWER_ENTITY}/goals", "Arrows3D:origins")] == 1
    assert counts[(f"/{ANSWER_ENTITY}/start", "Points3D:positions")] == 1
    assert counts[("/answer", "TextDocument:text")] == 1

    code, out, err = run_cli(
        "replan", store, "chair", *args, "--visited", str(answer["candidates"][0]["candidate"]),
        "--rrd", tmp_path / "r.rrd",
    )  # fmt: skip
    assert code == 0, err
    chosen = json.loads(out)
    strips = _strips(tmp_path / "r.rrd")
    assert set(strips) == {f"/{attempt_entity(2)}"}  # the visited one's way is not known
    path = [
        (p["pose"]["position"]["x"], p["pose"]["position"]["y"]) for p in chosen["path"]["poses"]
    ]
    np.testing.assert_allclose(np.array(strips[f"/{attempt_entity(2)}"])[:, :2], path, atol=1e-5)
    code, _, err = run_cli("query", store, "--batch", tmp_path / "x.txt", "--rrd", "a.rrd")
    assert code == 1
    assert "--rrd" in err


def _floor(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """A random floor: scattered obstacles, walls with doors, and rooms left closed."""
    obstacle = rng.random(shape) < rng.choice([0.0, 0.02, 0.08, 0.2, 0.35])
    for _ in range(int(rng.integers(0, 4))):
        at = int(rng.integers(0, shape[0]))
        obstacle[at, :] = True
        door = int(rng.integers(0, shape[1]))
        obstacle[at, door : door + int(rng.integers(0, 5))] = False
    return obstacle


def test_nearest_first_is_scipys_dijkstra() -> None:
    """The NumPy search gives scipy's distances bit for bit and scipy's cell before each
    wherever it does not say TIED; a path through a TIED cell is scipy's too (asked of
    scipy), on floors of every shape, density and clearance, from starts all over them."""
    rng = np.random.default_rng(0)
    tied = 0
    for _ in range(150):
        shape = (int(rng.integers(1, 45)), int(rng.integers(1, 45)))
        space = _space(_floor(rng, shape), cell=float(rng.choice([0.05, 0.1, 0.037])))
        roadmap = Roadmap.from_free_space(space, float(rng.choice([0.0, 0.1, 0.2])))
        cells = np.flatnonzero(roadmap.passable)
        for source in rng.choice(cells, min(3, len(cells)), replace=False):
            dist, pred = roadmap.nearest_first(int(source))
            want_dist, want_pred = roadmap.dijkstra(int(source))
            assert np.array_equal(dist.view(np.int64), want_dist.view(np.int64))
            known = pred != TIED
            assert np.array_equal(pred[known], want_pred[known])
            tied += int((~known).sum())
            start = tuple(roadmap.centres([int(source)])[0])
            travel = roadmap.travel(start, reach=0.0)
            for cell in np.flatnonzero(~known)[:5]:
                goal = _goal_at(space, divmod(int(cell), shape[1]))
                _scipys_path_is_taken(roadmap, travel, goal, want_pred)
    assert tied > 0  # the ties scipy's heap decides were met, and asked of it


def _scipys_path_is_taken(
    roadmap: Roadmap, travel: Travel, goal: Goal, want_pred: np.ndarray
) -> None:
    """The way to ``goal`` is the one scipy's cells-before give (cell centres; the start
    is the source's own centre here)."""
    cell = travel.cell(goal.position[:2])
    cells = [cell]
    while cells[-1] != travel.source:
        cells.append(int(want_pred[cells[-1]]))
    want = roadmap.centres(np.array(cells[::-1]))
    assert np.array_equal(travel.waypoints(goal), want)


def test_large_grids_are_searched_by_scipy(monkeypatch: pytest.MonkeyPatch) -> None:
    """Above the NumPy search's size, scipy's Dijkstra answers (and the same)."""
    space = _space(_rooms())
    roadmap = Roadmap.from_free_space(space, 0.0)
    start = _centre(space, (3, 3))
    numpy_travel = roadmap.travel(start, reach=0.0)
    monkeypatch.setattr(paths, "_NUMPY_CELLS", 0)
    scipy_travel = Roadmap.from_free_space(space, 0.0).travel(start, reach=0.0)
    assert np.array_equal(numpy_travel.distance, scipy_travel.distance)
    assert not (scipy_travel.predecessor == TIED).any()
