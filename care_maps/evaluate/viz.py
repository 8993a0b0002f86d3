"""Rerun logging of the evaluation: every query stepped through, and success-vs-k charts.

On the ``query`` timeline (one step per query, from 0, every query of the scene: maps,
protocols and rooms in turn), under ``world/eval``:

- ``room``: the outline of the query's room (the unit it is evaluated in);
- ``target/boxes`` and ``target/points``: the ground-truth instances that count as a success
  (the one instance of an instance query; every object of the class in the room otherwise);
- ``ranked``: the room's best candidates by confidence (``#1`` is the first attempt);
- ``first``: the first attempt, green on success, red on failure;
- ``choice/<strategy>`` (and ``choice_category/<strategy>``): each replan rule's second
  attempt at the displayed k (:func:`display_k`), drawn as a marker above the candidate it
  chose, on a stalk down to it, so rules that chose the same candidate stay apart (the view
  opens with the paper's four rules shown, the ablations and random ones hidden);
- ``query``: a text document with the query, the first attempt and a table of every rule's
  choice (every criterion and k); ``eval/log``: one line per query.

The success rate of every (strategy, criterion) against k is drawn as a static 2D chart per
map and protocol under ``eval/charts/<map>_<protocol>`` (one entity per series, with a legend),
so the charts stay visible while the time cursor steps through queries. Where the scene's
attempt sequences walked, the share of its queries solved at a goal reached within each
distance travelled is a second chart, ``eval/charts/travel_<map>_<protocol>``, one step curve
per rule of the report's travel plot (:func:`care_maps.evaluate.report.travel.travel_curves`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import rerun as rr
import rerun.blueprint as rrb

from care_maps.core.viz import open_scene_recording, panels, send_blueprint
from care_maps.query.confidence import confidence
from care_maps.query.map import CandidateMap
from care_maps.replan.strategies import STRATEGIES, Criterion

__all__ = [
    "CHART_ENTITY",
    "EVAL_ENTITY",
    "QUERY_TIMELINE",
    "display_k",
    "evaluation_blueprint",
    "first_failed_step",
    "log_evaluation",
    "query_groups",
    "write_evaluation_rrd",
]

EVAL_ENTITY = "world/eval"
CHART_ENTITY = "eval/charts"
LOG_ENTITY = "eval/log"
DOC_ENTITY = "query"
SCENE_ENTITY = "world/scene"
FOCUS_ENTITY = "world"
"""Shifted per query so the query's room sits at the origin, where the 3D view looks (the
view's origin is the root above ``world``): stepping through queries moves room to room."""
QUERY_TIMELINE = "query"
GREEN, RED, GREY, TARGET = (40, 200, 80), (230, 50, 50), (150, 150, 150), (60, 230, 230)
SHORT = {
    "no_replan": "no replan",
    "oracle": "oracle",
    "max_confidence": "max conf",
    "random": "random",
    "random_topk": "rand top-k",
    "max_entropy": "max H",
    "min_stderr": "min SE",
    "min_pwkl": "min pwKL",
    "min_entropy": "min H",
    "max_pwkl": "max pwKL",
    "largest": "largest",
    "most_views": "most views",
    "nearest_topk": "nearest",
    "max_entropy_near": "max H near",
    "min_stderr_near": "min SE near",
    "min_pwkl_near": "min pwKL near",
}
"""Short names of the replan rules for labels (the tables use the long ones)."""
COLOURS = {
    "no_replan": (120, 120, 120),
    "oracle": (255, 255, 255),
    "max_confidence": (31, 119, 180),
    "random": (160, 160, 100),
    "random_topk": (188, 189, 34),
    "max_entropy": (255, 127, 14),
    "min_stderr": (44, 160, 44),
    "min_pwkl": (214, 39, 40),
    "min_entropy": (148, 103, 189),
    "max_pwkl": (227, 119, 194),
    "largest": (140, 86, 75),
    "most_views": (23, 190, 207),
    "nearest_topk": (100, 100, 220),
    "max_entropy_near": (255, 187, 120),
    "min_stderr_near": (152, 223, 138),
    "min_pwkl_near": (255, 152, 150),
}
_SHOWN = ("max_confidence", "max_entropy", "min_stderr", "min_pwkl")
"""Rules whose choices the 3D view shows as it opens (the paper's); the others' entities are
there, hidden, one click (the eye icon) away."""
_HIDDEN_CHOICES = [f"{EVAL_ENTITY}/choice/{name}" for name in SHORT if name not in _SHOWN] + [
    f"{EVAL_ENTITY}/choice_category"
]
_TOP = 10
"""Ranked candidates drawn per query."""
_MAX_TARGET_POINTS = 3000
_CHART_W, _CHART_H = 500.0, 300.0


