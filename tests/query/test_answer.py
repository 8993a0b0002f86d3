"""An answer keeps its promises (``care query`` / ``care replan``), on the bundled sample and
on the third-party living room:

- every goal said to keep ``--clearance`` does, by a brute-force distance to the obstacle
  cells; one that cannot is flagged, and is not the first attempt unless allowed;
- every candidate has a path, or a ``path_note`` saying why, checked against a free-cell
  graph built here with networkx from the occupancy arrays (reachability, lengths, the
  nearest reachable approach point);
- every coordinate of the JSON is in the goals' frame: composed with the transform
  ``care frame --json`` publishes, they give the world-frame ones;
- the ``--rrd`` draws the candidates of the goals it shows, no more, no fewer.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import networkx as nx
import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy import ndimage
from scipy.spatial.transform import Rotation

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]
CLEARANCE, REACH, START_REACH = 0.3, 1.0, 1.0
FREE_START = "0.43,2.93"
"""A free cell of the sample that the robot's clearance keeps apart from some chairs."""


def _care(*args: object) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "care_maps.cli.main", *map(str, args)],
        capture_output=True, text=True, cwd=ROOT, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.fixture(scope="module")
def sample(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled sample ingested and fused into a grid, as ``care run`` does."""
    store = tmp_path_factory.mktemp("sample") / "scene_000"
    _care(
        "ingest",
        ROOT / "care_maps/data/sample/scene_000.mcap",
        "--out",
        store,
        "--encoder",
        "labels",
    )
    _care("fuse", "grid", store)
    return store


@pytest.fixture(scope="module")
def livingroom(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The living-room frames (y-down world ``map``), written to MCAP by the real writer,
    ingested with the ingest tests' tiny encoder (a ``tv`` in its vocabulary), fused."""
    from care_maps.core.frames import Frame
    from care_maps.fuse.grid import GridConfig, build_grid
    from care_maps.ingest.pipeline import IngestConfig, run_ingest
    from care_maps.ingest.write import write_recording
    from care_maps.runtime.execution import Execution
    from tests.support.encoders import TinyEncoder
    from tests.support.frames import load_livingroom

    frames = []
    for f in load_livingroom(shared_data / "rgbd/livingroom1_clean_micro", 200)[::5]:
        k = f.K.copy()
        k[:2] /= 2
        k[:2, 2] = (f.K[:2, 2] - 0.5) / 2
        rgb, depth = f.rgb[::2, ::2].copy(), f.depth_m[::2, ::2].copy()
        frames.append(Frame(f.stamp_ns, rgb, depth, k, f.cam_to_world))
    root = tmp_path_factory.mktemp("livingroom")
    rec = write_recording(root / "rec.mcap", frames, fmt="mcap")
    config = IngestConfig(vocabulary="tv,sofa,table,lamp")
    store = run_ingest(
        rec, root / "store", config, run=Execution(progress=False), encoder=TinyEncoder()
    )
    build_grid(store, GridConfig(cell_size=0.05, stride=2))
    return store


class Floor:
    """The store's occupancy as arrays, and the robot's graph over it, built apart from
    ``care_maps.query.paths``: passable = seen, not an obstacle, and a float32 distance transform of
    at least the clearance; 8 moves, no corner cut."""

    def __init__(self, store: Path, clearance: float = CLEARANCE) -> None:
        from care_maps.fuse.layout import GridLayout  # the grid's size and origin, as stored

        table = pq.read_table(store / "cells.parquet", columns=["ix", "iy", "obstacle"])
        layout = GridLayout.from_table(table)
        self.size, self.origin, shape = layout.cell_size, np.array(layout.origin), layout.shape
        ix, iy = (table.column(c).to_numpy().astype(int) for c in ("ix", "iy"))
        obstacle = table.column("obstacle").to_numpy(zero_copy_only=False).astype(bool)
        self.blocked = np.zeros(shape, bool)
        self.blocked[ix[obstacle], iy[obstacle]] = True
        seen = np.zeros(shape, bool)
        seen[ix, iy] = True
        self.free = seen & ~self.blocked
        self.metres = ndimage.distance_transform_edt(~self.blocked) * self.size
        self.ok = self.free & (self.metres.astype(np.float32) >= clearance)
        self.graph = nx.Graph()
        nx_, ny_ = shape
        for x, y in zip(*np.nonzero(self.ok), strict=True):
            self.graph.add_node((x, y))
            for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
                u, v = x + dx, y + dy
                if not (0 <= u < nx_ and 0 <= v < ny_ and self.ok[u, v]):
                    continue
                if dx and dy and not (self.ok[u, y] and self.ok[x, v]):
                    continue
                self.graph.add_edge((x, y), (u, v), weight=self.size * math.hypot(dx, dy))

    def cell(self, xy) -> tuple[int, int]:
        return tuple(int(v) for v in np.floor((np.asarray(xy[:2]) - self.origin) / self.size))

    def centre(self, cell) -> np.ndarray:
        return self.origin + (np.asarray(cell) + 0.5) * self.size

    def entry(self, start) -> tuple[tuple[int, int] | None, float]:
        """The cell a start joins (its own, else the nearest passable within the reach) and
        the metres to it."""
        own = self.cell(start)
        inside = all(0 <= c < n for c, n in zip(own, self.ok.shape, strict=True))
        if inside and self.ok[own]:
            return own, float(np.hypot(*(self.centre(own) - start)))
        cells = np.argwhere(self.ok)
        gap = np.hypot(*(self.centre(cells) - start).T)
        if not len(cells) or gap.min() > START_REACH:
            return None, math.inf
        return tuple(cells[np.argmin(gap)]), float(gap.min())

    def obstacle_distance(self, xy) -> float:
        """Brute force: metres from ``xy`` to the nearest obstacle cell's centre."""
        return float(np.hypot(*(self.centre(np.argwhere(self.blocked)) - xy[:2]).T).min())

    def approach(self, target, allowed: np.ndarray) -> tuple[int, int] | None:
        """The ``allowed`` cell nearest ``target`` within the reach (ties: lower index)."""
        cells = np.argwhere(allowed)
        gap = np.hypot(*(self.centre(cells) - np.asarray(target[:2])).T)
        near = gap <= REACH
        return tuple(cells[near][np.argmin(gap[near])]) if near.any() else None


def _xy(pose: dict) -> np.ndarray:
    p = pose["pose"]["position"]
    return np.array([p["x"], p["y"]])


def _check_answer(store: Path, answer: dict, start: tuple[float, float]) -> None:
    """Each row's goal, state, note and distance against the networkx floor."""
    floor = Floor(store)
    source, lead = floor.entry(np.asarray(start))
    length = (
        nx.single_source_dijkstra_path_length(floor.graph, source) if source is not None else {}
    )
    reached = np.zeros_like(floor.ok)
    for cell in length:
        reached[cell] = True
    first = None
    for row in answer["candidates"]:
        goal, state, note = row["goal"], row["path_state"], row["path_note"]
        xy = _xy(goal["pose_stamped"])
        if goal["clearance_ok"]:
            assert floor.obstacle_distance(xy) >= CLEARANCE - 1e-6
            assert floor.ok[floor.cell(xy)]
        else:  # nothing within reach keeps it: the brute force agrees
            assert floor.approach(goal["target"], floor.ok) is None
            assert state in {"tight", "no_free_cell"}
            assert row["distance"] is None
            assert "--clearance" in note
            continue
        if source is None:
            assert state == "start_off_roadmap"
            assert "off the roadmap" in note
            continue
        cell = floor.cell(xy)
        if cell in length:
            assert state == "reachable", row
            assert row["distance"] == pytest.approx(length[cell] + lead, abs=1e-6)
            assert note is None
            first = first or row
            continue
        assert row["distance"] is None
        alt = floor.approach(goal["target"], floor.ok & reached)
        if alt is None:
            assert state == "cut_off", row
            assert "cut off" in note
            continue
        assert state == "detour", row
        assert "cut off" in note
        got = row["reachable_goal"]
        np.testing.assert_allclose(_xy(got["pose_stamped"]), floor.centre(alt), atol=1e-9)
        assert row["reachable_distance"] == pytest.approx(length[alt] + lead, abs=1e-6)
        first = first or row
    if first is not None:  # the first attempt: the best-ranked with a way, the others passed
        assert answer["candidate"] == first["candidate"]
        passed = [r["candidate"] for r in answer["candidates"] if r["rank"] < first["rank"]]
        assert [p["candidate"] for p in answer["passed_over"]] == passed
        assert answer["distance"] == pytest.approx(
            first["distance"] if first["path_state"] == "reachable" else first["reachable_distance"]
        )
        path = [_xy(p) for p in answer["path"]["poses"]]
        assert path[-1] == pytest.approx(_xy(answer["goal"]["pose_stamped"]))


@pytest.mark.parametrize("start", [None, FREE_START])
def test_sample_paths_and_notes_match_networkx(sample: Path, start: str | None) -> None:
    args = ("query", sample, "chair", "--map", "grid", "--top", "30", "--json")
    answer = json.loads(_care(*args, *(("--from", start) if start else ())))
    xy = tuple(float(v) for v in start.split(",")) if start else answer["start"][:2]
    _check_answer(sample, answer, xy)
    states = {r["path_state"] for r in answer["candidates"]}
    assert {"reachable", "cut_off"} <= states  # the sample has both
    assert answer["path"] is not None
    assert answer["passed_over"]  # the top chair is cut off from either start

    table = _care(*args[:-1], *(("--from", start) if start else ()))
    assert "passed over" in table
    assert "cut off" in table


def test_replan_offers_a_reachable_candidate_and_says_what_it_passed(sample: Path) -> None:
    chosen = json.loads(_care("replan", sample, "chair", "--map", "grid", "--from", FREE_START))
    assert chosen["path"] is not None
    assert chosen["path_state"] in {"reachable", "detour"}
    assert chosen["passed_over"]
    floor = Floor(sample)
    source, _ = floor.entry(np.array([0.43, 2.93]))
    length = nx.single_source_dijkstra_path_length(floor.graph, source)
    assert floor.cell(_xy(chosen["goal"]["pose_stamped"])) in length
    for passed in chosen["passed_over"]:
        assert passed["reason"]


def test_livingroom_paths_and_a_start_off_the_roadmap(livingroom: Path) -> None:
    args = ("query", livingroom, "tv", "--map", "grid", "--top", "15", "--json")
    answer = json.loads(_care(*args))
    frame = _world_from_frame(livingroom)
    start = _map_xy(frame, answer["start"], answer["frame_id"], livingroom)
    _check_answer(livingroom, answer, start)

    off = json.loads(_care(*args, "--from", "-6,-6"))  # far outside the room
    floor = Floor(livingroom)
    cells = np.argwhere(floor.ok)
    nearest = floor.centre(cells[np.argmin(np.hypot(*(floor.centre(cells) - (-6, -6)).T))])
    for row in off["candidates"]:
        if row["goal"]["clearance_ok"]:
            assert row["path_state"] == "start_off_roadmap"
            assert f"({nearest[0]:.2f}, {nearest[1]:.2f})" in row["path_note"]
    assert off["path"] is None
    assert "off the roadmap" in off["path_note"]


def _world_from_frame(store: Path) -> dict:
    return json.loads(_care("frame", store, "--json"))


def _map_xy(transform: dict, point: list[float], frame_id: str, store: Path) -> tuple:
    """Map x, y of a point given in ``frame_id`` (the map frame, or the world frame)."""
    if frame_id == transform["child_frame_id"]:
        return tuple(point[:2])
    world_from_map = _matrix(transform)
    x, y, _ = np.linalg.solve(world_from_map, [*point, 1.0])[:3]
    return x, y


def _matrix(transform: dict) -> np.ndarray:
    t, r = transform["transform"]["translation"], transform["transform"]["rotation"]
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat([r[k] for k in "xyzw"]).as_matrix()
    out[:3, 3] = [t[k] for k in "xyz"]
    return out


def _pose(stamped: dict) -> np.ndarray:
    p, q = stamped["pose"]["position"], stamped["pose"]["orientation"]
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat([q[k] for k in "xyzw"]).as_matrix()
    out[:3, 3] = [p[k] for k in "xyz"]
    return out


def test_one_frame_for_every_coordinate(livingroom: Path) -> None:
    """In ``care_map`` (published under ``map``) and in ``map`` itself: the target, the
    candidate's position and the start move with the goal by the published transform."""
    world_from_map = _matrix(_world_from_frame(livingroom))
    args = ("query", livingroom, "tv", "--map", "grid", "--top", "3", "--json")
    in_map = json.loads(_care(*args))
    in_world = json.loads(_care(*args, "--frame-id", "map"))
    assert in_map["frame_id"] == "care_map"
    assert in_world["frame_id"] == "map"
    for a, b in zip(in_map["candidates"], in_world["candidates"], strict=True):
        ga, gb = a["goal"], b["goal"]
        assert ga["pose_stamped"]["header"]["frame_id"] == "care_map"
        assert gb["pose_stamped"]["header"]["frame_id"] == "map"
        np.testing.assert_allclose(
            world_from_map @ _pose(ga["pose_stamped"]), _pose(gb["pose_stamped"]), atol=1e-9
        )
        target = (world_from_map @ [*ga["target"], 1.0])[:3]
        np.testing.assert_allclose(target, gb["target"], atol=1e-9)
        np.testing.assert_allclose(target, ga["world_target"], atol=1e-9)
        position = (world_from_map @ [*a["position"], 1.0])[:3]
        np.testing.assert_allclose(position, b["position"], atol=2e-3)  # rounded to mm
    start = (world_from_map @ [*in_map["start"], 1.0])[:3]
    np.testing.assert_allclose(start, in_world["start"], atol=1e-9)
    assert in_map["start"][2] == 0.0  # on the floor of the map frame


def test_a_tight_goal_is_flagged_and_passed_over_unless_allowed(sample: Path) -> None:
    from care_maps.query import load_map
    from care_maps.query.goals import GoalConfig, GoalMaker
    from care_maps.query.paths import PathConfig
    from care_maps.replan.answer import AnswerGoals, PathState, first_offer

    cmap = load_map(sample, "grid")
    floor = Floor(sample)
    strict = AnswerGoals(GoalMaker.from_store(sample), cmap, None, PathConfig())
    tight = next(
        c for c in range(0, cmap.num_candidates, 7) if strict.offer(c).state == PathState.TIGHT
    )
    goal = strict.offer(tight).goal
    assert goal.keeps_clearance is False
    assert goal.clearance == pytest.approx(floor.obstacle_distance(goal.position), abs=1e-6)
    assert goal.clearance < CLEARANCE
    assert goal.as_dict()["clearance_ok"] is False
    fine = next(c for c in range(cmap.num_candidates) if strict.offer(c).offerable)
    got = first_offer(strict, np.array([tight, fine]))
    assert got.offer.candidate == fine
    assert [p.candidate for p in got.passed] == [tight]
    assert "keeps --clearance" in got.passed[0].note
    assert strict.offerable()[[tight, fine]].tolist() == [False, True]

    config = GoalConfig(allow_tight_goals=True)
    loose = AnswerGoals(GoalMaker.from_store(sample, config), cmap, None, PathConfig())
    assert first_offer(loose, np.array([tight, fine])).offer.candidate == tight
    assert loose.offer(tight).drive.keeps_clearance is False  # still flagged


def test_the_query_rrd_draws_the_candidates_of_its_goals(sample: Path, tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    from care_maps.query import load_map
    from care_maps.query.viz import ANSWER_ENTITY

    rrd = tmp_path / "q.rrd"
    args = ("query", sample, "chair", "--map", "grid", "--from", FREE_START, "--json")
    answer = json.loads(_care(*args, "--attempts", "3", "--rrd", rrd))
    got = {}
    for chunk in RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        for name in ("Points3D:positions", "Arrows3D:origins", "Points3D:labels"):
            if name in batch.schema.names:
                got[(str(chunk.entity_path), name)] = batch.column(name).to_pylist()[0]
    objects = np.array(got[(f"/{ANSWER_ENTITY}/candidates", "Points3D:positions")])
    arrows = np.array(got[(f"/{ANSWER_ENTITY}/goals", "Arrows3D:origins")])
    assert len(objects) == len(arrows) == 3
    np.testing.assert_allclose(arrows[0, :2], _xy(answer["goal"]["pose_stamped"]), atol=1e-5)
    cmap = load_map(sample, "grid")
    np.testing.assert_allclose(objects[0], cmap.positions[answer["candidate"]], atol=1e-5)
    for obj, arrow in zip(objects, arrows, strict=True):  # each object within reach of its goal
        assert np.hypot(*(obj[:2] - arrow[:2])) <= REACH + 1e-6


def test_the_python_answer_is_the_commands(sample: Path) -> None:
    """``answer_query`` from Python gives what ``care query --json`` prints: one assembly of
    the answer for both."""
    from care_maps.core.maps import MapKind
    from care_maps.query.paths import PathConfig
    from care_maps.replan.ask import answer_query

    printed = json.loads(
        _care("query", sample, "chair", "--map", "grid", "--json", "--from", FREE_START)
    )
    start = tuple(float(v) for v in FREE_START.split(","))
    found = answer_query(sample, "chair", kind=MapKind.GRID, paths=PathConfig(start=start))
    assert json.loads(json.dumps(found.as_dict())) == printed
