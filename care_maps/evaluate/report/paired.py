"""The paired table of ``results.md``: each CARe entry against max confidence and against the
best random top-k, over the same queries (statistics in :mod:`care_maps.evaluate.paired`), and the
per-query outcomes that it and the pre-registered tables read."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from care_maps.evaluate.config import NO_CRITERION
from care_maps.evaluate.paired import compare, comparison_rng
from care_maps.evaluate.report.rates import QUERY_KEYS, RULE_KEYS, per_query
from care_maps.evaluate.scene_test import MIN_SCENES
from care_maps.replan.strategies import STRATEGIES, Criterion, StrategyName

__all__ = [
    "CARE_STRATEGIES",
    "INTERVAL_NOTE",
    "Outcomes",
    "difference_text",
    "outcomes",
    "paired_markdown",
    "paired_table",
]

CARE_STRATEGIES = tuple(
    name
    for name, s in STRATEGIES.items()
    if s.uses_set and not s.random and not s.needs_truth and not s.travel
)
"""The CARe rules: a measure chosen over a candidate set (ablations included). The travel
rules (``nearest_topk``, ``*_near``) are compared on SPL (:mod:`care_maps.evaluate.report.travel`)."""


Outcomes = tuple[dict, dict]
"""What :func:`outcomes` returns: ``(solved, first)``."""


def outcomes(attempts: pa.Table) -> Outcomes:
    """``solved[(map, protocol)][(strategy, criterion, k)][query key]`` (mean over seeds of
    "some attempt succeeded", as :func:`care_maps.evaluate.report.rates.per_query`) and ``first[...]`` (the
    first attempt succeeded), grouped by Arrow rather than row by row.

    Plain dicts, not the defaultdicts they are built in: the report hands one result to its
    five tables (:func:`care_maps.evaluate.report.write.write_report`; half a second a table at 8 scenes),
    and a read of a missing key must not add it for the next table.
    """
    first_rows = (
        attempts.filter(pc.equal(attempts.column("attempt"), 1))
        .group_by([*QUERY_KEYS, *RULE_KEYS], use_threads=False)
        .aggregate([("success", "max")])
        .to_pylist()
    )
    firsts = {
        (tuple(r[c] for c in QUERY_KEYS), (r["strategy"], r["criterion"], r["k"])): r["success_max"]
        for r in first_rows
    }
    solved: dict = defaultdict(lambda: defaultdict(dict))
    first: dict = defaultdict(lambda: defaultdict(dict))
    for r in per_query(attempts).to_pylist():
        query = tuple(r[c] for c in QUERY_KEYS)
        rule = (r["strategy"], r["criterion"], r["k"])
        solved[r["map"], r["protocol"]][rule][query] = r["solved"]
        first[r["map"], r["protocol"]][rule][query] = bool(firsts.get((query, rule), False))
    return _plain(solved), _plain(first)


def _plain(nested: dict) -> dict:
    return {key: dict(rules) for key, rules in nested.items()}


def _best(rules: dict, strategy: str) -> tuple[str, str, int] | None:
    """The (strategy, criterion, k) of ``strategy`` with the highest success."""
    cands = [(np.mean(list(v.values())), r) for r, v in rules.items() if r[0] == strategy]
    if not cands:
        return None
    return max(cands, key=lambda c: (c[0], -c[1][2]))[1]


def paired_table(
    attempts: pa.Table,
    *,
    bootstrap: int = 10_000,
    seed: int = 0,
    known: Outcomes | None = None,
) -> pa.Table:
    """One row per (map, protocol, CARe strategy, criterion, k, baseline): the paired
    difference in success, its bootstrap interval, discordant counts, first-attempt ties
    and McNemar's p. Baselines: ``max_confidence`` and the best ``random_topk`` (the
    criterion and k with the highest success in that map and protocol). ``known``: the
    :func:`outcomes` of ``attempts``, when the caller has them."""
    solved, first = known or outcomes(attempts)
    rows = []
    for (kind, protocol), rules in sorted(solved.items()):
        baselines: list[tuple[str, str, int]] = []
        if (StrategyName.MAX_CONFIDENCE, NO_CRITERION, 0) in rules:
            baselines.append((StrategyName.MAX_CONFIDENCE, NO_CRITERION, 0))
        best_random = _best(rules, StrategyName.RANDOM_TOPK)
        if best_random is not None:
            baselines.append(best_random)
        for rule in sorted(r for r in rules if r[0] in CARE_STRATEGIES):
            queries = sorted(rules[rule])
            for base in baselines:
                a = np.array([rules[rule][q] for q in queries])
                b = np.array([rules[base].get(q, np.nan) for q in queries])
                keep = ~np.isnan(b)
                qs = [q for q, k in zip(queries, keep, strict=True) if k]
                res = compare(
                    a[keep], b[keep],
                    rng=comparison_rng(seed, kind, protocol, *rule, *base),
                    first_a=np.array([first[kind, protocol][rule][q] for q in qs], bool),
                    first_b=np.array([first[kind, protocol][base][q] for q in qs], bool),
                    n_resamples=bootstrap, groups=np.array([q[0] for q in qs], dtype=object),
                )  # fmt: skip
                rows.append(
                    {
                        "map": kind, "protocol": protocol, "strategy": rule[0],
                        "criterion": rule[1], "k": rule[2], "baseline": base[0],
                        "baseline_criterion": base[1], "baseline_k": base[2],
                        "n_queries": res.n, "rate": 100 * res.rate_a,
                        "baseline_rate": 100 * res.rate_b, "diff": 100 * res.diff,
                        "lo": 100 * res.lo, "hi": 100 * res.hi, "only_strategy": res.only_a,
                        "only_baseline": res.only_b, "both": res.both, "neither": res.neither,
                        "first_ties": res.first_ties, "mcnemar_p": res.p_value,
                        "scene_p": res.scene_p, "scenes": res.scenes,
                    }
                )  # fmt: skip
    return pa.Table.from_pylist(rows)


def _fmt(value: float, spec: str = ".0f") -> str:
    return "" if value is None or np.isnan(value) else format(value, spec)


def difference_text(row: dict) -> str:
    """``+1.2 [-0.4, +2.9]``: a row's difference and its 95% interval, or, where the interval
    does not hold (fewer scenes than :data:`care_maps.evaluate.scene_test.MIN_SCENES`), the words."""
    diff = f"{row['diff']:+.1f}"
    lo, hi = row.get("lo"), row.get("hi")
    if lo is None or hi is None or np.isnan(lo) or np.isnan(hi):
        scenes = row.get("scenes") or 0
        effective = row.get("effective_scenes")
        if effective is not None and not np.isnan(effective) and effective < scenes - 0.05:
            # unequal scenes: the rule counts effective ones (care_maps.evaluate.scene_test)
            return f"{diff} [no interval: {scenes} scenes, {effective:.1f} effective; it holds from {MIN_SCENES}]"
        return f"{diff} [no interval: {scenes} scene(s), it holds from {MIN_SCENES}]"
    return f"{diff} [{lo:+.1f}, {hi:+.1f}]"


INTERVAL_NOTE = (
    "95% intervals: the scene-level sign-flip test inverted (scenes are the units: queries of "
    f"one scene share a map), valid with few scenes and printed from {MIN_SCENES} scenes on; "
    "scene p: that test at 0"
)
"""How every paired table's interval is made, as its caption says it."""