def _viridis(values: np.ndarray) -> np.ndarray:
    import matplotlib as mpl

    v = np.asarray(values, float)
    span = np.ptp(v) if len(v) else 0.0
    v = (v - v.min()) / span if span > 0 else np.zeros_like(v)
    return (mpl.colormaps["viridis"](v)[:, :3] * 255).astype(np.uint8)


def query_groups(attempts: pa.Table, scene: str, kinds: Sequence[str]) -> list[list[dict]]:
    """The rows of each query of ``scene`` (deterministic rules and seed 0 of random ones),
    in the order the timeline steps through them."""
    mine = attempts.filter(
        pc.and_(
            pc.equal(attempts.column("scene"), scene), pc.less_equal(attempts.column("seed"), 0)
        )
    )
    mine = mine.filter(pc.is_in(mine.column("map"), pa.array(list(kinds), pa.string())))
    groups: dict[tuple, list[dict]] = {}
    for row in mine.to_pylist():
        groups.setdefault((row["map"], row["protocol"], row["unit"], row["query"]), []).append(row)
    return list(groups.values())


def first_failed_step(attempts: pa.Table, scene: str, kinds: Sequence[str]) -> int | None:
    """Step of the first query whose first attempt failed (a query worth a screenshot)."""
    for step, rows in enumerate(query_groups(attempts, scene, kinds)):
        first = next(r for r in rows if r["attempt"] == 1)
        if not first["success"]:
            return step
    return None


def display_k(attempts: pa.Table, kind: str) -> int:
    """The k whose choices the 3D view shows for map ``kind``: its smallest k."""
    ks = attempts.filter(pc.equal(attempts.column("map"), kind)).column("k").to_numpy()
    ks = ks[ks > 0]
    return int(ks.min()) if len(ks) else 0


# -- the 3D context of one query ---------------------------------------------------------


def _gt_targets(gt, unit_room: int | None, row: dict) -> tuple[np.ndarray, list[str]]:
    """Instance ids (and their labels) that make a choice for this query a success."""
    table = gt.instances
    ids = table.column("instance_id").to_numpy()
    names = [n.strip().lower() for n in table.column("class_name").to_pylist()]
    rooms = table.column("room_id").to_numpy()
    if "#" in row["query"]:  # instance protocol: class#instance_id
        wanted = np.array([int(row["query"].rsplit("#", 1)[1])])
    else:
        hit = np.array([n == row["target"].strip().lower() for n in names], bool)
        if unit_room is not None:
            hit &= rooms == unit_room
        wanted = ids[hit]
    keep = np.isin(ids, wanted)
    return ids[keep], [f"target {row['target']}#{i}" for i in ids[keep]]


