"""``care query`` and ``care replan``: ask a map where the object is, and where to look
next after a failed attempt.

The options are generated from the configs (:mod:`care_maps.cli.options`):
:class:`care_maps.replan.batch.BatchConfig`, :class:`care_maps.replan.attempts.ReplanConfig`,
:class:`care_maps.query.goals.GoalConfig` and :class:`care_maps.query.paths.PathConfig`. Stage
modules are imported inside the commands so ``care --help`` stays fast.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any, NoReturn

import typer

from care_maps.cli.choices import MapKind
from care_maps.cli.options import Options, config_options, point_xy, with_choices
from care_maps.query.goals import GoalConfig
from care_maps.query.paths import PathConfig
from care_maps.replan.attempts import ReplanConfig
from care_maps.replan.batch import BatchConfig

__all__ = ["register"]

StoreArg = Annotated[Path, typer.Argument(help="Store directory with fused maps (`care fuse`).")]
TextArg = Annotated[str, typer.Argument(help="What to look for: a class name or free text.")]
MapOpt = Annotated[MapKind, typer.Option("--map", help=with_choices("Map to ask.", MapKind))]
WeightsOpt = Annotated[
    Path | None,
    typer.Option(
        help="The store's CLIP weights directory, if it moved since ingest (free text is "
        "embedded by the store's own model)."
    ),
]


def _resolve(store: Path, kind: str, text: str, weights: Path | None = None) -> Any:
    """The map's :class:`care_maps.query.openvocab.QueryTarget` for the text: a vocabulary class, or
    free text joining the vocabulary through the store's own text encoder (printed)."""
    from care_maps.query import load_map
    from care_maps.query.openvocab import open_query

    cmap = load_map(store, MapKind(kind).value, weights=weights)  # type: ignore[arg-type]
    target = open_query(cmap, text)
    if target.match.method != "vocabulary":
        typer.echo(f"query {target.match.describe()}", err=True)
    return target


AnswerRrdOpt = Annotated[
    Path | None,
    typer.Option(
        "--rrd",
        help="Also draw the answer in this Rerun file (open with `rerun FILE`): the start, "
        "each attempt's goal and its way over the floor, coloured by order.",
    ),
]

_BATCH = {
    "k": {"flags": ("-k",), "min": 1},
    "attempts": {"min": 1},
    "top": {"min": 1},
}
_GOAL = ("clearance", "frame_id", "allow_tight_goals")
_TIGHT = {"allow_tight_goals": {"flags": ("--allow-tight-goals",)}}
"""One flag, not a switch both ways: off is the default a robot relies on."""
_FROM = {"start": {"flags": ("--from",)}}
_XY = {"start": point_xy}
"""``--from``: one map position x,y, refused while the command line is read (naming ``--from``)."""


@config_options("path", PathConfig, only=("start",), extra=_FROM, parse=_XY)
@config_options("goal", GoalConfig, only=_GOAL, extra=_TIGHT)
@config_options("settings", BatchConfig, only=("top", "k", "attempts", "exclude_radius", "seed"),
                extra=_BATCH)  # fmt: skip
