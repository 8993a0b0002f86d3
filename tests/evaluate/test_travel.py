"""Travel in the evaluation: SPL by hand, walk lengths and approach cells against networkx
and the goals' own rule, the travel strategies, the paired SPL test against scipy and an
exact enumeration, and a small evaluation whose every walk is recomputed with networkx."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import networkx as nx
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from scipy import ndimage, stats

from care_maps.core.keys import GRID_ORIGIN_KEY, GRID_SHAPE_KEY
from care_maps.core.store import read_table, write_table_atomic
from care_maps.evaluate.config import EvalConfig, TravelStart
from care_maps.evaluate.job import run_eval
from care_maps.evaluate.paired import compare_measure, comparison_rng, wilcoxon_signed_rank
from care_maps.evaluate.report import per_query
from care_maps.evaluate.spl import episode_paths, shortest_to_success, spl, success_within
from care_maps.evaluate.travel import scene_travel
from care_maps.fuse.layout import GridLayout
from care_maps.query import load_map
from care_maps.query.goals import FreeSpace, GoalConfig, GoalMaker
from care_maps.query.paths import Roadmap
from care_maps.query.travel import Legs, approach_cells, largest_region
from care_maps.replan.attempts import Walk, run_attempts
from care_maps.replan.strategies import STRATEGIES, Situation, StrategyName, travel_score
from care_maps.runtime.execution import Execution

CELL = 0.5


# -- SPL by hand ----------------------------------------------------------------------------


def test_spl_by_hand() -> None:
    """Anderson et al.'s S l / max(p, l), worked by hand: a walk of 5 m where 4 m would do
    scores 0.8; a failure 0; no reachable success 0; starting on the success, 1; unknown NaN."""
    solved = np.array([1, 1, 0, 0, 1, 1])
    shortest = np.array([4.0, 4.0, 4.0, np.inf, 0.0, np.nan])
    path = np.array([5.0, 3.0, 9.0, 2.0, 0.0, 1.0])
    np.testing.assert_allclose(spl(solved, shortest, path), [0.8, 1.0, 0, 0, 1.0, np.nan])


def test_episode_paths_skip_unreachable_legs() -> None:
    """Legs of 2 m, an unreachable goal, then 3 m to a success: 5 m walked, solved; a success
    at the unreachable goal is not one the robot reached."""
    distance = np.array([[2.0, np.inf, 3.0], [2.0, np.inf, np.nan]])
    success = np.array([[False, False, True], [False, True, False]])
    made = np.array([[True, True, True], [True, True, False]])
    path, solved = episode_paths(distance, success, made)
    np.testing.assert_allclose(path, [5.0, 2.0])
    np.testing.assert_array_equal(solved, [True, False])
    start = np.array([[3.0, 1.0, np.inf], [3.0, 1.0, np.inf]])
    np.testing.assert_allclose(shortest_to_success(start, success), [np.inf, 1.0])
    np.testing.assert_allclose(success_within([1.0, 3.0], [True, True], [0, 2, 5]), [0, 0.5, 1])


# -- walks against networkx -------------------------------------------------------------------


def _space(obstacle: np.ndarray, seen: np.ndarray | None = None) -> FreeSpace:
    ix, iy = (a.reshape(-1) for a in np.indices(obstacle.shape))
    keep = np.ones(ix.size, bool) if seen is None else seen.reshape(-1)
    layout = GridLayout(CELL / 5, (-1.0, 2.0), obstacle.shape)
    return FreeSpace.from_cells(layout, ix[keep], iy[keep], obstacle.reshape(-1)[keep])


def _floor() -> np.ndarray:
    """A 3 x 2 m floor of 0.1 m cells: a wall with a door, and a closed room in a corner."""
    obstacle = np.zeros((30, 20), bool)
    obstacle[15, :] = True
    obstacle[15, 8:14] = False
    obstacle[22:30, 12] = obstacle[22, 12:20] = True
    obstacle[29, 12:20] = obstacle[22:30, 19] = True
    return obstacle


def _graph(passable: np.ndarray, size: float) -> nx.Graph:
    """The robot's moves, built apart: 8 neighbours, no corner cutting."""
    graph = nx.Graph()
    n_x, n_y = passable.shape
    for x, y in zip(*np.nonzero(passable), strict=True):
        graph.add_node((x, y))
        for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
            u, v = x + dx, y + dy
            if not (0 <= u < n_x and 0 <= v < n_y and passable[u, v]):
                continue
            if dx and dy and not (passable[u, y] and passable[x, v]):
                continue
            graph.add_edge((x, y), (u, v), weight=size * math.hypot(dx, dy))
    return graph


