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
from typing import Annotated, Any, NoReturn, cast

import typer

from care_maps.cli.options import Options, config_options, point_xy, with_choices
from care_maps.core.maps import MapKind
from care_maps.query.goals import GoalConfig
from care_maps.query.paths import PathConfig
from care_maps.replan.attempts import Choice, ReplanConfig
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

    cmap = load_map(store, MapKind(kind).value, weights=weights)
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

_BATCH: dict[str, dict[str, Any]] = {
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
    if text is None:  # no --batch: TEXT was given (checked above)
        _fail("give either TEXT or --batch FILE")
    from care_maps.replan.ask import answer_query

    target = _resolve(store, kind, text, weights)
    found = answer_query(
        store, text, top=config.top, goal=goal.config(), paths=paths, target=target
    )
    answer, result = found.goals, found.as_dict()
    if rrd is not None:
        from care_maps.cli.answer_rrd import query_rrd

        query_rrd(
            rrd, store, target, answer, config, found.offered, found.ranking, result["path_note"]
        )
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
    from care_maps.replan.ask import answer_goals, offered_dict, position_in_frame
    from care_maps.replan.strategies import get_strategy

    _check_rrd(rrd, store)
    ids, places = _visited(visited or [])
    paths = path.config()
    target = _resolve(store, kind, text, weights)
    cmap, match = target.cmap, target.match
    answer = answer_goals(store, cmap, goal.config(), paths)
    config = settings.config()
    distance = None
    if get_strategy(config.strategy).travel:
        distance = _candidate_distances(cmap, answer, config.strategy)
    offered = offer_next(answer, target, ids, config=config, visited_at=places, distance=distance)
    choice = cast(Choice, offered.choice)  # offer_next always has one (first_offer: None)
    out = dataclasses.asdict(choice)
    found = offered.offer is not None
    out["frame_id"] = answer.goals.frame_id
    out["position"] = position_in_frame(answer, choice.candidate) if found else None
    out["class"] = match.names[0]
    out["method"] = match.method
    way = offered_dict(answer, offered)
    del way["candidate"], way["rank"]  # the choice says which
    out.update(way)
    if rrd is not None:
        from care_maps.cli.answer_rrd import replan_rrd

        drive = offered.offer.drive if offered.offer is not None else None
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
    cmap = load_map(store, kind, weights=weights)
    start = time.perf_counter()
    from care_maps.replan.ask import goal_maker, travel_from

    goals = goal_maker(store, goal)
    travel = travel_from(store, goals, paths)
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
