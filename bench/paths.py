"""Geodesic distances from a start to every candidate of a query (target: < 100 ms at 1M cells).

On square floors of 5 cm cells with 4 m rooms, walls, 1 m doors and clutter
(``bench/query.py``'s ``_floor``, 0.2% of the cells obstacles: a robot of 0.3 m radius
still gets through most of the floor), 100 objects at seeded places get their goals
(approach points, :class:`care_maps.query.goals.GoalMaker`'s rule) and the robot starts in the
middle of the floor. Timed:

- the roadmap (:meth:`care_maps.query.paths.Roadmap.from_free_space` and its graph): once per map
  and robot radius;
- a query: one search from the start (:meth:`care_maps.query.paths.Roadmap.travel`), the distance to
  each of the 100 goals and the path to the nearest reachable one; first from a start the
  roadmap has not searched from (the search, nearly all of it), then again from the same
  start (the roadmap keeps its last searches: a batch, a walk's next leg, a second query);
- side by side, the plain ways: scipy's whole-floor distance transform, a graph built from
  an edge list and the same search; and networkx (a graph of the passable cells and its
  single-source Dijkstra), its distances compared with ours;
- the search itself against other graph libraries on the same graph, each its own graph
  built once (not timed) and its fastest single-source call: python-igraph, networkit and
  scikit-image's ``MCP_Geometric`` on the grid (which cuts corners: its distances differ);
  a library that is not installed is left out (``pip install -e .[paths-bench]``).

Run: ``python bench/paths.py`` (``--sizes 250000`` for a quick look).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

# `bench/query.py` is named like the `query` package: keep this folder off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from bench.docs_section import add_docs_flag, recorded  # noqa: E402

SIZES = (250_000, 1_000_000, 4_000_000)
OBJECTS, CLUTTER = 100, 0.002
TARGET_MS = 100.0
"""The target: every candidate's distance at 1M cells within this."""


def _goals(space, n: int, seed: int = 1) -> list:
    """Goals (approach points) for ``n`` objects at seeded places on the floor."""
    from care_maps.query.goals import Goal, GoalConfig

    config = GoalConfig()
    side = space.layout.shape[0] * space.layout.cell_size
    goals = []
    for i, (x, y) in enumerate(np.random.default_rng(seed).uniform(0.5, side - 0.5, (n, 2))):
        found = space.approach((x, y), config)
        if found is None:
            goals.append(Goal(i, "map", 0, (x, y, 0.5), (x, y, 0.5), 0.0, False, None))
            continue
        gx, gy, clear = found
        yaw = math.atan2(y - gy, x - gx)
        goals.append(Goal(i, "map", 0, (x, y, 0.5), (gx, gy, 0.0), yaw, True, clear))
    return goals


def _best(fn, repeat: int = 3) -> tuple[float, object]:
    """Best wall time (ms) of ``repeat`` runs, and the last result."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times) * 1e3, out


def _query(roadmap, start, goals, reach: float, *, again: bool = False) -> np.ndarray:
    """What ``care query`` does per query: one search, every goal's distance, the path to
    the nearest reachable goal (``again``: the roadmap has searched from ``start`` before;
    else its kept searches are dropped first, as for a new start)."""
    if not again:
        roadmap._searches.clear()
    travel = roadmap.travel(start, reach)
    dist = travel.distances(goals)
    if np.isfinite(dist).any():
        travel.waypoints(goals[int(np.argmin(dist))])
    return dist


def _plain_scipy(space, clearance: float, start_cell: int, goal_cells: np.ndarray) -> np.ndarray:
    """The plain way with the same search: the whole floor's distance transform, an edge
    list of the passable cells' moves, a sparse matrix built from it."""
    from scipy import ndimage
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    size = space.layout.cell_size
    metres = ndimage.distance_transform_edt(~space.blocked) * size
    ok = space.free & (metres.astype(np.float32) >= clearance)
    nx, ny = ok.shape
    ids = np.arange(nx * ny).reshape(nx, ny)
    rows, cols, lengths = [], [], []
    for dx, dy in ((1, 0), (0, 1), (1, 1), (1, -1)):
        a = (slice(0, nx - dx), slice(max(-dy, 0), ny - max(dy, 0)))
        b = (slice(dx, nx), slice(max(dy, 0), ny + min(dy, 0) or None))
        move = ok[a] & ok[b]
        if dx and dy:
            move &= ok[b[0], a[1]] & ok[a[0], b[1]]
        rows.append(ids[a][move])
        cols.append(ids[b][move])
        lengths.append(np.full(int(move.sum()), size * math.hypot(dx, dy)))
    graph = coo_matrix(
        (np.concatenate(lengths), (np.concatenate(rows), np.concatenate(cols))),
        shape=(nx * ny, nx * ny),
    ).tocsr()
    return dijkstra(graph, directed=False, indices=start_cell)[goal_cells]