def _passable(space: FreeSpace, clearance: float) -> np.ndarray:
    metres = ndimage.distance_transform_edt(~space.blocked) * space.layout.cell_size
    return space.free & (metres.astype(np.float32) >= clearance)


@pytest.mark.parametrize("seed", [0, 1])
def test_legs_and_approach_cells_match_networkx_and_the_goals(seed: int) -> None:
    """Every candidate's approach cell is the cell of GoalMaker's goal (or -1 where that goal
    is no cell a robot stands on), and the legs between goals are networkx's distances."""
    rng = np.random.default_rng(seed)
    obstacle = _floor() | (rng.random((30, 20)) < 0.04)
    space = _space(obstacle)
    config = GoalConfig(clearance=0.1, reach=0.5)
    roadmap = Roadmap.from_free_space(space, config.clearance)
    ok = _passable(space, config.clearance)
    np.testing.assert_array_equal(roadmap.passable, ok)
    targets = rng.uniform((-1.0, 2.0), (2.0, 4.0), (40, 2))
    cells = approach_cells(roadmap, targets, config.reach)
    n_y = space.layout.shape[1]
    for target, cell in zip(targets, cells, strict=True):
        found = space.approach(tuple(target), config)
        if found is None:
            assert cell == -1
            continue
        cx, cy = roadmap.cell_of(found[:2])
        assert cell == (cx * n_y + cy if ok[cx, cy] else -1)
    graph = _graph(ok, space.layout.cell_size)
    legs = Legs(roadmap, cells, 0.5)
    some = [i for i, c in enumerate(cells) if c >= 0][:6]
    got = legs.from_goals(np.array(some))
    for row, i in zip(got, some, strict=True):
        source = divmod(int(cells[i]), n_y)
        want = nx.single_source_dijkstra_path_length(graph, source)
        for j, c in enumerate(cells):
            expect = want.get(divmod(int(c), n_y), math.inf) if c >= 0 else math.inf
            assert row[j] == pytest.approx(expect, abs=1e-9)
    assert np.array_equal(legs.from_goals(np.array(some)), got)  # the cache
    region = largest_region(roadmap)
    biggest = max(nx.connected_components(graph), key=len)
    assert {divmod(int(c), n_y) for c in region} == biggest


# -- the walk in the attempts and the travel rules --------------------------------------------


def test_an_unreachable_goal_leaves_the_robot_where_it_was() -> None:
    """Three candidates on a line: 0 (failure, unreachable), 1 (failure) and 2 (success).
    Max confidence tries 0, 1, 2: the second leg starts at the start again, the third at 1."""
    conf = np.array([[0.9, 0.8, 0.7]])
    success = np.array([[False, False, True]])
    start = np.array([[np.inf, 2.0, 5.0]])
    between = {1: np.array([np.inf, 0.0, 3.0]), 2: np.array([np.inf, 3.0, 0.0])}
    asked = []

    def legs(ids: np.ndarray) -> np.ndarray:
        asked.extend(ids.tolist())
        return np.stack([between[int(i)] for i in ids])

    res = run_attempts(
        StrategyName.MAX_CONFIDENCE, conf, success, {}, attempts=3, walk=Walk(start, legs)
    )
    np.testing.assert_array_equal(res.candidate, [[0, 1, 2]])
    np.testing.assert_allclose(res.distance, [[np.inf, 2.0, 3.0]])
    assert asked == [1]  # the unreachable goal was never stood on, the last needs no leg


def test_nearest_and_travel_aware_rules() -> None:
    """``nearest_topk`` takes the nearest reachable member; the travel-aware score is
    rank / (|S| - 1) + d / d_max, worked by hand; without distances each rule is its CARe rule."""
    conf = np.array([[0.5, 0.4, 0.3, 0.2]])
    cset = np.array([[False, True, True, True]])
    stderr = np.array([0.1, 0.2, 0.3, 0.4])  # min stderr ranks 1, 2, 3 as 0, 1, 2
    distance = np.array([[0.0, 8.0, 2.0, np.inf]])
    situation = Situation(conf, cset | [[True, False, False, False]], cset, {"stderr": stderr},
                          distance=distance)  # fmt: skip
    nearest = STRATEGIES[StrategyName.NEAREST_TOPK].rule(situation)
    assert nearest.candidate[0] == 2
    rank = np.array([[-1, 0, 1, 2]])
    score = travel_score(rank, distance)
    np.testing.assert_allclose(score, [[np.nan, 0 + 8 / 8, 0.5 + 2 / 8, np.inf]])
    near = STRATEGIES[StrategyName.MIN_STDERR_NEAR].rule(situation)
    assert near.candidate[0] == 2
    assert near.value[0] == pytest.approx(0.75)
    blind = Situation(conf, situation.available, cset, {"stderr": stderr})
    assert STRATEGIES[StrategyName.MIN_STDERR_NEAR].rule(blind).candidate[0] == 1
    assert STRATEGIES[StrategyName.NEAREST_TOPK].rule(blind).candidate[0] == 1  # confidence
    lost = Situation(conf, situation.available, cset, {"stderr": stderr},
                     distance=np.full((1, 4), np.inf))  # fmt: skip
    assert STRATEGIES[StrategyName.MIN_STDERR_NEAR].rule(lost).candidate[0] == 1


