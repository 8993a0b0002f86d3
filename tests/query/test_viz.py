"""The answer recording (``care_maps.query.viz``): a way per reachable attempt, in the colour of its
order; an unreachable or already visited attempt's goal says so; no paths, no ways."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from care_maps.core.viz import rrd_entity_counts
from care_maps.query.goals import Goal
from care_maps.query.paths import Leg
from care_maps.query.viz import (
    ANSWER_ENTITY,
    ATTEMPT_COLOURS,
    Answer,
    attempt_entity,
    write_answer_rrd,
)


def _goal(candidate: int, x: float, y: float) -> Goal:
    return Goal(candidate, "map", 0, (x + 0.3, y, 0.5), (x, y, 0.0), 0.0, True, 0.5)


def _answer(legs, visited: int = 0) -> Answer:
    goals = [_goal(7, 1.0, 0.0), _goal(3, 2.0, 1.0), _goal(9, 0.0, 2.0)]
    return Answer(
        title='"chair" in the grid map',
        labels=["#1", "#2", "#3"],
        confidence=np.array([0.9, 0.5, 0.1]),
        goals=goals,
        legs=legs,
        start=None if legs is None else (0.0, 0.0),
        visited=visited,
    )


def _read(rrd: Path) -> dict[str, dict[str, list]]:
    from rerun.chunk import RrdReader

    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        cols = {n: batch.column(n).to_pylist()[0] for n in batch.schema.names if ":" in n}
        out.setdefault(str(chunk.entity_path), {}).update(cols)
    return out


def test_each_reachable_attempt_has_its_way(tmp_path: Path) -> None:
    goals = _answer(None).goals
    legs = [
        Leg(goals[0], (0.0, 0.0), np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 0.0]])),
        Leg(goals[1], (1.0, 0.0), None),  # unreachable: the robot stays
        Leg(goals[2], (1.0, 0.0), np.array([[1.0, 0.0], [0.5, 1.0], [0.0, 2.0]])),
    ]
    rrd = write_answer_rrd(tmp_path / "a.rrd", "s", _answer(legs))
    got = _read(rrd)
    assert {attempt_entity(1), attempt_entity(3)} <= {p.lstrip("/") for p in got}
    assert f"/{attempt_entity(2)}" not in got
    third = got[f"/{attempt_entity(3)}"]
    np.testing.assert_allclose(np.array(third["LineStrips3D:strips"][0])[:, :2], legs[2].waypoints)
    assert third["LineStrips3D:labels"] == [f"attempt 3: {legs[2].length:.2f} m"]
    colour = third["LineStrips3D:colors"][0]
    assert colour >> 8 == int.from_bytes(bytes(ATTEMPT_COLOURS[2]), "big")  # RGBA, order 3
    labels = got[f"/{ANSWER_ENTITY}/goals"]["Arrows3D:labels"]
    assert labels == ["goal 1", "goal 2: unreachable", "goal 3"]
    doc = got["/answer"]["TextDocument:text"][0]
    assert "| 2 | 3 | 2.00, 1.00 | unreachable | 1.00, 0.00 |" in doc


def test_visited_attempts_and_no_paths(tmp_path: Path) -> None:
    goals = _answer(None).goals
    legs = [None, None, Leg(goals[2], (0.0, 0.0), np.array([[0.0, 0.0], [0.0, 2.0]]))]
    got = _read(write_answer_rrd(tmp_path / "r.rrd", "s", _answer(legs, visited=2)))
    assert got[f"/{ANSWER_ENTITY}/goals"]["Arrows3D:labels"] == [
        "goal 1: visited", "goal 2: visited", "goal 3",
    ]  # fmt: skip
    assert [p for p in got if "/attempts/" in p] == [f"/{attempt_entity(3)}"]
    counts = rrd_entity_counts(write_answer_rrd(tmp_path / "n.rrd", "s", _answer(None)))
    assert not [e for e, _ in counts if "/attempts/" in e or e.endswith("/start")]
    assert counts[(f"/{ANSWER_ENTITY}/candidates", "Points3D:positions")] == 1