def _log_context(rec: rr.RecordingStream, gt, unit: str, row: dict) -> np.ndarray | None:
    """Room outline and target instances; returns the room's candidate mask function input."""
    if gt is None:
        rec.log(f"{EVAL_ENTITY}/room", rr.Clear(recursive=False))
        rec.log(f"{EVAL_ENTITY}/target", rr.Clear(recursive=True))
        return None
    from care_maps.evaluate.success import _unit_names

    room_of_unit = dict(zip(_unit_names(gt), gt.rooms, strict=True))
    room = room_of_unit.get(unit)
    if room is not None:
        poly = np.asarray(room.floor_polygon, np.float64)
        ring = np.vstack([poly, poly[:1]])
        rec.log(
            f"{EVAL_ENTITY}/room",
            rr.LineStrips3D(
                [np.c_[ring, np.full(len(ring), 0.02)]], colors=[TARGET], radii=0.02,
                labels=[unit],
            ),
        )  # fmt: skip
    else:
        rec.log(f"{EVAL_ENTITY}/room", rr.Clear(recursive=False))
    ids, labels = _gt_targets(gt, None if room is None else room.room_id, row)
    table = gt.instances
    keep = np.isin(table.column("instance_id").to_numpy(), ids)
    lo = np.asarray(table.column("bbox_min").to_pylist(), np.float32).reshape(-1, 3)[keep]
    hi = np.asarray(table.column("bbox_max").to_pylist(), np.float32).reshape(-1, 3)[keep]
    rec.log(
        f"{EVAL_ENTITY}/target/boxes",
        rr.Boxes3D(mins=lo, sizes=hi - lo, colors=[TARGET], radii=0.015, labels=labels),
    )
    pts = gt.points[np.isin(gt.point_instance, ids)]
    if len(pts) > _MAX_TARGET_POINTS:
        pts = pts[:: int(np.ceil(len(pts) / _MAX_TARGET_POINTS))]
    rec.log(f"{EVAL_ENTITY}/target/points", rr.Points3D(pts, colors=[TARGET], radii=0.01))
    # the point the 3D eye follows: the room's middle (else the targets'), on the floor
    around = np.asarray(room.floor_polygon, np.float64) if room is not None else pts[:, :2]
    if len(around):
        middle = (around.min(axis=0) + around.max(axis=0)) / 2
        rec.log(FOCUS_ENTITY, rr.Transform3D(translation=[-middle[0], -middle[1], 0.0]))
    return room.room_id if room is not None else None


