"""Rerun logging of one answer of ``care query`` or ``care replan``: where the robot starts,
the candidates, their goals and the way of each attempt over the floor.

A robot that misses on its first attempt drives on to the next, so the recording shows
what the answer costs to drive, not only where the object may be. Under
:data:`ANSWER_ENTITY`, in the map frame (the frame the grid recording draws its cells in, so
``rerun store.grid.rrd answer.rrd`` overlays them; the goals' JSON is this frame, or it
moved by ``--frame-id``'s transform):

- ``floor``: the obstacle cells, on the floor;
- ``scene``: the store's coloured point cloud, thinned (where the store has one);
- ``candidates``: the candidates whose goals it shows (each attempt's, no more, no fewer: an
  object drawn without its goal, or a goal without its object, reads as part of the answer
  that is not), coloured by confidence, labelled;
- ``start``: where the paths start (``--from``, or the recording's first pose);
- ``goals``: each attempt's goal, an arrow at the approach point facing the object;
- ``attempts/<k>``: the way of attempt k (:class:`care_maps.query.paths.Leg`), a line on the floor
  in the colour of its order, labelled with the attempt and the metres it drives; an
  attempt the robot cannot reach has no line, its goal says so.

:data:`DOC_ENTITY` holds the answer as text: the query, the start and a row per attempt.
The layout (:func:`answer_blueprint`) is the 3D view with the text beside it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from care_maps.core.errors import QueryError
from care_maps.core.viz import open_scene_recording, panels, send_blueprint
from care_maps.query.goals import FreeSpace, Goal
from care_maps.query.paths import Leg

__all__ = [
    "ANSWER_ENTITY",
    "ATTEMPT_COLOURS",
    "DOC_ENTITY",
    "Answer",
    "GoalState",
    "answer_blueprint",
    "attempt_entity",
    "log_answer",
    "write_answer_rrd",
]

ANSWER_ENTITY = "world/answer"
DOC_ENTITY = "answer"
ATTEMPT_COLOURS = (
    (44, 160, 44),
    (255, 127, 14),
    (148, 103, 189),
    (23, 190, 207),
    (227, 119, 194),
    (188, 189, 34),
    (140, 86, 75),
    (31, 119, 180),
)
"""Colour of attempt k's way and goal: ``ATTEMPT_COLOURS[(k - 1) % 8]`` (first green)."""
_RED, _GREY, _WHITE = (230, 50, 50), (110, 110, 110), (255, 255, 255)
_LIFT = 0.03
"""Height (m) of the ways above the floor, each later attempt a little higher, so ways that
share a corridor stay apart."""
_MAX_SCENE_POINTS = 60_000
_ARROW = 0.4
"""Length (m) of a goal's heading arrow."""


class GoalState(StrEnum):
    """What a goal's label says beside its number, and how it is coloured."""

    AHEAD = ""
    """An attempt of this answer, reachable (or no paths to say otherwise): its order's colour."""
    UNREACHABLE = "unreachable"
    """No way leads there from where the robot stood: red, and no line."""
    VISITED = "visited"
    """An attempt made before this answer (``care replan --visited``): grey."""


@dataclass(frozen=True)
class Answer:
    """What one answer shows: the attempts in order, each with its candidate and goal."""

    title: str
    """The heading of the text: what was asked and of which map."""
    labels: Sequence[str]
    """A label per attempt's candidate (rank and confidence)."""
    confidence: np.ndarray
    """Confidence of each attempt's candidate (colours)."""
    goals: Sequence[Goal]
    """The goal of each attempt, in order; its candidate is drawn at ``Goal.target``."""
    legs: Sequence[Leg | None] | None
    """The way of each attempt (None: no paths: no grid, or no start near free space; an
    entry None: an attempt made before this answer, whose way it does not know)."""
    start: tuple[float, float] | None
    """Where the paths start (map x, y); None without paths."""
    notes: Sequence[str] = ()
    """Lines under the table (why there are no paths, what the attempts follow)."""
    visited: int = 0
    """The first ``visited`` goals are attempts made before (``care replan --visited``)."""

    def __post_init__(self) -> None:
        n = len(self.goals)
        if len(self.labels) != n or len(self.confidence) != n:
            msg = (
                f"an answer draws one candidate per goal: {n} goals, {len(self.labels)} labels, "
                f"{len(self.confidence)} confidences"
            )
            raise QueryError(msg)

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) map positions of the candidates drawn: those of the goals."""
        return np.array([g.target for g in self.goals], np.float64).reshape(-1, 3)


def attempt_entity(attempt: int) -> str:
    """Entity path of attempt ``attempt``'s way (from 1)."""
    return f"{ANSWER_ENTITY}/attempts/{attempt}"


