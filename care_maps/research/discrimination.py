"""The necessary condition of CARe, measured: does each rule's measure tell right candidates
from wrong ones inside its candidate set, at the same confidence?

A CARe rule can only beat max confidence where its measure (max entropy, min stderr, min
pwKL), read in the rule's direction, prefers a candidate that solves the query over one that
does not *among candidates of equal confidence*: its AUROC there must exceed 0.5. This module
plays the situation the rule faces (a failed first attempt, then the criterion's top-k set,
:func:`care_maps.evaluate.discrimination.second_attempt_set`) on every query of a dataset's stores, as
the evaluation builds them (same queries, rooms, grid protocols), and sums the pair counts of
:mod:`care_maps.evaluate.discrimination` into one AUROC per (map, protocol, rule, criterion, k):
``stratified`` (pairs within one 1-nat log-confidence bin: confidence held fixed) and
``unstratified`` (every pair of the set).

    python -m care_maps.research.discrimination STORES... (the stores of an evaluated dataset)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from care_maps.core.maps import MapKind
from care_maps.evaluate.config import EvalConfig
from care_maps.evaluate.discrimination import (
    Discrimination,
    rule_discrimination,
    second_attempt_set,
)
from care_maps.evaluate.job import Scene, scene_query_sets
from care_maps.evaluate.success import QuerySet
from care_maps.query.confidence import log_confidence
from care_maps.query.map import REPLAN_COLUMNS
from care_maps.replan.strategies import Criterion, StrategyName
from care_maps.runtime.threads import Work, threads_for

__all__ = ["MEASURE_RULES", "discrimination_markdown", "discrimination_table"]

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
    out = {}
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
    """One row per (map, protocol, rule, criterion, k): pair counts and AUROC, stratified
    by confidence and not, summed over every query of ``scenes``."""
    config = config or EvalConfig()
    totals: dict[_Key, Discrimination] = {}
    with threads_for(Work.EVAL):
        for scene in scenes:
            for key, d in _scene_counts(scene, config).items():
                totals[key] = totals[key] + d if key in totals else d
    rows = []
    for key in sorted(totals, key=lambda k: (k.map, k.protocol, k.strategy, k.criterion, k.k)):
        d = totals[key]
        rows.append(
            {
                "map": str(key.map), "protocol": key.protocol, "strategy": str(key.strategy),
                "criterion": str(key.criterion), "k": key.k,
                "pairs": d.stratified.pairs, "auroc": d.stratified.auroc,
                "pairs_all": d.unstratified.pairs, "auroc_all": d.unstratified.auroc,
            }
        )  # fmt: skip
    return pa.Table.from_pylist(rows)


def discrimination_markdown(
    table: pa.Table, settings: dict[MapKind, tuple[tuple[str, str, int], ...]]
) -> str:
    """The AUROC of each measure at the pre-registered (criterion, k) of its rule, per map
    and protocol: stratified by confidence (the condition) and not."""
    rows = table.to_pylist()
    out = [
        "| map | protocol | rule (criterion, k) | pairs at equal confidence | AUROC at equal confidence | all pairs | AUROC, all pairs |",
        "|---|---|---|---:|---:|---:|---:|",
    ]
    for r in rows:
        wanted = settings.get(MapKind(r["map"]), ())
        if (r["strategy"], r["criterion"], r["k"]) not in wanted:
            continue
        out.append(
            f"| {r['map']} | {r['protocol']} | {r['strategy']} ({r['criterion']}, k={r['k']}) "
            f"| {r['pairs']} | {_f(r['auroc'])} | {r['pairs_all']} | {_f(r['auroc_all'])} |"
        )
    return "\n".join(out) + "\n"


def _f(v: float) -> str:
    return "–" if v is None or np.isnan(v) else f"{v:.3f}"