def _choice_marker(
    rec: rr.RecordingStream, entity: str, position: np.ndarray, slot: int, row: dict
) -> None:
    """A marker on a stalk from the chosen candidate, its direction fixed per rule (slot), so
    rules that chose the same candidate fan out and their labels stay readable from above."""
    angle = np.pi / 4 + slot * np.pi / 2 + (slot // 4) * np.pi / 4
    reach = 0.6 + 0.25 * (slot // 4)
    top = position + np.array([reach * np.cos(angle), reach * np.sin(angle), 0.5])
    ok = row["success"]
    label = f"{SHORT.get(row['strategy'], row['strategy'])} {'ok' if ok else 'miss'}"
    colour = COLOURS.get(row["strategy"], GREY)
    rec.log(
        entity,
        rr.Points3D([top], colors=[colour], radii=0.07, labels=[label], show_labels=True),
        rr.LineStrips3D([[top, position]], colors=[colour], radii=0.01),
    )


def _query_doc(step: int, total: int, rows: list[dict], first: dict, kind_k: int) -> str:
    head = rows[0]
    lines = [
        f'## Query {step + 1} of {total}: "{head["target"]}"',
        "",
        f"map **{head['map']}**, protocol **{head['protocol']}**, room **{head['unit']}**, "
        f"query `{head['query']}`",
        "",
        f"First attempt: candidate {first['candidate']} (confidence {first['confidence']:.3f}) "
        f"**{'succeeded' if first['success'] else 'failed'}**.",
        "",
    ]
    seconds = [r for r in rows if r["attempt"] == 2]
    if seconds:
        lines += [
            f"Second attempts (the 3D view shows criterion confidence at k={kind_k}):",
            "",
            "| rule | criterion | k | candidate | value | outcome |",
            "|---|---|---|---|---|---|",
        ]
        for r in sorted(seconds, key=lambda r: (r["strategy"], r["criterion"], r["k"])):
            outcome = "success" if r["success"] else "miss"
            fell = " (fell back)" if r["fell_back"] else ""
            lines.append(
                f"| {SHORT.get(r['strategy'], r['strategy'])} | {r['criterion']} | {r['k']} | "
                f"{r['candidate']} | {r['value']:.4g} | {outcome}{fell} |"
            )
    elif not first["success"]:
        lines.append("No rule made a second attempt.")
    return "\n".join(lines)


def _log_query(
    rec: rr.RecordingStream,
    cmap: CandidateMap,
    rows: list[dict],
    gt,
    kind_k: int,
    step: int,
    total: int,
) -> str:
    """Log one query's context, ranking and decisions; returns its one-line description."""
    head = rows[0]
    room_id = _log_context(rec, gt, head["unit"], head)
    y = cmap.class_id(head["target"])
    conf = confidence(cmap, np.array([y]))[0]
    in_room = np.ones(cmap.num_candidates, bool)
    if gt is not None and room_id is not None:
        in_room = gt.room_of(cmap.positions[:, :2]) == room_id
    ids = np.flatnonzero(in_room)
    ranked = ids[np.argsort(-conf[ids], kind="stable")[:_TOP]]
    rec.log(
        f"{EVAL_ENTITY}/ranked",
        rr.Points3D(
            cmap.positions[ranked], colors=_viridis(conf[ranked]), radii=0.05,
            labels=[f"#{r + 1} {conf[c]:.2f}" if r else "" for r, c in enumerate(ranked)],
        ),
    )  # fmt: skip
    first = next(r for r in rows if r["attempt"] == 1)  # the same for every strategy
    if first["candidate"] >= 0:
        rec.log(
            f"{EVAL_ENTITY}/first",
            rr.Points3D(
                cmap.positions[[first["candidate"]]], colors=[GREEN if first["success"] else RED],
                radii=0.12,
                labels=[f"1st (#1 {first['confidence']:.2f}): {'ok' if first['success'] else 'FAILED'}"],
            ),
        )  # fmt: skip
    else:
        rec.log(f"{EVAL_ENTITY}/first", rr.Clear(recursive=False))
    rec.log(f"{EVAL_ENTITY}/choice", rr.Clear(recursive=True))
    rec.log(f"{EVAL_ENTITY}/choice_category", rr.Clear(recursive=True))
    seconds = [
        r
        for r in rows
        if r["attempt"] == 2 and r["candidate"] >= 0 and r["k"] in (0, kind_k)
        and r["strategy"] not in ("oracle",)
    ]  # fmt: skip
    order = [*_SHOWN, *(name for name in SHORT if name not in _SHOWN)]
    for r in seconds:
        parent = "choice_category" if r["criterion"] == "category" else "choice"
        _choice_marker(
            rec, f"{EVAL_ENTITY}/{parent}/{r['strategy']}", cmap.positions[r["candidate"]],
            order.index(r["strategy"]), r,
        )  # fmt: skip
    rec.log(
        DOC_ENTITY,
        rr.TextDocument(
            _query_doc(step, total, rows, first, kind_k), media_type=rr.MediaType.MARKDOWN
        ),
    )
    words = f"{head['map']}/{head['protocol']} {head['unit']}: {head['query']}: first "
    words += "ok" if first["success"] else "FAILED"
    good = sorted({SHORT.get(r["strategy"], r["strategy"]) for r in seconds if r["success"]})
    if not first["success"]:
        words += f"; replans that succeed (k={kind_k}): {', '.join(good) or 'none'}"
    return words


# -- charts ----------------------------------------------------------------------------


def _chart_name(kind: str, protocol: str) -> str:
    return f"{kind}_{protocol}"


def _log_chart(
    rec: rr.RecordingStream, kind: str, protocol: str, rates: list[dict], ks: list[int]
) -> None:
    """One success-vs-k chart: axes, one polyline per (strategy, criterion), a legend."""
    base = f"{CHART_ENTITY}/{_chart_name(kind, protocol)}"
    n = max(len(ks) - 1, 1)
    lowest = min((r["rate"] for r in rates), default=0.0)
    floor = max(0.0, float(np.floor(lowest / 10.0) * 10.0))  # the axis starts where data does
    if floor > 90.0:
        floor = 90.0
    ticks = np.linspace(floor, 100.0, 5)

    def xy(i: float, rate: float) -> tuple[float, float]:
        return (_CHART_W * i / n, _CHART_H * (1 - (rate - floor) / (100.0 - floor)))

    frame = [xy(0, 100), xy(0, floor), xy(n, floor)]
    grid = [[xy(0, v), xy(n, v)] for v in ticks[1:]]
    rec.log(f"{base}/axes", rr.LineStrips2D([frame, *grid], colors=[(90, 90, 90)]), static=True)
    rec.log(
        f"{base}/axes/y",
        rr.Points2D(
            [(-40.0, xy(0, v)[1]) for v in ticks], radii=0.1,
            labels=[f"{v:.4g}%" for v in ticks], colors=[(200, 200, 200)],
        ),
        static=True,
    )  # fmt: skip
    rec.log(
        f"{base}/axes/k",
        rr.Points2D(
            [(xy(i, floor)[0], _CHART_H + 22.0) for i in range(len(ks))], radii=0.1,
            labels=[f"k={k}" for k in ks], colors=[(200, 200, 200)],
        ),
        static=True,
    )  # fmt: skip
    series: dict[tuple[str, bool, str], dict[int, float]] = {}
    for r in rates:
        key = (r["strategy"], r["closed_form"], r["criterion"])
        series.setdefault(key, {})[r["k"]] = r["rate"]
    legend_y = 0.0
    for (strategy, closed, criterion), by_k in sorted(series.items()):
        colour = np.array(COLOURS.get(strategy, GREY), float)
        if criterion == Criterion.CATEGORY:
            colour = colour * 0.55
        if closed:
            colour = colour * 0.8 + 40
        values = [by_k.get(k, by_k.get(0)) for k in ks]
        pts = [xy(i, v) for i, v in enumerate(values) if v is not None]
        name = SHORT.get(strategy, strategy) + (" exp." if closed else "")
        uses_set = STRATEGIES[strategy].uses_set
        label = f"{name} / {criterion}" if uses_set else name
        entity = (
            f"{base}/{strategy}{'_expected' if closed else ''}/{criterion if uses_set else 'none'}"
        )
        c = colour.clip(0, 255).astype(np.uint8)
        rec.log(
            entity,
            rr.LineStrips2D([pts], colors=[c], radii=1.5),
            rr.Points2D(pts, colors=[c], radii=3.0),
            static=True,
        )
        rec.log(
            f"{entity}/legend",
            rr.Points2D([(_CHART_W + 130.0, legend_y)], colors=[c], radii=5.0, labels=[label]),
            static=True,
        )
        legend_y += 16.0


def _log_travel_chart(
    rec: rr.RecordingStream, kind: str, protocol: str, lines: list[tuple]
) -> None:
    """One success-vs-distance chart: axes with metre and percent ticks, one step curve per
    rule (``lines`` of :func:`care_maps.evaluate.report.travel.travel_curves`), a legend."""
    from care_maps.evaluate.spl import success_within

    base = f"{CHART_ENTITY}/{_travel_name(kind, protocol)}"
    top = max((float(p.max()) for _, _, p, _, _ in lines if len(p)), default=1.0)
    top = max(top, 1e-3) * 1.02

    def xy(metres: np.ndarray, share: np.ndarray) -> np.ndarray:
        return np.stack([_CHART_W * metres / top, _CHART_H * (1 - share)], axis=1)

    frame = xy(np.array([0.0, 0.0, top]), np.array([1.0, 0.0, 0.0]))
    grid = [xy(np.array([0.0, top]), np.array([v, v])) for v in (0.25, 0.5, 0.75, 1.0)]
    rec.log(f"{base}/axes", rr.LineStrips2D([frame, *grid], colors=[(90, 90, 90)]), static=True)
    ticks = np.linspace(0.0, top, 5)
    rec.log(
        f"{base}/axes/m",
        rr.Points2D(
            [(x, _CHART_H + 22.0) for x in xy(ticks, np.zeros(5))[:, 0]], radii=0.1,
            labels=[f"{m:.3g} m" for m in ticks], colors=[(200, 200, 200)],
        ),
        static=True,
    )  # fmt: skip
    rec.log(
        f"{base}/axes/y",
        rr.Points2D(
            [(-40.0, y) for y in xy(np.zeros(5), np.linspace(0, 1, 5))[:, 1]], radii=0.1,
            labels=[f"{v:.0f}%" for v in np.linspace(0, 100, 5)], colors=[(200, 200, 200)],
        ),
        static=True,
    )  # fmt: skip
    for row, (strategy, label, path, solved, weight) in enumerate(lines):
        stops = np.unique(np.r_[0.0, path, top])  # the share changes only at these
        share = success_within(path, solved, stops, weight)
        steps = xy(np.repeat(stops, 2)[1:], np.repeat(share, 2)[:-1])  # flat, then up
        c = np.array(COLOURS.get(strategy, GREY), np.uint8)
        entity = f"{base}/{strategy}"
        rec.log(entity, rr.LineStrips2D([steps], colors=[c], radii=1.5), static=True)
        rec.log(
            f"{entity}/legend",
            rr.Points2D([(_CHART_W + 130.0, 16.0 * row)], colors=[c], radii=5.0, labels=[label]),
            static=True,
        )


def _travel_name(kind: str, protocol: str) -> str:
    return f"travel_{kind}_{protocol}"


def evaluation_blueprint(
    charts: Sequence[tuple[str, str]], travel: Sequence[tuple[str, str]] = ()
) -> rrb.Blueprint:
    """3D query context and the log left; the query's details and the charts right.

    The 3D view looks at the query's room: :data:`FOCUS_ENTITY` moves each room to the origin.
    """
    eye = rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=(0.0, -4.0, 6.0),
        look_target=(0.0, 0.0, 0.3),
        eye_up=(0.0, 0.0, 1.0),
    )
    tabs = [
        rrb.Spatial2DView(
            origin=f"{CHART_ENTITY}/{_chart_name(kind, protocol)}",
            name=f"success vs k: {kind} / {protocol}",
            visual_bounds=rrb.VisualBounds2D(
                x_range=[-70.0, _CHART_W + 250.0], y_range=[-30.0, _CHART_H + 50.0]
            ),
        )
        for kind, protocol in charts
    ]
    tabs += [
        rrb.Spatial2DView(
            origin=f"{CHART_ENTITY}/{_travel_name(kind, protocol)}",
            name=f"success vs distance: {kind} / {protocol}",
            visual_bounds=rrb.VisualBounds2D(
                x_range=[-70.0, _CHART_W + 250.0], y_range=[-30.0, _CHART_H + 50.0]
            ),
        )
        for kind, protocol in travel
    ]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(
                    origin="/",
                    contents="+ world/**",
                    name="query: room, target (cyan), ranked, 1st attempt, replan choices",
                    eye_controls=eye,
                    overrides={path: rrb.EntityBehavior(visible=False) for path in _HIDDEN_CHOICES},
                ),
                rrb.TextLogView(origin=LOG_ENTITY, name="queries"),
                row_shares=[3, 1],
            ),
            rrb.Vertical(
                rrb.TextDocumentView(origin=DOC_ENTITY, name="query"),
                rrb.Tabs(*tabs) if tabs else rrb.Vertical(),
                row_shares=[1, 1],
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(state="expanded", timeline=QUERY_TIMELINE, play_state="paused"),
        *panels()[:2],
    )