def paired_markdown(table: pa.Table) -> str:
    """Each (non-ablation) CARe strategy and criterion at its best k, against each baseline;
    the full table (every k, the ablations) is ``paired.parquet``."""
    if table.num_rows == 0:
        return ""
    out = [
        "## Paired comparisons (same queries)\n",
        "Difference in success (percentage points) of each CARe rule at its best k against max "
        f"confidence and the best random top-k, over the same queries ({INTERVAL_NOTE}), "
        "the discordant queries (only CARe / only the baseline solved them; "
        "fractional where the random baseline is averaged over seeds), the queries both solved "
        "at the first attempt (which every strategy shares: ties by construction), and the "
        "exact McNemar p-value (deterministic pairs only). Every k: `paired.parquet`.\n",
    ]
    rows = table.to_pylist()
    shown = [s for s in CARE_STRATEGIES if not STRATEGIES[s].ablation]
    for kind, protocol in sorted({(r["map"], r["protocol"]) for r in rows}):
        here = [r for r in rows if r["map"] == kind and r["protocol"] == protocol]
        out.append(f"### {kind}, protocol `{protocol}` ({here[0]['n_queries']} queries)\n")
        out.append(
            "| CARe rule | criterion | k | vs | success | baseline | difference [95% CI] "
            "| only CARe | only baseline | first-attempt ties | McNemar p | scene p |"
        )
        out.append("|---|---|---:|---|---:|---:|---|---:|---:|---:|---:|---:|")
        for strategy in shown:
            for criterion in (Criterion.CONFIDENCE, Criterion.CATEGORY):
                mine = [
                    r for r in here if r["strategy"] == strategy and r["criterion"] == criterion
                ]
                if not mine:
                    continue
                best_k = max(mine, key=lambda r: (r["rate"], -r["k"]))["k"]
                for r in (r for r in mine if r["k"] == best_k):
                    base = STRATEGIES[r["baseline"]].label
                    if r["baseline_criterion"] != NO_CRITERION:
                        base += f" ({r['baseline_criterion']}, k={r['baseline_k']})"
                    out.append(
                        f"| {STRATEGIES[strategy].label} | {criterion} | {r['k']} | {base} "
                        f"| {r['rate']:.1f} | {r['baseline_rate']:.1f} "
                        f"| {difference_text(r)} "
                        f"| {_fmt(r['only_strategy'], '.4g')} | {_fmt(r['only_baseline'], '.4g')} "
                        f"| {r['first_ties']} | {_fmt(r['mcnemar_p'], '.3g')} "
                        f"| {_fmt(r['scene_p'], '.3g')} |"
                    )
        out.append("")
    return "\n".join(out)