def _networkx(roadmap, start_cell: int, goal_cells: np.ndarray) -> tuple[float, float, np.ndarray]:
    """networkx: a graph of the moves, then its single-source Dijkstra (seconds each)."""
    import networkx as nx

    moves = roadmap.graph.tocoo()
    t0 = time.perf_counter()
    graph = nx.Graph()
    edges = zip(moves.row.tolist(), moves.col.tolist(), moves.data.tolist(), strict=True)
    graph.add_weighted_edges_from(edges)
    t1 = time.perf_counter()
    found = nx.single_source_dijkstra_path_length(graph, start_cell)
    t2 = time.perf_counter()
    return t1 - t0, t2 - t1, np.array([found.get(int(c), np.inf) for c in goal_cells])


def run(sizes, naive_max: int, library_max: int) -> None:
    from bench.query import _floor
    from care_maps.query.goals import GoalConfig
    from care_maps.query.paths import PathConfig, Roadmap

    clearance, reach = GoalConfig().clearance, PathConfig().start_reach
    print(
        f"5 cm cells, robot radius {clearance} m, {OBJECTS} objects a query, start mid-floor; "
        f"networkx up to {naive_max:,} cells, other libraries up to {library_max:,}"
    )
    print(
        "| cells | passable | roadmap ms (once a map) | query ms (search, distances, path) "
        "| again from the start ms | reached | plain scipy ms | x | "
        "networkx s (graph + search) | x | same distances |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    searches = []
    for n in sizes:
        space = _floor(n, clutter=CLUTTER)
        side = space.layout.shape[0] * space.layout.cell_size
        start = (side / 2, side / 2)
        goals = _goals(space, OBJECTS)
        build_ms, roadmap = _best(lambda s=space: _graph(Roadmap.from_free_space(s, clearance)))
        query_ms, dist = _best(lambda r=roadmap, s=start, g=goals: _query(r, s, g, reach))
        again_ms, _ = _best(
            lambda r=roadmap, s=start, g=goals: _query(r, s, g, reach, again=True), repeat=20
        )
        travel = roadmap.travel(start, reach)
        cells = np.array([travel.cell(g.position[:2]) if g.approach else 0 for g in goals])
        approach = np.array([g.approach for g in goals])
        on_graph = dist - travel.distance[travel.source]  # less the step onto the roadmap
        t0 = time.perf_counter()
        plain = _plain_scipy(space, clearance, travel.source, cells)
        plain_ms = (time.perf_counter() - t0) * 1e3
        ours_cold = build_ms + query_ms
        row = (
            f"| {space.free.size:,} | {roadmap.passable.mean():.0%} | {build_ms:.0f} | "
            f"{query_ms:.0f} | {again_ms:.2f} | {np.isfinite(dist).sum()}/{len(goals)} | "
            f"{plain_ms:,.0f} | x{plain_ms / ours_cold:.1f} |"
        )
        if n <= naive_max:
            graph_s, search_s, naive = _networkx(roadmap, travel.source, cells)
            naive = np.where(approach, naive, np.inf)
            same = _same(on_graph, naive) and _same(on_graph, np.where(approach, plain, np.inf))
            naive_ms = (graph_s + search_s) * 1e3
            row += (
                f" {graph_s:.1f} + {search_s:.1f} | x{naive_ms / ours_cold:,.0f} | "
                f"{'yes' if same else 'NO'} |"
            )
        else:
            row += " | | |"
        print(row)
        if n <= library_max:
            searches.append((n, roadmap, travel.source, cells, approach, on_graph))
    print(
        "x: the plain way's time over ours (roadmap + query: a first query on a map); "
        "distances compared to 1e-9 m, unreachable goals included"
    )
    _libraries(searches)


def _libraries(searches) -> None:
    """The search alone (what a query from a new start pays), scipy's against each other
    library's fastest single-source call on the same graph."""
    from scipy.sparse.csgraph import dijkstra

    if not searches:
        return
    names = [name for name, fn in LIBRARIES.items() if fn(None, 0, None) is not None]
    print(
        "| cells | scipy dijkstra ms | "
        + " | ".join(f"{name} ms | x | same distances" for name in names)
        + " |"
    )
    print("| --- | --- |" + " --- | --- | --- |" * len(names))
    for n, roadmap, source, cells, approach, on_graph in searches:
        ms, _ = _best(lambda g=roadmap.graph, s=source: dijkstra(g, indices=s))
        row = f"| {n:,} | {ms:.0f} |"
        for name in names:
            lib_ms, found = LIBRARIES[name](roadmap, source, cells)
            found = np.where(approach, found, np.inf)
            both = np.isfinite(found) & np.isfinite(on_graph)
            gap = float(np.abs(found[both] - on_graph[both]).max()) if both.any() else 0.0
            same = "yes" if _same(on_graph, found) else f"no: {gap:.2f} m apart at most"
            row += f" {lib_ms:,.0f} | x{lib_ms / ms:.1f} | {same} |"
        print(row)
    print(
        f"x: the library's time over scipy's; the target is {TARGET_MS:.0f} ms for every "
        "candidate of a query at 1M cells"
    )


def _igraph(roadmap, source: int, cells: np.ndarray):
    """python-igraph: an undirected graph of the moves (built once), ``distances``."""
    try:
        import igraph
    except ImportError:
        return None
    if roadmap is None:
        return True
    moves = roadmap.graph.tocoo()
    once = moves.row < moves.col
    graph = igraph.Graph(n=moves.shape[0], edges=np.c_[moves.row[once], moves.col[once]])
    graph.es["length"] = moves.data[once]
    targets = cells.tolist()
    ms, found = _best(lambda: graph.distances(source=int(source), target=targets, weights="length"))
    return ms, np.array(found[0], float)


def _networkit(roadmap, source: int, cells: np.ndarray):
    """networkit: a weighted graph of the moves (built once), its ``Dijkstra``."""
    try:
        import networkit
    except ImportError:
        return None
    if roadmap is None:
        return True
    moves = roadmap.graph.tocoo()
    once = moves.row < moves.col
    edges = (moves.row[once].astype(np.uint64), moves.col[once].astype(np.uint64))
    graph = networkit.GraphFromCoo(
        (moves.data[once], edges), n=moves.shape[0], weighted=True, directed=False
    )

    def search() -> np.ndarray:
        run = networkit.distance.Dijkstra(graph, int(source), storePaths=False)
        run.run()
        return np.asarray(run.getDistances())

    ms, found = _best(search)
    found = found[cells]
    return ms, np.where(found > 1e300, np.inf, found)  # its "unreachable" is the largest double


def _skimage(roadmap, source: int, cells: np.ndarray):
    """scikit-image's ``MCP_Geometric`` on the grid (cost 1 on passable cells, impassable
    elsewhere, 8 neighbours), stopping once every goal is reached."""
    try:
        from skimage.graph import MCP_Geometric
    except ImportError:
        return None
    if roadmap is None:
        return True
    cost = np.where(roadmap.passable, 1.0, np.inf)
    ny = roadmap.layout.shape[1]
    ends = [divmod(int(c), ny) for c in cells]

    def search() -> np.ndarray:
        found, _ = MCP_Geometric(cost, fully_connected=True).find_costs(
            [divmod(int(source), ny)], ends, find_all_ends=True
        )
        return found

    ms, found = _best(search)
    return ms, np.array([found[e] for e in ends]) * roadmap.layout.cell_size


LIBRARIES = {"igraph": _igraph, "networkit": _networkit, "scikit-image MCP": _skimage}
"""The search in other libraries: ``fn(roadmap, source, cells)`` gives (best ms, distances
of ``cells``); ``fn(None, ...)`` says whether the library is installed (None: not)."""


def _graph(roadmap):
    """The roadmap with its graph built (a cached property: timed with the roadmap)."""
    roadmap.graph  # noqa: B018
    return roadmap


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    both = np.isfinite(a) & np.isfinite(b)
    return bool(
        np.array_equal(np.isfinite(a), np.isfinite(b)) and np.allclose(a[both], b[both], atol=1e-9)
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument(
        "--naive-max", type=int, default=1_000_000, help="largest floor also run with networkx"
    )
    parser.add_argument(
        "--library-max",
        type=int,
        default=1_000_000,
        help="largest floor also searched with igraph, networkit and scikit-image",
    )
    add_docs_flag(parser)
    args = parser.parse_args()
    full = not args.no_docs and set(SIZES) <= set(args.sizes)  # fewer sizes: a quick look
    with recorded("paths", write=full):
        run(args.sizes, args.naive_max, args.library_max)


if __name__ == "__main__":
    main()
