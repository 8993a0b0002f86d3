"""Does each CARe rule's measure tell right candidates from wrong ones inside its candidate
set, at the same confidence?

This module plays the situation a rule faces (a failed first attempt, then the criterion's
top-k set, :func:`care_maps.evaluate.discrimination.second_attempt_set`) on every query of a
dataset's stores, as the evaluation builds them (same queries, rooms, grid protocols), and
sums the pair counts of :mod:`care_maps.evaluate.discrimination` per (map, protocol, rule,
criterion, k), keeping each scene's counts for the scene-level intervals:

- ``matched``: (right, wrong) pairs of one query's set whose confidences lie within
  :data:`care_maps.evaluate.discrimination.MATCH_CALIPER` nats of log-odds of each other,
  with confidence's own AUROC over the same pairs beside the measure's (the check that the
  caliper held confidence equal: 0.5 when it did), each with its 95% interval with scenes
  as the units (:func:`care_maps.evaluate.discrimination.scene_auroc`);
- ``stratified``: pairs within one 1-nat bin of log-confidence, with confidence's own AUROC
  there (kept to show that the bins do not hold confidence equal);
- ``unstratified``: every (right, wrong) pair of the set.

What it covers: whether the measure orders a right candidate above a wrong one *of the same
set at the same confidence*. What it does not: a rule can beat max confidence without it,
by where its pick lies rather than by what the measure sees (after a failed grid attempt
without exclusion, any pick away from the failed cell's neighbours gains: uniform random
replanning beats max confidence there), and it can have it and still lose (its one pick
from the whole set against confidence's next candidate). So the AUROC is neither a
necessary nor a sufficient condition for a gain; it says what the measure adds to
confidence within the set, and nothing about where the pick takes the robot.

Run by :func:`care_maps.research.reproduce.discriminate` on a measured dataset's stores; the
maths is :mod:`care_maps.evaluate.discrimination`'s, this module only gathers the counts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from care_maps.core.maps import MapKind
from care_maps.evaluate.config import EvalConfig
from care_maps.evaluate.discrimination import (
    MATCH_CALIPER,
    Discrimination,
    rule_discrimination,
    scene_auroc,
    second_attempt_set,
)
from care_maps.evaluate.job import Scene, scene_query_sets
from care_maps.evaluate.paired import comparison_rng
from care_maps.evaluate.scene_test import MIN_SCENES
from care_maps.evaluate.success import QuerySet
from care_maps.query.confidence import log_confidence
from care_maps.query.map import REPLAN_COLUMNS
from care_maps.replan.strategies import Criterion, StrategyName
from care_maps.runtime.threads import Work, threads_for

__all__ = ["MEASURE_RULES", "discrimination_markdown", "discrimination_table", "reading"]

MEASURE_RULES = (StrategyName.MAX_ENTROPY, StrategyName.MIN_STDERR, StrategyName.MIN_PWKL)
"""The CARe rules whose measure is tested (the ablations are their mirror images)."""


@dataclass(frozen=True)
class _Key:
    map: str
    protocol: str
    strategy: str
    criterion: str
    k: int


def _query_set_counts(
    qs: QuerySet, kind: MapKind, config: EvalConfig, radius: float
) -> dict[tuple[str, str, int], Discrimination]:
    """Counts of every measure rule, criterion and k on one query set."""
    cmap = qs.cmap
    if not cmap.num_candidates or not len(qs.queries):
        return {}
    conf = log_confidence(cmap, qs.class_ids)
    ks = config.ks(kind)
    rank = (
        cmap.class_rank(qs.class_ids, limit=max(ks))
        if Criterion.CATEGORY in config.criteria
        else None
    )
    columns = {m: cmap.column(m) for m in REPLAN_COLUMNS}
    positions = cmap.positions if kind == MapKind.GRID else None
    out: dict[tuple[str, str, int], Discrimination] = {}
    for criterion in config.criteria:
        for k in ks:
            member = second_attempt_set(
                conf, criterion, k, rank=rank, success=qs.success,
                positions=positions, exclude_radius=radius,
            )  # fmt: skip
            for rule in MEASURE_RULES:
                out[rule, criterion, k] = rule_discrimination(
                    rule, conf, qs.success, member, columns
                )
    return out


def _scene_counts(scene: Scene, config: EvalConfig) -> dict[_Key, Discrimination]:
    totals: dict[_Key, Discrimination] = {}
    for kind, _, protocol, radius, sets in scene_query_sets(scene, config):
        for qs in sets:
            for (rule, criterion, k), d in _query_set_counts(qs, kind, config, radius).items():
                key = _Key(kind, protocol, rule, criterion, k)
                totals[key] = totals[key] + d if key in totals else d
    return totals


def discrimination_table(scenes: Sequence[Scene], config: EvalConfig | None = None) -> pa.Table:
    """One row per (map, protocol, rule, criterion, k), summed over every query of
    ``scenes``: the matched pairs' AUROC, the measure's and confidence's own, each with its
    scene-level interval (and the measure's p-value of 0.5); the 1-nat strata's, the
    measure's and confidence's own; and every pair's."""
    config = config or EvalConfig()
    per_scene: dict[_Key, list[Discrimination]] = {}
    with threads_for(Work.EVAL):
        for scene in scenes:
            for key, d in _scene_counts(scene, config).items():
                per_scene.setdefault(key, []).append(d)
    order = sorted(per_scene, key=lambda k: (k.map, k.protocol, k.strategy, k.criterion, k.k))
    return pa.Table.from_pylist([_row(key, per_scene[key], config.seed) for key in order])


def _row(key: _Key, scenes: list[Discrimination], seed: int) -> dict[str, object]:
    """One table row from the per-scene counts of one key."""
    total = sum(scenes, Discrimination())
    name = (key.map, key.protocol, key.strategy, key.criterion, key.k)
    measure = scene_auroc(
        [d.matched for d in scenes], rng=comparison_rng(seed, "discrimination", *name)
    )
    conf = scene_auroc(
        [d.matched_confidence for d in scenes],
        rng=comparison_rng(seed, "discrimination-confidence", *name),
    )
    return {
        "map": str(key.map), "protocol": key.protocol, "strategy": str(key.strategy),
        "criterion": str(key.criterion), "k": key.k, "caliper": MATCH_CALIPER,
        "pairs_matched": total.matched.pairs, "auroc_matched": measure.auroc,
        "auroc_matched_low": measure.low, "auroc_matched_high": measure.high,
        "p_matched": measure.p_value,
        "confidence_auroc_matched": conf.auroc,
        "confidence_auroc_matched_low": conf.low, "confidence_auroc_matched_high": conf.high,
        "scenes_matched": measure.scenes, "effective_scenes_matched": measure.effective,
        "pairs": total.stratified.pairs, "auroc": total.stratified.auroc,
        "confidence_auroc": total.stratified_confidence.auroc,
        "pairs_all": total.unstratified.pairs, "auroc_all": total.unstratified.auroc,
    }  # fmt: skip


def reading(
    auroc: float,
    low: float | None,
    high: float | None,
    confidence_low: float | None,
    confidence_high: float | None,
) -> str:
    """What a matched AUROC may be read as, from its scene-level interval and confidence's
    own: a direction only where the interval leaves out 0.5 and confidence's own interval
    holds it."""
    if auroc is None or np.isnan(auroc):
        return "no matched pair"
    if low is None or high is None or confidence_low is None or confidence_high is None:
        return "too few scenes for an interval"
    if not confidence_low <= 0.5 <= confidence_high:
        return "confidence not held equal"
    if low > 0.5:
        return "prefers the right candidate"
    if high < 0.5:
        return "prefers the wrong candidate"
    return "not shown to differ from 0.5"


def discrimination_markdown(
    table: pa.Table, settings: dict[str, tuple[tuple[str, str, int], ...]]
) -> str:
    """The matched-pairs AUROC of each measure at the pre-registered (criterion, k) of its
    rule, per map and protocol, with confidence's own AUROC in the same pairs, both with
    95% intervals over scenes, beside the 1-nat strata's and every pair's; then what the
    figure covers and what it does not."""
    rows = table.to_pylist()
    caliper = rows[0]["caliper"] if rows else MATCH_CALIPER
    out = [
        "| map | protocol | rule (criterion, k) | matched pairs (scenes) "
        "| confidence's own AUROC in the pairs [95%] | measure's AUROC in the pairs [95%] "
        "| reading | 1-nat bins: measure's AUROC (confidence's own) | all pairs: measure's AUROC |",
        "|---|---|---|---:|---:|---:|---|---:|---:|",
    ]
    for r in rows:
        wanted = settings.get(MapKind(r["map"]), ())
        if (r["strategy"], r["criterion"], r["k"]) not in wanted:
            continue
        conf = _ci(r["confidence_auroc_matched"], r["confidence_auroc_matched_low"],
                   r["confidence_auroc_matched_high"])  # fmt: skip
        meas = _ci(r["auroc_matched"], r["auroc_matched_low"], r["auroc_matched_high"])
        read = reading(
            r["auroc_matched"], r["auroc_matched_low"], r["auroc_matched_high"],
            r["confidence_auroc_matched_low"], r["confidence_auroc_matched_high"],
        )  # fmt: skip
        out.append(
            f"| {r['map']} | {r['protocol']} | {r['strategy']} ({r['criterion']}, k={r['k']}) "
            f"| {r['pairs_matched']} ({r['scenes_matched']}) | {conf} | {meas} | {read} "
            f"| {_f(r['auroc'])} ({_f(r['confidence_auroc'])}) | {_f(r['auroc_all'])} |"
        )
    out += ["", _legend(caliper)]
    return "\n".join(out) + "\n"


def _legend(caliper: float) -> str:
    return (
        "Matched pairs: a right and a wrong candidate of the same query's set whose "
        f"confidences are within {caliper:g} nats of log-odds of each other (odds within a "
        f"factor {np.exp(caliper):.2f}). Confidence's own AUROC in those pairs is the check "
        "that they hold confidence equal (0.5 when they do); the 1-nat bins, shown beside, "
        "need not. Intervals: 95%, by the sign-flip test over scenes (none below "
        f"{MIN_SCENES} effective scenes); a direction is read only where the interval "
        "leaves out 0.5 and confidence's own interval holds it. What the AUROC covers: "
        "whether the measure, in its rule's direction, ranks a right candidate of the set "
        "above an equally confident wrong one. What it does not: a gain that comes from "
        "where the pick lies (after a failed grid attempt without exclusion, from leaving "
        "the failed cell's neighbours), so it is neither a necessary nor a sufficient "
        "condition for beating max confidence.\n"
    )


def _ci(v: float, low: float | None, high: float | None) -> str:
    if v is None or np.isnan(v):
        return "–"
    return f"{v:.2f}" if low is None or high is None else f"{v:.2f} [{low:.2f}, {high:.2f}]"


def _f(v: float) -> str:
    return "–" if v is None or np.isnan(v) else f"{v:.2f}"