def query(
    store: StoreArg,
    text: Annotated[
        str | None,
        typer.Argument(help="What to look for: a class name or free text (not with --batch)."),
    ] = None,
    kind: MapOpt = MapKind.INSTANCES,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
    settings: Options[BatchConfig] = None,  # type: ignore[assignment]
    goal: Options[GoalConfig] = None,  # type: ignore[assignment]
    path: Options[PathConfig] = None,  # type: ignore[assignment]
    weights: WeightsOpt = None,
    batch: Annotated[
        Path | None,
        typer.Option(
            help="Answer many queries at once: a text file (one query a line) or a CSV with a "
            "'query' column and optional 'visited' places 'x,y;x,y'. Writes --out."
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(help="Parquet table of a --batch run (default: BATCH.answers.parquet)."),
    ] = None,
    rrd: AnswerRrdOpt = None,
) -> None:
    """Rank a map's candidates by confidence for TEXT, with their uncertainty measures, a
    goal pose for each (``geometry_msgs/PoseStamped`` JSON with --json), the clearance it
    keeps, its distance along free space from --from (default: the recording's first pose),
    and the first attempt: the best-ranked candidate whose goal keeps --clearance and is
    reachable, with its path (``nav_msgs/Path``), saying which were passed over and why; with --batch, every query's ranking and each strategy's attempt
    sequence as a Parquet table, each row with its distance from the start. --rrd draws the
    first --attempts attempts by max confidence, each driven from where the last ended."""

    if (batch is None) == (text is None):
        _fail("give either TEXT or --batch FILE")
    if batch is not None and rrd is not None:
        _fail("--rrd draws one answer: give TEXT, not --batch")
    _check_rrd(rrd, store)
    config, paths = settings.config(), path.config()
    if batch is not None:
        _batch(store, kind, batch, out, weights, goal.config(), config, paths)
        return
    target = _resolve(store, kind, text, weights)
    answer = _answer_goals(store, target.cmap, goal.config(), paths)
    ranking, first = _first_offer(answer, target.confidence())
    rows = [_row(answer, target, ranking, int(c)) for c in ranking.order[: config.top]]
    result = {
        "query": text,
        "class": target.match.names[0],
        "method": target.match.method,
        "frame_id": answer.goals.frame_id,
        "candidates": rows,
        **_offered(answer, first, ranking),
    }
    if rrd is not None:
        from care_maps.cli.answer_rrd import query_rrd

        query_rrd(rrd, store, target, answer, config, first, ranking, result["path_note"])
    if as_json:
        typer.echo(json.dumps(result))
        return
    _print_table(answer, kind, target, result)


def _print_table(answer: Any, kind: str, target: Any, result: dict) -> None:
    """``care query``'s table: a row per candidate (its goal, the clearance the goal keeps,
    ``!`` below --clearance, the metres to it, ``-``: none), then the first attempt, the
    candidates passed over and each row's note."""
    cmap, frame = target.cmap, answer.goals.frame_id
    typer.echo(
        f"{MapKind(kind).value} map, class {target.match.names[0]!r}: {cmap.num_candidates} "
        f"candidates (positions and goals in {frame!r})"
    )
    typer.echo(
        "rank  cand  confidence  entropy   stderr     pwkl  views  position  "
        "goal (x, y, yaw deg)  clear m  path m"
    )
    for r in result["candidates"]:
        goal = r["goal"]
        pose = goal["pose_stamped"]["pose"]["position"]
        dist = "-" if r["distance"] is None else f"{r['distance']:.2f}"
        if r["reachable_distance"] is not None:
            dist = f"{r['reachable_distance']:.2f}*"
        clear = "-" if goal["clearance"] is None else f"{goal['clearance']:.2f}"
        clear += "!" if goal["clearance_ok"] is False else " "
        typer.echo(
            f"{r['rank']:>4} {r['candidate']:>5} {r['confidence']:>11.4g} {r['entropy']:>8.3f} "
            f"{r['stderr']:>8.4g} {r['pwkl']:>8.4g} {r['num_views']:>6}  {r['position']}  "
            f"({pose['x']:.2f}, {pose['y']:.2f}, {math.degrees(goal['yaw']):.0f})  {clear:>7}  "
            f"{dist}"
        )
    for line in _summary(answer, result):
        typer.echo(line)


def _summary(answer: Any, result: dict) -> list[str]:
    """The lines under the table: what the first attempt is, what was passed over and why,
    each row's note (``*``: the metres to the reachable goal the note names)."""
    lines = []
    if result["candidate"] is not None:
        pose = result["goal"]["pose_stamped"]["pose"]["position"]
        way = "-" if result["distance"] is None else f"{result['distance']:.2f} m"
        lines.append(
            f"first attempt: candidate {result['candidate']} (rank {result['rank']}), goal "
            f"({pose['x']:.2f}, {pose['y']:.2f}), path {way}"
        )
    passed = [f"#{p['rank']} {p['candidate']} ({p['path_state']})" for p in result["passed_over"]]
    if result["passed_over_more"]:
        passed.append(f"and {result['passed_over_more']} more")
    if passed:
        lines.append(
            f"passed over (no goal that keeps --clearance and is reachable): {', '.join(passed)}"
        )
    notes = [
        f"  #{r['rank']} {r['candidate']}: {r['path_note']}"
        for r in result["candidates"]
        if r["path_note"] is not None and r["path_note"] != answer.start_note
    ]
    if notes:
        lines += ["notes:", *notes]
    if result["path_note"] is not None:
        lines.append(result["path_note"])
    return lines


@config_options("path", PathConfig, only=("start",), extra=_FROM, parse=_XY)
@config_options("goal", GoalConfig, only=_GOAL, extra=_TIGHT)
@config_options("settings", ReplanConfig, extra={"k": _BATCH["k"]})
def replan(
    store: StoreArg,
    text: TextArg,
    visited: Annotated[
        list[str] | None,
        typer.Option(
            help="Where the robot already looked without finding it (repeat the option): a "
            "candidate id (12) or a map position x,y in metres (1.5,-2.0); the candidates within "
            "--exclude-radius of a position count as visited."
        ),
    ] = None,
    settings: Options[ReplanConfig] = None,  # type: ignore[assignment]
    kind: MapOpt = MapKind.INSTANCES,
    goal: Options[GoalConfig] = None,  # type: ignore[assignment]
    path: Options[PathConfig] = None,  # type: ignore[assignment]
    weights: WeightsOpt = None,
    rrd: AnswerRrdOpt = None,
) -> None:
    """The next candidate to try for TEXT after the --visited ones (JSON on stdout), with its
    goal pose (``geometry_msgs/PoseStamped`` in the map frame, facing the object) and the
    path to it along free space from --from (``nav_msgs/Path``). --rrd draws it, and the
    goals of the visited candidates."""
    import dataclasses

    from care_maps.replan.answer import offer_next
    from care_maps.replan.strategies import get_strategy

    _check_rrd(rrd, store)
    ids, places = _visited(visited or [])
    paths = path.config()
    target = _resolve(store, kind, text, weights)
    cmap, match = target.cmap, target.match
    answer = _answer_goals(store, cmap, goal.config(), paths)
    config = settings.config()
    distance = None
    if get_strategy(config.strategy).travel:
        distance = _candidate_distances(cmap, answer, config.strategy)
    offered = offer_next(answer, target, ids, config=config, visited_at=places, distance=distance)
    out = dataclasses.asdict(offered.choice)
    found = offered.offer is not None
    out["frame_id"] = answer.goals.frame_id
    out["position"] = _position(answer, offered.choice.candidate) if found else None
    out["class"] = match.names[0]
    out["method"] = match.method
    way = _offered(answer, offered)
    del way["candidate"], way["rank"]  # the choice says which
    out.update(way)
    if rrd is not None:
        from care_maps.cli.answer_rrd import replan_rrd

        drive = offered.offer.drive if found else None
        replan_rrd(rrd, store, target, answer, ids, drive, out["path_note"])
    typer.echo(json.dumps(out))


def _batch(
    store: Path,
    kind: str,
    batch: Path,
    out: Path | None,
    weights: Path | None,
    goal: GoalConfig,
    config: BatchConfig,
    paths: PathConfig,
) -> None:
    """``care query --batch``: read the queries, answer them all, write one table (each
    row's distance from the one start: one search for the whole batch)."""
    import time

    from care_maps.core.outputs import check_file_output
    from care_maps.core.store import write_table_atomic
    from care_maps.query import load_map
    from care_maps.replan.batch import plan_batch, read_queries

    queries = read_queries(batch)
    if not queries:
        _fail(f"{batch}: no queries in it")
    out = out or batch.with_name(f"{batch.stem}.answers.parquet")
    check_file_output(out, inputs=[store, batch], flag="--out", magic=(b"PAR1",))
    cmap = load_map(store, kind, weights=weights)  # type: ignore[arg-type]
    start = time.perf_counter()
    goals = _goal_maker(store, goal)
    travel = _travel(store, goals, paths)
    table = plan_batch(cmap, queries, config, goals=goals, travel=travel, progress=True)
    elapsed = time.perf_counter() - start
    write_table_atomic(table, out)
    note = _no_path(travel, paths)
    if note is not None:
        typer.echo(note)
    typer.echo(
        f"{len(queries)} queries over {cmap.num_candidates} {kind} candidates in {elapsed:.2f} s "
        f"({1000 * elapsed / len(queries):.2f} ms a query); wrote {table.num_rows} rows to {out}"
    )


def _visited(values: list[str]) -> tuple[list[int], list[tuple[float, float]]]:
    """``--visited`` values: candidate ids and map positions ``x,y`` (read by the one parser
    of a map position, :func:`care_maps.cli.options.point_xy`, as ``--from`` is)."""
    ids: list[int] = []
    places: list[tuple[float, float]] = []
    for value in values:
        try:
            if "," in value:
                places.append(point_xy(value))
            else:
                ids.append(int(value.strip()))
        except ValueError:
            _fail(
                f"--visited {value!r}: give a candidate id (12) or a map position x,y (1.5,-2.0) "
                "of finite metres"
            )
    return ids, places


def _goal_maker(store: Path, config: GoalConfig) -> Any:
    """The store's :class:`care_maps.query.goals.GoalMaker`."""
    from care_maps.query.goals import GoalMaker

    return GoalMaker.from_store(store, config)


def _travel(store: Path, goals: Any, config: PathConfig) -> Any:
    """Shortest paths over the store's free space (:class:`care_maps.query.paths.Travel`) from
    ``config.start``, else the recording's first pose; None without a grid or a start."""
    from care_maps.query.paths import Roadmap

    roadmap = Roadmap.for_goals(goals)
    start = config.start or _first_position(store)
    if roadmap is None or start is None:
        return None
    return roadmap.travel(start, config.start_reach)


def _answer_goals(store: Path, cmap: Any, goal: GoalConfig, paths: PathConfig) -> Any:
    """The offers of the map's candidates (:class:`care_maps.replan.answer.AnswerGoals`): goals, and
    paths from ``paths.start``, else the recording's first pose."""
    from care_maps.replan.answer import AnswerGoals

    goals = _goal_maker(store, goal)
    return AnswerGoals(goals, cmap, _travel(store, goals, paths), paths)


def _candidate_distances(cmap: Any, answer: Any, strategy: str) -> Any:
    """(N,) metres from the start to each candidate's approach point (inf: unreachable),
    what a travel rule trades its measure against; one line and exit 1 without paths."""
    import numpy as np

    from care_maps.query.travel import approach_cells

    travel = answer.travel
    if not answer.usable:
        _fail(
            f"--strategy {strategy} trades its measure against travel, but there are no paths "
            "from the start (no grid map, or no free cell near it); give --from x,y in free "
            "space or pick another strategy"
        )
    cells = approach_cells(travel.roadmap, cmap.positions[:, :2], answer.goals.config.reach)
    out = np.full(len(cells), np.inf)
    out[cells >= 0] = travel.distance[cells[cells >= 0]]
    return out


def _no_path(travel: Any, config: PathConfig) -> str | None:
    """Why a batch has no paths (the start is off free space), None where it has: a line
    under its summary, not an error."""
    if travel is None or travel.source is not None:
        return None
    x, y = travel.start
    return (
        f"no paths: no free cell keeps --clearance within {config.start_reach} m of the "
        f"start ({x:.2f}, {y:.2f}); give --from x,y in free space"
    )


def _first_position(store: Path) -> tuple[float, float] | None:
    """The recording's first camera position (:meth:`care_maps.core.store.Store.first_position`)."""
    from care_maps.core.store import Store

    return Store(store).first_position()


class _Ranking:
    """A query's candidates by confidence (ties by lower id), and each one's rank."""

    def __init__(self, conf: Any) -> None:
        import numpy as np

        from care_maps.query import rank_by_confidence

        self.conf = conf
        self.order = rank_by_confidence(conf[None])[0]
        self.rank = np.empty(len(self.order), np.int64)
        self.rank[self.order] = np.arange(1, len(self.order) + 1)


def _first_offer(answer: Any, conf: Any) -> tuple[_Ranking, Any]:
    """The ranking and its first attempt (:func:`care_maps.replan.answer.first_offer`)."""
    from care_maps.replan.answer import first_offer

    ranking = _Ranking(conf)
    return ranking, first_offer(answer, ranking.order)


def _position(answer: Any, candidate: int) -> list[float]:
    """The candidate's position in the goals' frame."""
    return [float(v) for v in answer.goals.in_frame(answer.cmap.positions[candidate])[0]]


def _row(answer: Any, target: Any, ranking: _Ranking, c: int) -> dict:
    """One candidate of ``care query``'s answer: measures, position and goal (in the goals'
    frame), the metres to the goal (None: no way to it) and what its offer says."""
    cmap, offer = target.cmap, answer.offer(c)
    plain = offer.drive is offer.goal
    return {
        "rank": int(ranking.rank[c]),
        "candidate": c,
        "confidence": float(ranking.conf[c]),
        "entropy": float(cmap.entropy[c]),
        "stderr": float(cmap.stderr[c]),
        "pwkl": float(cmap.pwkl[c]),
        "num_views": int(cmap.num_views[c]),
        "position": [round(v, 3) for v in _position(answer, c)],
        "goal": offer.goal.as_dict(),
        "distance": offer.distance if plain else None,
        **offer.as_dict(),
    }


def _offered(answer: Any, offered: Any, ranking: _Ranking | None = None) -> dict:
    """The answer's first (or next) attempt: the candidate, the goal the robot is sent to,
    the way there (``nav_msgs/Path`` JSON in the goals' frame, ``distance`` and
    ``path_length`` in metres, None: no way), the start (x, y, z in the goals' frame), the
    candidates passed over and why, and the note on the way (None: plainly reachable)."""
    from care_maps.query.paths import nav_path, path_length

    offer = offered.offer
    rank = (lambda c: int(ranking.rank[c])) if ranking is not None else (lambda c: None)
    travel = answer.travel
    start = None
    if travel is not None:
        start = [float(v) for v in answer.goals.in_frame([*travel.start, 0.0])[0]]
    points = None if offer is None else offer.waypoints
    note = answer.start_note if offer is None else offer.note
    if offer is None and (offered.passed or offered.left_out):
        note = (
            "no candidate left has a goal that keeps --clearance "
            f"{answer.clearance:g} m and is reachable (see passed_over)"
        )
    return {
        "candidate": None if offer is None else offer.candidate,
        "rank": None if offer is None else rank(offer.candidate),
        "goal": None if offer is None else offer.drive.as_dict(),
        "path_state": None if offer is None else offer.state.value,
        "passed_over": [p.passed(rank(p.candidate)) for p in offered.passed],
        "passed_over_more": offered.left_out,
        "distance": None if points is None else offer.distance,
        "path": None if points is None else nav_path(offer.drive, points),
        "path_length": None if points is None else path_length(points),
        "start": start,
        "path_note": note,
    }


def _check_rrd(rrd: Path | None, store: Path) -> None:
    """Refuse a --rrd that is not ours before any work."""
    if rrd is not None:
        from care_maps.core.outputs import check_file_output

        check_file_output(rrd, inputs=[store])


def _fail(message: str) -> NoReturn:
    from care_maps.core.errors import QueryError

    raise QueryError(message)


def register(app: typer.Typer) -> None:
    """Add ``care query`` and ``care replan`` to ``app``."""
    app.command("query")(query)
    app.command("replan")(replan)