def _colour(attempt: int) -> tuple[int, int, int]:
    return ATTEMPT_COLOURS[(attempt - 1) % len(ATTEMPT_COLOURS)]


def _viridis(values: np.ndarray) -> np.ndarray:
    import matplotlib as mpl

    v = np.asarray(values, float)
    span = float(np.ptp(v)) if len(v) else 0.0
    v = (v - v.min()) / span if span > 0 else np.ones_like(v)
    return (mpl.colormaps["viridis"](v)[:, :3] * 255).astype(np.uint8)


def _metres(value: float) -> str:
    return f"{value:.2f} m" if math.isfinite(value) else "unreachable"


def _document(answer: Answer) -> str:
    """The answer as Markdown: the question, the start, and a row per attempt."""
    lines = [f"## {answer.title}", ""]
    if answer.start is not None:
        lines += [f"Paths start at ({answer.start[0]:.2f}, {answer.start[1]:.2f}) m.", ""]
    lines += [
        "| attempt | candidate | goal x, y (m) | drives | from x, y (m) |",
        "|---|---|---|---|---|",
    ]
    legs = answer.legs if answer.legs is not None else [None] * len(answer.goals)
    for k, (goal, leg) in enumerate(zip(answer.goals, legs, strict=True), start=1):
        drives, origin = ("visited before", "-") if k <= answer.visited else ("-", "-")
        if leg is not None:
            drives, origin = _metres(leg.length), f"{leg.start[0]:.2f}, {leg.start[1]:.2f}"
        x, y = goal.position[:2]
        lines.append(f"| {k} | {goal.candidate} | {x:.2f}, {y:.2f} | {drives} | {origin} |")
    lines += ["", *answer.notes]
    return "\n".join(lines)


def _log_floor(rec: rr.RecordingStream, floor: FreeSpace | None) -> None:
    if floor is None:
        return
    ix, iy = np.nonzero(floor.blocked)
    size, (ox, oy) = floor.layout.cell_size, floor.layout.origin
    xyz = np.c_[ox + (ix + 0.5) * size, oy + (iy + 0.5) * size, np.zeros(len(ix))]
    rec.log(
        f"{ANSWER_ENTITY}/floor",
        rr.Points3D(xyz, colors=[_GREY], radii=size / 2),
        static=True,
    )


def _log_scene(rec: rr.RecordingStream, scene: tuple[np.ndarray, np.ndarray] | None) -> None:
    if scene is None or not len(scene[0]):
        return
    points, colours = scene
    step = max(1, math.ceil(len(points) / _MAX_SCENE_POINTS))
    rec.log(
        f"{ANSWER_ENTITY}/scene",
        rr.Points3D(points[::step], colors=colours[::step], radii=0.01),
        static=True,
    )