def log_evaluation(
    rec: rr.RecordingStream,
    attempts: pa.Table,
    summary: pa.Table,
    maps: dict[str, CandidateMap],
    *,
    scene: str,
    gt=None,
    scene_points: np.ndarray | None = None,
    scene_colours: np.ndarray | None = None,
) -> int:
    """Log every query of ``scene`` and the success-vs-k charts; returns the queries logged.

    ``gt`` (a :class:`care_maps.truth.model.GroundTruth`) adds the room outline, the target
    instances and limits the ranked candidates to the query's room.
    """
    if scene_points is not None:
        rec.log(
            f"{SCENE_ENTITY}",
            rr.Points3D(scene_points, colors=scene_colours, radii=0.01),
            static=True,
        )
    groups = query_groups(attempts, scene, list(maps))
    ks_shown = {kind: display_k(attempts, kind) for kind in maps}
    for step, rows in enumerate(groups):
        rec.set_time(QUERY_TIMELINE, sequence=step)
        kind = rows[0]["map"]
        text = _log_query(rec, maps[kind], rows, gt, ks_shown[kind], step, len(groups))
        first_ok = next(r for r in rows if r["attempt"] == 1)["success"]
        rec.log(
            LOG_ENTITY,
            rr.TextLog(f"[{step}] {text}", level=rr.TextLogLevel.INFO if first_ok else "WARN"),
        )
    rec.reset_time()
    rates = [r for r in summary.to_pylist() if r["map"] in maps]
    charts = sorted({(r["map"], r["protocol"]) for r in rates})
    for kind, protocol in charts:
        mine = [r for r in rates if r["map"] == kind and r["protocol"] == protocol]
        ks = sorted({r["k"] for r in mine if r["k"]})
        _log_chart(rec, kind, protocol, mine, ks or [0])
    for (kind, protocol), lines in sorted(_scene_curves(attempts, summary, scene).items()):
        if kind in maps:
            _log_travel_chart(rec, kind, protocol, lines)
    return len(groups)