# -- the paired SPL test ------------------------------------------------------------------------


def _exact_wilcoxon(d: np.ndarray) -> float:
    """Two-sided exact signed-rank p-value by enumerating every sign pattern (no ties)."""
    d = d[d != 0]
    ranks = stats.rankdata(np.abs(d))
    w = ranks[d > 0].sum()
    signs = np.array(list(itertools.product([False, True], repeat=len(d))))
    totals = (signs * ranks).sum(axis=1)
    low, high = np.mean(totals <= w), np.mean(totals >= w)
    return min(1.0, 2 * min(low, high))


def test_the_paired_spl_test_is_scipys_wilcoxon() -> None:
    rng = np.random.default_rng(5)
    a = rng.random(12)
    b = a + rng.normal(0.1, 0.2, 12)
    b[:3] = a[:3]  # ties at zero (queries both rules walk alike) are dropped
    p = wilcoxon_signed_rank(a, b)
    assert p == pytest.approx(_exact_wilcoxon(a - b), rel=1e-9)
    d = (a - b)[a != b]
    assert p == pytest.approx(stats.wilcoxon(d, zero_method="wilcox").pvalue)
    assert wilcoxon_signed_rank(a, a) == 1.0
    res = compare_measure(np.r_[a, np.nan], np.r_[b, 0.5], rng=comparison_rng(0, "x"),
                          n_resamples=500)  # fmt: skip
    assert res.n == 12
    assert res.diff == pytest.approx(np.mean(a - b))
    assert res.lo <= res.diff <= res.hi
    assert (res.better, res.worse) == (int(np.sum(a > b)), int(np.sum(a < b)))


# -- a small evaluation, every walk recomputed ----------------------------------------------------


def _add_free_space(store: Path) -> np.ndarray:
    """Give the hand-made grid (20 x 10 cells of 0.5 m) its obstacle layers: a wall between
    the rooms with a door, the four cells round each object, and a closed corner pocket."""
    cells = read_table(store / "cells.parquet")
    x = cells.column("x").to_numpy().astype(np.float64)
    y = cells.column("y").to_numpy().astype(np.float64)
    ix, iy = np.floor(x / CELL).astype(np.int32), np.floor(y / CELL).astype(np.int32)
    obstacle = np.zeros((20, 10), bool)
    obstacle[10, :] = True
    obstacle[10, 4:6] = False  # the door
    for cx, cy in [(1, 1), (3, 2), (2, 4), (7, 1), (8, 3), (6, 4)]:
        obstacle[2 * cx - 1 : 2 * cx + 1, 2 * cy - 1 : 2 * cy + 1] = True
    obstacle[17, 7:] = obstacle[17:, 7] = True  # cells ix 18-19, iy 8-9 closed in
    table = cells.append_column("ix", pa.array(ix)).append_column("iy", pa.array(iy))
    table = table.append_column("obstacle", pa.array(obstacle[ix, iy]))
    md = dict(cells.schema.metadata or {})
    md[GRID_SHAPE_KEY] = json.dumps([20, 10]).encode()
    md[GRID_ORIGIN_KEY] = json.dumps([0.0, 0.0]).encode()
    write_table_atomic(table, store / "cells.parquet", md)
    return obstacle