def _log_attempts(rec: rr.RecordingStream, answer: Answer) -> None:
    """Each attempt's goal (an arrow) and way (a line on the floor, coloured by order)."""
    goals = list(answer.goals)
    legs = list(answer.legs) if answer.legs is not None else [None] * len(goals)
    if goals:
        yaw = np.array([g.yaw for g in goals])
        state = [
            GoalState.VISITED if k <= answer.visited
            else GoalState.UNREACHABLE if leg is not None and leg.waypoints is None
            else GoalState.AHEAD
            for k, leg in enumerate(legs, start=1)
        ]  # fmt: skip
        colour = {GoalState.UNREACHABLE: _RED, GoalState.VISITED: _GREY}
        rec.log(
            f"{ANSWER_ENTITY}/goals",
            rr.Arrows3D(
                origins=[(g.position[0], g.position[1], _LIFT) for g in goals],
                vectors=np.c_[_ARROW * np.cos(yaw), _ARROW * np.sin(yaw), np.zeros(len(goals))],
                colors=[colour.get(s, _colour(k)) for k, s in enumerate(state, start=1)],
                labels=[f"goal {k}" + (f": {s}" if s else "") for k, s in enumerate(state, 1)],
                radii=0.02,
            ),
            static=True,
        )
    for k, leg in enumerate(legs, start=1):
        if leg is None or leg.waypoints is None:
            continue
        lift = _LIFT * (1 + 0.5 * (k - 1))
        line = np.c_[leg.waypoints, np.full(len(leg.waypoints), lift)]
        rec.log(
            attempt_entity(k),
            rr.LineStrips3D(
                [line], colors=[_colour(k)], radii=0.03,
                labels=[f"attempt {k}: {_metres(leg.length)}"],
            ),
            static=True,
        )  # fmt: skip
    if answer.start is not None:
        rec.log(
            f"{ANSWER_ENTITY}/start",
            rr.Points3D(
                [(answer.start[0], answer.start[1], _LIFT)], colors=[_WHITE], radii=0.08,
                labels=["start"],
            ),
            static=True,
        )  # fmt: skip


def log_answer(
    rec: rr.RecordingStream,
    answer: Answer,
    *,
    floor: FreeSpace | None = None,
    scene: tuple[np.ndarray, np.ndarray] | None = None,
) -> None:
    """Log ``answer`` (static: one answer, no timeline), over the obstacle cells of
    ``floor`` and the ``scene`` cloud ((M, 3) points, (M, 3) uint8 colours)."""
    _log_floor(rec, floor)
    _log_scene(rec, scene)
    if len(answer.positions):
        rec.log(
            f"{ANSWER_ENTITY}/candidates",
            rr.Points3D(
                np.asarray(answer.positions, np.float32), colors=_viridis(answer.confidence),
                radii=0.06, labels=list(answer.labels),
            ),
            static=True,
        )  # fmt: skip
    _log_attempts(rec, answer)
    rec.log(
        DOC_ENTITY,
        rr.TextDocument(_document(answer), media_type=rr.MediaType.MARKDOWN),
        static=True,
    )


def _eye(points: np.ndarray) -> rrb.EyeControls3D:
    """Steeply above the answer's places (start, goals, candidates): ways on the floor stay
    in sight over the walls of the scene's cloud."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if not len(pts):
        return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, 0.0])
    reach = float(max(hi[0] - lo[0], hi[1] - lo[1], 2.0))
    return rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=centre + np.array([0.0, -0.45 * reach, 1.3 * reach]),
        look_target=centre,
        eye_up=(0.0, 0.0, 1.0),
    )


def answer_blueprint(eye: rrb.EyeControls3D | None = None) -> rrb.Blueprint:
    """The 3D view of the answer (ways, goals, candidates over the floor), its text beside."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                origin="world",
                name="answer: start, attempts' ways (by order), goals, candidates",
                eye_controls=eye,
            ),
            rrb.TextDocumentView(origin=DOC_ENTITY, name="answer"),
            column_shares=[3, 1],
        ),
        *panels(),
    )


def write_answer_rrd(
    rrd: Path,
    scene_name: str,
    answer: Answer,
    *,
    floor: FreeSpace | None = None,
    scene: tuple[np.ndarray, np.ndarray] | None = None,
) -> Path:
    """Write ``answer`` to a new ``rrd`` file of scene ``scene_name`` (the store's name: it
    merges with the store's other recordings), with :func:`answer_blueprint`."""
    rec = open_scene_recording(rrd, scene_name)
    around = [np.asarray(answer.positions, np.float64).reshape(-1, 3)]
    around += [np.array([[*g.position[:2], 0.0] for g in answer.goals]).reshape(-1, 3)]
    if answer.start is not None:
        around.append(np.array([[*answer.start, 0.0]]))
    send_blueprint(rec, answer_blueprint(_eye(np.vstack(around))))
    log_answer(rec, answer, floor=floor, scene=scene)
    rec.flush()
    rec.disconnect()
    return Path(rrd)