def _scene_curves(attempts: pa.Table, summary: pa.Table, scene: str) -> dict:
    """The scene's success-vs-distance curves (none where it did not walk)."""
    from care_maps.evaluate.report.travel import travel_curves

    if "distance" not in attempts.column_names:
        return {}
    mine = attempts.filter(pc.equal(attempts.column("scene"), scene))
    return {key: lines for key, lines in travel_curves(mine, summary).items() if lines}


def write_evaluation_rrd(
    rrd: Path,
    attempts: pa.Table,
    summary: pa.Table,
    maps: dict[str, CandidateMap],
    *,
    scene: str,
    rec: rr.RecordingStream | None = None,
    gt=None,
    store: Path | None = None,
) -> Path:
    """Log :func:`log_evaluation` into ``rec``, or a new ``rrd`` file (``rerun rrd``).

    ``store`` adds the scene's point cloud (its ``scene_points.parquet``) as 3D context.
    """
    own = rec is None
    points = colours = None
    if store is not None and (Path(store) / "scene_points.parquet").is_file():
        from care_maps.fuse.pointcloud import read_scene_points

        cloud = read_scene_points(Path(store) / "scene_points.parquet")
        points, colours = cloud.points, cloud.colors
    if rec is None:
        rec = open_scene_recording(rrd, scene)
        rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # the 3D view's origin
    charts = sorted({(r["map"], r["protocol"]) for r in summary.to_pylist() if r["map"] in maps})
    travel = sorted(k for k in _scene_curves(attempts, summary, scene) if k[0] in maps)
    if own:
        send_blueprint(rec, evaluation_blueprint(charts, travel))
    log_evaluation(
        rec, attempts, summary, maps, scene=scene, gt=gt, scene_points=points,
        scene_colours=colours,
    )  # fmt: skip
    if own:
        rec.flush()
        rec.disconnect()
    return Path(rrd)
