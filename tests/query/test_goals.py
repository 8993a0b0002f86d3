"""Goal poses: approach points in free space against a brute-force search, PoseStamped
orientation against scipy's rotations, and the CLI's JSON on a fused grid."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from care_maps.core.errors import QueryError
from care_maps.fuse.layout import GridLayout
from care_maps.query.goals import FreeSpace, Goal, GoalConfig, GoalMaker, squared_distances
from care_maps.query.map import CandidateMap

CELL = 0.1
SHAPE = (20, 16)  # nx, ny
ORIGIN = (-1.0, 2.0)


def _room() -> tuple[FreeSpace, np.ndarray, np.ndarray]:
    """A 2 x 1.6 m patch, all seen, with a 0.3 x 0.2 m object and a wall along x = max."""
    ix, iy = (a.reshape(-1) for a in np.meshgrid(np.arange(20), np.arange(16), indexing="ij"))
    obstacle = ((ix >= 8) & (ix <= 10) & (iy >= 7) & (iy <= 8)) | (ix == 19)
    seen = ~((ix < 2) & (iy < 2))  # an unseen corner
    layout = GridLayout(CELL, ORIGIN, SHAPE)
    space = FreeSpace.from_cells(layout, ix[seen], iy[seen], obstacle[seen])
    return space, np.stack([ix, iy], 1)[seen], obstacle[seen]


def _brute_force(cells, obstacle, target, clearance, reach):
    """Plain loops: the nearest free cell within reach keeping the clearance."""
    centre = lambda c: (ORIGIN[0] + (c[0] + 0.5) * CELL, ORIGIN[1] + (c[1] + 0.5) * CELL)  # noqa: E731
    blocked = [centre(c) for c, o in zip(cells, obstacle, strict=True) if o]
    best = None
    for c, o in zip(cells, obstacle, strict=True):
        if o:
            continue
        x, y = centre(c)
        d = math.hypot(x - target[0], y - target[1])
        clear = min(math.hypot(x - bx, y - by) for bx, by in blocked)
        if d <= reach and clear >= clearance - 1e-6 and (best is None or d < best[0] - 1e-12):
            best = (d, x, y, clear)
    return best


@pytest.mark.parametrize(("clearance", "reach"), [(0.0, 1.0), (0.3, 1.0), (0.45, 0.8)])
def test_approach_point_is_the_nearest_safe_free_cell(clearance: float, reach: float) -> None:
    space, cells, obstacle = _room()
    target = (ORIGIN[0] + 0.95, ORIGIN[1] + 0.8)  # the object's centre
    got = space.approach(target, GoalConfig(clearance=clearance, reach=reach))
    want = _brute_force(cells, obstacle, target, clearance, reach)
    assert got is not None
    assert want is not None
    assert got[:2] == pytest.approx(want[1:3], abs=1e-9)
    assert got[2] == pytest.approx(want[3], abs=1e-6)
    assert got[2] >= clearance - 1e-6


def test_no_free_cell_within_reach_means_the_object_itself() -> None:
    space, _, _ = _room()
    cmap = _one_candidate_map((ORIGIN[0] + 9.0, ORIGIN[1] + 9.0, 0.4))  # far outside the grid
    goal = GoalMaker("map", 5, space).goal(cmap, 0)
    assert not goal.approach
    assert goal.position == goal.target
    assert goal.clearance is None


def _one_candidate_map(position) -> CandidateMap:
    return CandidateMap(
        kind="grid", vocabulary=("chair",), text=np.ones((1, 2), np.float32), logit_scale=1.0,
        features=np.ones((1, 2), np.float32), log_norm=np.zeros(1, np.float32),
        top_classes=np.zeros((1, 1), np.int16), entropy=np.zeros(1, np.float32),
        stderr=np.zeros(1, np.float32), pwkl=np.zeros(1, np.float32),
        num_views=np.ones(1, np.int32), positions=np.array([position], np.float32),
    )  # fmt: skip


def test_pose_stamped_faces_the_object() -> None:
    space, _, _ = _room()
    target = (ORIGIN[0] + 0.95, ORIGIN[1] + 0.8, 0.5)
    goal = GoalMaker("odom", 1_700_000_001_250_000_000, space).goal(_one_candidate_map(target), 0)
    msg = goal.pose_stamped()
    assert msg["header"] == {
        "frame_id": "odom",
        "stamp": {"sec": 1_700_000_001, "nanosec": 250_000_000},
    }
    q = msg["pose"]["orientation"]
    heading = Rotation.from_quat([q["x"], q["y"], q["z"], q["w"]]).apply([1.0, 0.0, 0.0])
    p = msg["pose"]["position"]
    to_target = np.array([target[0] - p["x"], target[1] - p["y"], 0.0])
    np.testing.assert_allclose(heading, to_target / np.linalg.norm(to_target), atol=1e-6)
    assert p["z"] == 0.0  # on the floor
    assert goal.approach


def test_bad_goal_settings_are_one_clear_error() -> None:
    with pytest.raises(QueryError, match="clearance"):
        GoalConfig(clearance=float("nan"))
    with pytest.raises(QueryError, match="reach"):
        GoalConfig(reach=0.0)
    with pytest.raises(QueryError, match="not in the map"):
        GoalMaker("map", 0, None).goal(_one_candidate_map((0, 0, 0)), 3)


def test_goal_dataclass_round_trips_as_json() -> None:
    import json

    goal = Goal(2, "map", 10, (1.0, 2.0, 0.5), (0.5, 2.0, 0.0), 0.0, True, 0.4)
    assert json.loads(json.dumps(goal.as_dict()))["pose_stamped"]["pose"]["orientation"]["w"] == 1.0


def _whole_grid_approach(space: FreeSpace, target, config: GoalConfig):
    """The approach point from a distance transform of the whole grid (scipy's), as goals
    were made before the clearance was computed around each goal, searched over every cell
    (row-major, as a window is: the same first cell among ties)."""
    from scipy import ndimage

    size, (ox, oy) = space.layout.cell_size, space.layout.origin
    whole = ndimage.distance_transform_edt(~space.blocked) * size
    clear = (whole if space.blocked.any() else np.full(whole.shape, np.inf)).astype(np.float32)
    cx, cy = (a + 0.5 for a in np.indices(space.blocked.shape))
    px, py = ox + cx * size, oy + cy * size
    dist = np.hypot(px - target[0], py - target[1])
    ok = (space.free & (dist <= config.reach)).reshape(-1)
    if not ok.any():
        return None
    safe = ok & (clear.reshape(-1) >= config.clearance)
    pool, key = (safe, dist.reshape(-1)) if safe.any() else (ok, -clear.reshape(-1))
    best = np.flatnonzero(pool)[np.argmin(key[pool])]
    return float(px.flat[best]), float(py.flat[best]), float(clear.flat[best])


@pytest.mark.parametrize("density", [0.0, 0.0005, 0.01, 0.2])
def test_clearance_around_a_goal_is_the_whole_grids(density: float) -> None:
    """Clearance is computed in a window around each goal, widened while an obstacle beyond
    it could matter: the goals, clearance included, equal those of a distance transform of
    the whole grid, on grids from obstacle-free to cluttered (far obstacles force widening)."""
    rng = np.random.default_rng(int(density * 1e4))
    nx, ny, size = 300, 220, 0.05
    layout = GridLayout(size, (-3.0, 1.0), (nx, ny))
    ix, iy = (a.reshape(-1) for a in np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"))
    seen = rng.random(ix.size) < 0.9
    obstacle = rng.random(ix.size) < density
    obstacle[(ix > 140) & (ix < 150) & (iy > 60) & (iy < 160)] |= density > 0  # a wall
    space = FreeSpace.from_cells(layout, ix[seen], iy[seen], obstacle[seen])
    for _ in range(40):
        target = (
            -3.0 + rng.uniform(-0.5, nx * size + 0.5),
            1.0 + rng.uniform(-0.5, ny * size + 0.5),
        )
        config = GoalConfig(clearance=float(rng.choice([0.0, 0.3, 1.2, 4.0])), reach=1.0)
        got = space.approach(target, config)
        want = _whole_grid_approach(space, target, config)
        assert got == want, (target, config)


def test_squared_distances_are_scipys_transform() -> None:
    """Clearances are the roots of scipy's squared distances bit for bit, on grids of every
    shape and density (a lone obstacle, a crowded floor); with ``below``, exactly which
    cells lie nearer than it."""
    from scipy import ndimage

    rng = np.random.default_rng(0)
    for _ in range(1500):
        nx, ny = (int(n) for n in rng.integers(1, 70, 2))
        blocked = rng.random((nx, ny)) < rng.choice([0.001, 0.01, 0.05, 0.2, 0.6, 0.95])
        blocked[rng.integers(nx), rng.integers(ny)] = True
        ours = squared_distances(blocked)
        theirs = ndimage.distance_transform_edt(~blocked)
        assert np.array_equal(np.sqrt(ours.astype(np.float64)), theirs)
        below = int(rng.integers(1, 60))
        assert np.array_equal(squared_distances(blocked, below=below) < below, ours < below)
