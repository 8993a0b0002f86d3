"""``--rrd`` of ``care query`` and ``care replan``: which attempts an answer draws, and their
ways, handed to :mod:`query.viz`.

An answer is worth drawing for what it costs a robot to drive: ``care query`` draws the
first ``--attempts`` attempts a robot replanning by max confidence makes, each from where
the last ended (:func:`query.paths.walk`), so a miss shows as the detour it is; ``care
replan`` draws the visited candidates' goals and the way to the next one, the very path
its JSON gives.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import typer

from query.paths import PathConfig
from replan.batch import BatchConfig

__all__ = ["query_rrd", "replan_rrd"]


def _write(rrd: Path, store: Path, answer: Any, goals: Any) -> None:
    """Write ``answer`` (a :class:`query.viz.Answer`) over the store's floor and cloud."""
    from query.viz import write_answer_rrd

    scene = None
    if (store / "scene_points.parquet").is_file():
        from fuse.pointcloud import read_scene_points

        cloud = read_scene_points(store / "scene_points.parquet")
        scene = (cloud.points, cloud.colors)
    write_answer_rrd(rrd, store.resolve().name, answer, floor=goals.free_space, scene=scene)
    typer.echo(f"rerun {rrd}", err=True)  # stderr: --json keeps stdout one JSON document


def _paths(travel: Any) -> bool:
    """There are paths: a grid, and a free cell near the start."""
    return travel is not None and travel.source is not None


def query_rrd(
    rrd: Path,
    store: Path,
    target: Any,
    goals: Any,
    travel: Any,
    paths: PathConfig,
    config: BatchConfig,
    rows: list[dict],
    note: str | None,
) -> None:
    """The listed candidates (``rows``, as ``care query`` prints them) and the first
    ``config.attempts`` attempts by max confidence (on a grid, ``config.exclude_radius``
    away from the cells tried), each driven from where the last ended."""
    from query.paths import walk
    from query.viz import Answer
    from replan import next_goal
    from replan.strategies import StrategyName

    cmap = target.cmap
    tried: list[int] = []
    for _ in range(config.attempts):
        choice = next_goal(
            cmap, target, tried, strategy=StrategyName.MAX_CONFIDENCE,
            exclude_radius=config.exclude_radius,
        )  # fmt: skip
        if choice.candidate < 0:
            break
        tried.append(choice.candidate)
    attempts = [goals.goal(cmap, c) for c in tried]
    legs = (
        walk(travel.roadmap, travel.start, paths.start_reach, attempts) if _paths(travel) else None
    )
    answer = Answer(
        title=f'"{target.match.names[0]}" in the {cmap.kind} map ({target.match.method})',
        positions=cmap.positions[[r["candidate"] for r in rows]].reshape(-1, 3),
        labels=[f"#{r['rank']} {r['confidence']:.2f}" for r in rows],
        confidence=np.array([r["confidence"] for r in rows]),
        goals=attempts,
        legs=legs,
        start=travel.start if legs is not None else None,
        notes=[
            "Attempts: max confidence, each after the earlier ones failed (on a grid, away "
            "from the cells tried), each driven from where the last ended.",
            *([note] if note else []),
        ],
    )
    _write(rrd, store, answer, goals)


def replan_rrd(
    rrd: Path,
    store: Path,
    target: Any,
    goals: Any,
    visited: list[int],
    chosen: Any,
    travel: Any,
    note: str | None,
) -> None:
    """The visited candidates' goals (their ways unknown: where the robot came from is
    not), then the next goal ``chosen`` with its way from the start (the JSON's ``path``)."""
    from query.paths import Leg
    from query.viz import Answer

    cmap = target.cmap
    before = [goals.goal(cmap, c) for c in visited if 0 <= c < cmap.num_candidates]
    attempts = [*before, *([chosen] if chosen is not None else [])]
    legs = None
    if _paths(travel):
        way = [Leg(chosen, travel.start, travel.waypoints(chosen))] if chosen else []
        legs = [None] * len(before) + way
    shown = [g.candidate for g in attempts]
    answer = Answer(
        title=f'next for "{target.match.names[0]}" in the {cmap.kind} map',
        positions=cmap.positions[shown].reshape(-1, 3),
        labels=[f"attempt {k}" for k in range(1, len(shown) + 1)],
        confidence=np.asarray(target.confidence())[shown],
        goals=attempts,
        legs=legs,
        start=travel.start if legs is not None else None,
        notes=[note] if note else [],
        visited=len(before),
    )
    _write(rrd, store, answer, goals)