def test_a_small_evaluation_walks_as_networkx_says(dataset, tmp_path: Path, run_cli) -> None:
    store = dataset / "stores" / "scene_0"
    obstacle = _add_free_space(store)
    config = EvalConfig(
        strategies=(StrategyName.NO_REPLAN, StrategyName.ORACLE, StrategyName.MAX_CONFIDENCE,
                    StrategyName.RANDOM, StrategyName.NEAREST_TOPK, StrategyName.MIN_STDERR,
                    StrategyName.MIN_STDERR_NEAR),
        k_instances=(2,), k_grid=(4,), attempts=3, seeds=2, bootstrap=50,
        travel_start=TravelStart.FREE_SPACE,
    )  # fmt: skip
    report = run_eval(store, config, tmp_path / "eval", run=Execution(workers=1, progress=False))
    assert "## Travel: path length and SPL" in report.markdown
    assert "Min stderr, travel-aware" in report.travel
    assert (tmp_path / "eval" / "plots" / "travel_grid_exclude-1m.png").is_file()
    pairs = pq.read_table(tmp_path / "eval" / "paired_spl.parquet").to_pylist()
    assert pairs
    assert all(0 <= r["wilcoxon_p"] <= 1 for r in pairs)

    attempts = pq.read_table(tmp_path / "eval" / "attempts.parquet").to_pylist()
    space = FreeSpace.from_cells(
        GridLayout(CELL, (0.0, 0.0), (20, 10)), *np.indices((20, 10)).reshape(2, -1),
        obstacle.reshape(-1),
    )  # fmt: skip
    graph = _graph(_passable(space, config.clearance), CELL)
    maker = GoalMaker.from_store(store, GoalConfig(clearance=config.clearance))
    maps = {kind: load_map(store, kind) for kind in config.maps}
    walks = {kind: scene_travel(store, maps[kind], config) for kind in config.maps}

    def node(kind: str, candidate: int):
        goal = maker.goal(maps[kind], candidate)
        cell = tuple(int(v) for v in np.floor(np.array(goal.position[:2]) / CELL))
        return cell if goal.approach and cell in graph else None

    def metres(a, b) -> float:
        if a is None or b is None:
            return math.inf
        try:
            return nx.dijkstra_path_length(graph, a, b)
        except nx.NetworkXNoPath:
            return math.inf

    checked = 0
    by_episode: dict[tuple, list[dict]] = {}
    for r in attempts:
        key = (r["map"], r["protocol"], r["unit"], r["query"], r["strategy"], r["criterion"],
               r["k"], r["seed"])  # fmt: skip
        by_episode.setdefault(key, []).append(r)
    for (kind, protocol, unit, query, *_), rows in by_episode.items():
        here = divmod(walks[kind]._start_cell("scene_0", kind, protocol, unit, query), 10)
        walked = 0.0
        for r in sorted(rows, key=lambda r: r["attempt"]):
            goal = node(kind, r["candidate"]) if r["candidate"] >= 0 else None
            leg = metres(here, goal)
            assert r["distance"] == pytest.approx(leg, rel=1e-6), (query, r)
            if math.isfinite(leg):
                walked += leg
                here = goal
            assert r["walked"] == pytest.approx(walked, rel=1e-6)
            checked += 1
    assert checked == len(attempts)
    queries = per_query(pq.read_table(tmp_path / "eval" / "attempts.parquet")).to_pylist()
    for q in queries:  # SPL by hand from the rows: S at a goal reached, p walked, l shortest
        key = tuple(
            q[c] for c in ("map", "protocol", "unit", "query", "strategy", "criterion", "k")
        )
        values = []
        for episode, rows in by_episode.items():
            if episode[:7] != key:
                continue
            hit = any(r["success"] and math.isfinite(r["distance"]) for r in rows)
            p, l_ = max(r["walked"] for r in rows), rows[0]["shortest"]
            values.append(0.0 if not hit or math.isinf(l_) else l_ / max(p, l_) if p or l_ else 1.0)
        assert q["spl"] == pytest.approx(np.mean(values), rel=1e-5), key
    xy = maps["grid"].positions[:, :2]
    pocket = (xy[:, 0] > 9) & (xy[:, 1] > 4)
    assert pocket.sum() == 4
    assert np.isinf(walks["grid"].legs.from_point((1.25, 2.25))[pocket]).all()

    code, out, err = run_cli("eval", str(store), "--out", str(tmp_path / "cli"),
                             "--strategies", "max_confidence", "--strategies", "nearest_topk",
                             "--travel-start", "free_space", "--seeds", "1", "--bootstrap", "20",
                             "--workers", "1")  # fmt: skip
    assert code == 0, err
    assert "SPL" in out
    assert "Nearest of top-k" in out


def test_no_walks_without_free_space_or_when_off(dataset) -> None:
    """A store without the grid's obstacle layers, or travel off, walks nowhere (NaN in the
    report); a start that is no TravelStart is one error."""
    from care_maps.core.errors import EvalError

    store = dataset / "stores" / "scene_1"
    cmap = load_map(store, "grid")
    assert scene_travel(store, cmap, EvalConfig(travel_start=TravelStart.FREE_SPACE)) is None
    _add_free_space(store)
    assert scene_travel(store, cmap, EvalConfig(travel_start=TravelStart.OFF)) is None
    assert scene_travel(store, cmap, EvalConfig()) is None  # first pose: the store has no views
    assert scene_travel(store, cmap, EvalConfig(travel_start="free_space")) is not None
    with pytest.raises(EvalError, match="--travel-start"):
        EvalConfig(travel_start="nowhere")
