"""``--rrd`` of ``care query`` and ``care replan``: which attempts an answer draws, and their
ways, handed to :mod:`care_maps.query.viz`.

An answer is worth drawing for what it costs a robot to drive: ``care query`` draws the
first ``--attempts`` attempts a robot replanning by max confidence makes, each from where
the last ended (:func:`care_maps.query.paths.walk`), so a miss shows as the detour it is; ``care
replan`` draws the visited candidates' goals and the way to the next one, the very path
its JSON gives. Either draws the candidates of the goals it shows, no others: an object
drawn without its goal reads as part of the answer when it is not.

The attempts are those the answer offers (:mod:`care_maps.replan.answer`): a candidate whose goal
breaks the clearance or that no way reaches is passed over, as the JSON passes it over, and
each attempt's goal is the one the robot is sent to.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import typer

from care_maps.replan.batch import BatchConfig

__all__ = ["query_rrd", "replan_rrd"]


def _write(rrd: Path, store: Path, answer: Any, goals: Any) -> None:
    """Write ``answer`` (a :class:`care_maps.query.viz.Answer`) over the store's floor and cloud."""
    from care_maps.query.viz import write_answer_rrd

    scene = None
    if (store / "scene_points.parquet").is_file():
        from care_maps.fuse.pointcloud import read_scene_points

        cloud = read_scene_points(store / "scene_points.parquet")
        scene = (cloud.points, cloud.colors)
    write_answer_rrd(rrd, store.resolve().name, answer, floor=goals.free_space, scene=scene)
    typer.echo(f"rerun {rrd}", err=True)  # stderr: --json keeps stdout one JSON document


def _attempts(answer: Any, target: Any, config: BatchConfig, first: Any) -> list[Any]:
    """The offers of the first ``config.attempts`` attempts by max confidence: the JSON's
    first attempt, then each next one after the earlier ones failed (on a grid,
    ``config.exclude_radius`` away from the cells tried), passing over what it passes over."""
    from care_maps.replan.answer import offer_next
    from care_maps.replan.attempts import ReplanConfig
    from care_maps.replan.strategies import StrategyName

    if first.offer is None:
        return []
    offers = [first.offer]
    skip = [p.candidate for p in first.passed]
    while len(offers) < config.attempts:
        nxt = offer_next(
            answer, target, [o.candidate for o in offers], skip=skip,
            config=ReplanConfig(
                strategy=StrategyName.MAX_CONFIDENCE, exclude_radius=config.exclude_radius
            ),
        )  # fmt: skip
        if nxt.offer is None:
            break
        offers.append(nxt.offer)
        skip += [p.candidate for p in nxt.passed]
    return offers


def query_rrd(
    rrd: Path,
    store: Path,
    target: Any,
    answer: Any,
    config: BatchConfig,
    first: Any,
    ranking: Any,
    note: str | None,
) -> None:
    """The first ``config.attempts`` attempts by max confidence (``first``: the JSON's
    first attempt, :func:`care_maps.replan.answer.first_offer`), each driven from where the last
    ended, with their candidates labelled by rank and confidence."""
    from care_maps.query.paths import walk
    from care_maps.query.viz import Answer

    cmap = target.cmap
    offers = _attempts(answer, target, config, first)
    attempts = [o.drive for o in offers]
    travel = answer.travel
    legs = None
    if answer.usable:
        legs = walk(travel.roadmap, travel.start, answer.paths.start_reach, attempts)
    conf = np.array([float(ranking.conf[g.candidate]) for g in attempts])
    drawn = Answer(
        title=f'"{target.match.names[0]}" in the {cmap.kind} map ({target.match.method})',
        labels=[
            f"#{int(ranking.rank[g.candidate])} {c:.2f}"
            for g, c in zip(attempts, conf, strict=True)
        ],
        confidence=conf,
        goals=attempts,
        legs=legs,
        start=travel.start if legs is not None else None,
        notes=[
            "Attempts: max confidence, each after the earlier ones failed (on a grid, away "
            "from the cells tried), each driven from where the last ended; candidates "
            "without a goal that keeps --clearance and is reachable passed over.",
            *([note] if note else []),
        ],
    )
    _write(rrd, store, drawn, answer.goals)


def replan_rrd(
    rrd: Path,
    store: Path,
    target: Any,
    answer: Any,
    visited: list[int],
    chosen: Any,
    note: str | None,
) -> None:
    """The visited candidates' goals (their ways unknown: where the robot came from is
    not), then the next goal ``chosen`` with its way from the start (the JSON's ``path``)."""
    from care_maps.query.paths import Leg
    from care_maps.query.viz import Answer

    cmap, goals, travel = target.cmap, answer.goals, answer.travel
    before = [goals.goal(cmap, c) for c in visited if 0 <= c < cmap.num_candidates]
    attempts = [*before, *([chosen] if chosen is not None else [])]
    legs = None
    if answer.usable:
        way = [Leg(chosen, travel.start, travel.waypoints(chosen))] if chosen else []
        legs = [None] * len(before) + way
    shown = [g.candidate for g in attempts]
    drawn = Answer(
        title=f'next for "{target.match.names[0]}" in the {cmap.kind} map',
        labels=[f"attempt {k}" for k in range(1, len(shown) + 1)],
        confidence=np.asarray(target.confidence())[shown],
        goals=attempts,
        legs=legs,
        start=travel.start if legs is not None else None,
        notes=[note] if note else [],
        visited=len(before),
    )
    _write(rrd, store, drawn, goals)
