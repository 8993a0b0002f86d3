"""Pre-registered evaluation: the paper's settings fixed in advance, best-of-k apart.

Choosing the best of 30 (criterion, k) settings after seeing the results inflates a gain,
and a p-value that ignores the 30 tries means little. So the headline table uses only the
settings the paper highlights (:data:`PAPER_SETTINGS`, fixed before any of our results
were seen) and corrects for those few comparisons (Holm); the best setting over k is
reported in its own table, Holm-corrected over every setting tried.

Every comparison is paired (the same queries) with scenes as the units: the scene-level
sign-flip test and its inverted interval (queries of one scene share a map and a perception
draw; no interval below 6 effective scenes; :mod:`care_maps.evaluate.scene_test`). Every
multiplicity correction is over the scene-level p-values (Holm); a family whose scenes
cannot give a p-value small enough for its correction (the smallest sign-flip p is
``2 / 2^G``) says so instead of printing one. The exact McNemar test over the discordant
queries is kept in the tables as what it is, a query-level test (queries of one scene are
not independent, so it rejects too often when scenes differ). Baselines: max confidence,
the best random top-k (the criterion and k where random choice did best, chosen after the
fact: its p-values are multiplied by the number of random settings it was chosen from),
and two non-CARe rules, the largest candidate and the candidate seen in the most views.

A rule reads "better" or "worse" only from its Holm-corrected scene p, and "within +-3
points" only from the equivalence test (:data:`care_maps.evaluate.scene_test.EQUIVALENCE_MARGIN`,
fixed before the run), Holm-corrected alike; anything else is "not shown to differ", with
its interval.

Also reported apart: queries no strategy can solve (no candidate matches: the oracle
fails), which dilute every difference alike; under the ``instance`` protocol, queries whose
first pick matched a *same-class sibling* (another instance of the target class: the class
protocol's first attempt succeeded where this query's failed), where the second attempt
has to move to another instance of the same class; and success by class.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
import pyarrow as pa

from care_maps.core.maps import MapKind
from care_maps.core.store import write_table_atomic
from care_maps.evaluate.config import NO_CRITERION
from care_maps.evaluate.paired import compare, comparison_rng, holm, mcnemar_exact
from care_maps.evaluate.report.paired import (
    CARE_STRATEGIES,
    INTERVAL_NOTE,
    Outcomes,
    difference_text,
    outcomes,
)
from care_maps.evaluate.report.rates import QUERY_KEYS
from care_maps.evaluate.scene_test import ALPHA, EQUIVALENCE_MARGIN
from care_maps.replan.strategies import STRATEGIES, Criterion, StrategyName

__all__ = [
    "PAPER_SETTINGS",
    "PAPER_SUCCESS",
    "PREREGISTERED_BOOTSTRAP",
    "SAME_BY_CONSTRUCTION",
    "TABLE_NAMES",
    "PreregisteredResult",
    "Reading",
    "Rule",
    "best_of_k_table",
    "by_class_table",
    "headline_table",
    "preregistered_markdown",
    "query_breakdown",
    "reading",
    "with_holm",
    "write_preregistered",
]

PREREGISTERED_BOOTSTRAP = 2000
"""Bootstrap resamples of an interval without scenes (the scene test enumerates every sign
pattern up to :data:`care_maps.evaluate.scene_test.EXACT_MAX_SCENES` scenes and draws
:data:`care_maps.evaluate.scene_test.N_SIGN_FLIPS` above); 0: no interval."""
TABLE_NAMES = ("preregistered", "best_of_k", "by_class", "query_breakdown")
"""The tables :func:`write_preregistered` writes, each as ``<name>.parquet``, in order."""

Rule = tuple[str, str, int]
"""(strategy, criterion, k); criterion ``-`` and k 0 for rules without a candidate set."""

PAPER_SETTINGS: dict[str, tuple[Rule, ...]] = {
    MapKind.INSTANCES: (
        (StrategyName.MAX_ENTROPY, Criterion.CONFIDENCE, 8),
        (StrategyName.MIN_STDERR, Criterion.CATEGORY, 2),
        (StrategyName.MIN_PWKL, Criterion.CATEGORY, 40),
    ),
    MapKind.GRID: (
        (StrategyName.MAX_ENTROPY, Criterion.CONFIDENCE, 4),
        (StrategyName.MIN_STDERR, Criterion.CONFIDENCE, 4),
        (StrategyName.MIN_PWKL, Criterion.CONFIDENCE, 16),
    ),
}
"""The settings the paper's tables highlight (``docs/method.md``), fixed before our results."""

MAX_CONF: Rule = (StrategyName.MAX_CONFIDENCE, NO_CRITERION, 0)
NON_CARE: tuple[Rule, ...] = (
    (StrategyName.LARGEST, NO_CRITERION, 0),
    (StrategyName.MOST_VIEWS, NO_CRITERION, 0),
)
"""The non-CARe baselines: biggest mask, most views."""

PAPER_SUCCESS: dict[tuple[MapKind, Rule], float] = {
    (MapKind.INSTANCES, (StrategyName.NO_REPLAN, NO_CRITERION, 0)): 12.09,
    (MapKind.INSTANCES, MAX_CONF): 17.05,
    (MapKind.INSTANCES, (StrategyName.MAX_ENTROPY, Criterion.CONFIDENCE, 8)): 18.20,
    (MapKind.INSTANCES, (StrategyName.MIN_STDERR, Criterion.CATEGORY, 2)): 18.07,
    (MapKind.INSTANCES, (StrategyName.MIN_PWKL, Criterion.CATEGORY, 40)): 18.75,
    (MapKind.INSTANCES, (StrategyName.ORACLE, NO_CRITERION, 0)): 36.40,
    (MapKind.GRID, (StrategyName.NO_REPLAN, NO_CRITERION, 0)): 54.4,
    (MapKind.GRID, MAX_CONF): 67.0,
    (MapKind.GRID, (StrategyName.MAX_ENTROPY, Criterion.CONFIDENCE, 4)): 81.0,
    (MapKind.GRID, (StrategyName.MIN_STDERR, Criterion.CONFIDENCE, 4)): 82.7,
    (MapKind.GRID, (StrategyName.MIN_PWKL, Criterion.CONFIDENCE, 16)): 85.2,
}
"""The paper's success with two attempts (%, Matterport3D; ``docs/method.md``, The paper's
figures): OpenMask3D for instances, VLMaps for the grid, printed beside ours."""

SAME_BY_CONSTRUCTION: dict[tuple[MapKind, str], str] = {
    (MapKind.GRID, StrategyName.LARGEST): "grid cells share one size: ties go to confidence",
}
"""Rules that equal max confidence by construction on a map, with why: their rows are
marked, not read as findings."""


class Reading(StrEnum):
    """What a comparison row may be read as (:func:`reading`)."""

    BETTER = "better"
    WORSE = "worse"
    EQUIVALENT = f"within ±{100 * EQUIVALENCE_MARGIN:.0f} points"
    NOT_SHOWN = "not shown to differ"
    CANNOT_REJECT = "too few scenes for this family"
    BY_CONSTRUCTION = "same by construction"


def _label(rule: Rule) -> str:
    name, criterion, k = rule
    label = STRATEGIES[name].label if name in STRATEGIES else name
    return label if criterion == NO_CRITERION else f"{label} ({criterion}, k={k})"


def _best_random(rules: dict) -> Rule | None:
    cands = [
        (np.mean(list(v.values())), r) for r, v in rules.items() if r[0] == StrategyName.RANDOM_TOPK
    ]
    return max(cands, key=lambda c: (c[0], -c[1][2]))[1] if cands else None


def _compare(rules: dict, first: dict, rule: Rule, base: Rule, *, bootstrap: int, seed: int):
    """Paired comparison of ``rule`` against ``base`` over shared queries, scenes as units."""
    queries = sorted(q for q in rules[rule] if q in rules[base])
    a = np.array([rules[rule][q] for q in queries], np.float64)
    b = np.array([rules[base][q] for q in queries], np.float64)
    scenes = np.array([q[0] for q in queries], dtype=object)
    return compare(
        a,
        b,
        rng=comparison_rng(seed, "prereg", *rule, *base),
        first_a=np.array([first[rule][q] for q in queries], bool),
        first_b=np.array([first[base][q] for q in queries], bool),
        n_resamples=bootstrap,
        groups=scenes,
    )


def _row(
    kind: str, protocol: str, rule: Rule, base: Rule, res, family: str, choices: int = 1
) -> dict:
    """One comparison; ``choices``: how many baselines ``base`` was chosen from after the
    fact (its scene p-values are multiplied by it, Bonferroni)."""
    p, approx = res.p_value, False
    if np.isnan(p):  # a seed-averaged side: McNemar on the mean discordant counts, rounded
        p, approx = mcnemar_exact(round(res.only_a), round(res.only_b)), True
    scene = res.scene
    return {
        "map": kind,
        "protocol": protocol,
        "family": family,
        "strategy": rule[0],
        "criterion": rule[1],
        "k": rule[2],
        "baseline": _label(base),
        "n_queries": res.n,
        "rate": 100 * res.rate_a,
        "baseline_rate": 100 * res.rate_b,
        "diff": 100 * res.diff,
        "lo": 100 * res.lo,
        "hi": 100 * res.hi,
        "only_strategy": res.only_a,
        "only_baseline": res.only_b,
        "mcnemar_p": p,
        "mcnemar_approx": approx,
        "scene_p": res.scene_p,
        "scenes": res.scenes,
        "effective_scenes": scene.effective if scene is not None else float("nan"),
        "scene_min_p": scene.min_p if scene is not None else float("nan"),
        "scene_mc_error": scene.mc_error if scene is not None else float("nan"),
        "equivalence_p": scene.equivalence_p if scene is not None else float("nan"),
        "baseline_choices": choices,
        "paper_rate": PAPER_SUCCESS.get((MapKind(kind), rule), float("nan")),
        "same_by_construction": SAME_BY_CONSTRUCTION.get((MapKind(kind), rule[0]), "")
        if base == MAX_CONF
        else "",
    }


def with_holm(rows: list[dict], keys: Sequence[str]) -> list[dict]:
    """Holm over each family of rows sharing ``keys`` (``()``: one family), on the scene-level
    p-values (times ``baseline_choices``, 1 where a row has none): ``holm_p`` of the difference, ``holm_equivalence_p`` of the
    equivalence test; ``family_size``, ``family_min_p`` (the smallest corrected p any row
    could reach) and ``family_can_reject`` (whether that passes Holm's first step,
    ``alpha / m``); then each row's :func:`reading`."""
    groups: dict[tuple, list[int]] = {}
    for i, r in enumerate(rows):
        groups.setdefault(tuple(r[k] for k in keys), []).append(i)
    for idx in groups.values():

        def scaled(name: str, idx: list[int] = idx) -> np.ndarray:
            values = [min(1.0, rows[i][name] * rows[i].get("baseline_choices", 1)) for i in idx]
            return np.array(values, np.float64)

        adjusted = holm(scaled("scene_p"))
        equivalent = holm(scaled("equivalence_p"))
        floor = float(np.nanmin(scaled("scene_min_p"))) if idx else float("nan")
        for j, i in enumerate(idx):
            rows[i]["holm_p"] = float(adjusted[j])
            rows[i]["holm_equivalence_p"] = float(equivalent[j])
            rows[i]["family_size"] = len(idx)
            rows[i]["family_min_p"] = floor
            rows[i]["family_can_reject"] = bool(floor <= ALPHA / len(idx))
            rows[i]["reading"] = reading(rows[i])
    return rows


def reading(row: dict) -> str:
    """What a row with its Holm-corrected p-values may be read as (:class:`Reading`)."""
    if row.get("same_by_construction"):
        return Reading.BY_CONSTRUCTION
    if not row["family_can_reject"]:
        return Reading.CANNOT_REJECT
    if row["holm_p"] <= ALPHA:
        return Reading.BETTER if row["diff"] > 0 else Reading.WORSE
    if row["holm_equivalence_p"] <= ALPHA:
        return Reading.EQUIVALENT
    return Reading.NOT_SHOWN


def headline_table(
    attempts: pa.Table,
    settings: dict[str, tuple[Rule, ...]] | None = None,
    *,
    bootstrap: int = PREREGISTERED_BOOTSTRAP,
    seed: int = 0,
    known: Outcomes | None = None,
) -> pa.Table:
    """The pre-registered rules and the non-CARe baselines against max confidence and the
    best random top-k, per map and protocol; Holm over each (map, protocol, baseline).
    ``known``, here and below: the :func:`~care_maps.evaluate.report.paired.outcomes` of
    ``attempts``, when the caller has them."""
    settings = PAPER_SETTINGS if settings is None else settings
    solved, first = known or outcomes(attempts)
    rows = []
    for (kind, protocol), rules in sorted(solved.items()):
        bases = [b for b in (MAX_CONF, _best_random(rules)) if b is not None and b in rules]
        mine = [r for r in (*settings.get(kind, ()), *NON_CARE) if r in rules]
        randoms = sum(r[0] == StrategyName.RANDOM_TOPK for r in rules)
        for base in bases:
            choices = 1 if base == MAX_CONF else randoms
            for rule in mine:
                family = "non-CARe baseline" if rule in NON_CARE else "pre-registered"
                res = _compare(
                    rules, first[kind, protocol], rule, base, bootstrap=bootstrap, seed=seed
                )
                rows.append(_row(kind, protocol, rule, base, res, family, choices))
    return pa.Table.from_pylist(with_holm(rows, ("map", "protocol", "baseline", "family")))


def best_of_k_table(
    attempts: pa.Table,
    *,
    bootstrap: int = PREREGISTERED_BOOTSTRAP,
    seed: int = 0,
    known: Outcomes | None = None,
) -> pa.Table:
    """Every CARe setting tried against max confidence, Holm-corrected over all of them
    (per map and protocol); ``best`` marks each strategy's best setting."""
    solved, first = known or outcomes(attempts)
    rows = []
    for (kind, protocol), rules in sorted(solved.items()):
        if MAX_CONF not in rules:
            continue
        tried = sorted(r for r in rules if r[0] in CARE_STRATEGIES)
        here = []
        for rule in tried:
            res = _compare(
                rules, first[kind, protocol], rule, MAX_CONF, bootstrap=bootstrap, seed=seed
            )
            here.append(_row(kind, protocol, rule, MAX_CONF, res, "best-of-k"))
        here = with_holm(here, ("map", "protocol"))
        for name in {r["strategy"] for r in here}:
            best = max(
                (r for r in here if r["strategy"] == name), key=lambda r: (r["rate"], -r["k"])
            )
            best["best"] = True
        for r in here:
            r.setdefault("best", False)
            r["settings_tried"] = len(tried)
        rows += here
    return pa.Table.from_pylist(rows)


def by_class_table(
    attempts: pa.Table,
    settings: dict[str, tuple[Rule, ...]] | None = None,
    *,
    known: Outcomes | None = None,
) -> pa.Table:
    """Success (%) per target class of max confidence and each pre-registered rule, with the
    queries each rule wins and loses against max confidence."""
    settings = PAPER_SETTINGS if settings is None else settings
    solved, _ = known or outcomes(attempts)
    targets = _targets(attempts)
    rows = []
    for (kind, protocol), rules in sorted(solved.items()):
        if MAX_CONF not in rules:
            continue
        base = rules[MAX_CONF]
        for rule in (r for r in settings.get(kind, ()) if r in rules):
            by: dict[str, list[tuple[float, float]]] = {}
            for q, v in rules[rule].items():
                if q in base:
                    by.setdefault(targets.get(q, "?"), []).append((v, base[q]))
            for target, pairs in sorted(by.items()):
                a, b = np.array(pairs).T
                rows.append(
                    {
                        "map": kind, "protocol": protocol, "strategy": rule[0],
                        "criterion": rule[1], "k": rule[2], "target": target,
                        "n_queries": len(a), "rate": 100 * float(a.mean()),
                        "max_confidence_rate": 100 * float(b.mean()),
                        "wins": float(np.sum(a * (1 - b))), "losses": float(np.sum(b * (1 - a))),
                    }
                )  # fmt: skip
    return pa.Table.from_pylist(rows)


def _targets(attempts: pa.Table) -> dict[tuple, str]:
    cols = [attempts.column(k).to_pylist() for k in (*QUERY_KEYS, "target")]
    return {tuple(row[:-1]): row[-1] for row in zip(*cols, strict=True)}


def query_breakdown(
    attempts: pa.Table,
    settings: dict[str, tuple[Rule, ...]] | None = None,
    *,
    known: Outcomes | None = None,
) -> pa.Table:
    """Per map and protocol: queries, those no strategy can solve (the oracle fails), and,
    under the ``instance`` protocol, those whose first pick was a same-class sibling, with
    how often each baseline and pre-registered rule recovers them."""
    settings = PAPER_SETTINGS if settings is None else settings
    solved, first = known or outcomes(attempts)
    targets = _targets(attempts)
    class_first: dict[tuple, bool] = {}
    for (kind, protocol), f in first.items():
        if protocol == "class" and (StrategyName.NO_REPLAN, NO_CRITERION, 0) in f:
            for q, ok in f[StrategyName.NO_REPLAN, NO_CRITERION, 0].items():
                class_first[q[0], kind, q[3], targets.get(q, q[4])] = ok
    rows = []
    for (kind, protocol), rules in sorted(solved.items()):
        oracle = rules.get((StrategyName.ORACLE, NO_CRITERION, 0), {})
        f0 = first[kind, protocol].get((StrategyName.NO_REPLAN, NO_CRITERION, 0), {})
        queries = sorted(f0)
        unsolvable = [q for q in queries if oracle.get(q, 1.0) == 0]
        sibling = [
            q
            for q in queries
            if protocol == "instance"
            and not f0[q]
            and class_first.get((q[0], kind, q[3], targets.get(q)), False)
        ]
        row = {
            "map": kind,
            "protocol": protocol,
            "queries": len(queries),
            "first_attempt_solved": int(sum(f0[q] for q in queries)),
            "unsolvable": len(unsolvable),
            "sibling_first_pick": len(sibling),
        }
        for rule in (MAX_CONF, *NON_CARE, *settings.get(kind, ())):
            if rule in rules and sibling:
                row[f"siblings recovered: {_label(rule)}"] = float(
                    sum(rules[rule].get(q, 0.0) for q in sibling)
                )
        rows.append(row)
    keys = list(dict.fromkeys(k for r in rows for k in r))  # every row's columns, in order
    return pa.Table.from_pylist([{k: r.get(k) for k in keys} for r in rows])


def _fmt(v: float, spec: str) -> str:
    return "" if v is None or (isinstance(v, float) and np.isnan(v)) else format(v, spec)


def _p_text(row: dict, name: str) -> str:
    """A Holm-corrected p, or why there is none: a family its scenes cannot reject."""
    if not row["family_can_reject"]:
        return "–"
    return _fmt(row[name], ".3g")


def _comparison_lines(rows: list[dict], title: str) -> list[str]:
    out = [
        title,
        "| map | protocol | rule | vs | success | paper | baseline | difference [95% CI] "
        "| scene p | Holm p | equivalence Holm p | reading |",
        "|---|---|---|---|---:|---:|---:|---|---:|---:|---:|---|",
    ]
    notes: dict[tuple, str] = {}
    for r in rows:
        rule = _label((r["strategy"], r["criterion"], r["k"]))
        base = r["baseline"]
        if r["baseline_choices"] > 1:
            base += f" (best of {r['baseline_choices']}: p x{r['baseline_choices']})"
        scene_p = _fmt(r["scene_p"], ".3g")
        if r["scene_mc_error"] and r["scene_mc_error"] > 0:
            scene_p += f" ±{r['scene_mc_error']:.1g}"
        why = f" ({r['same_by_construction']})" if r["same_by_construction"] else ""
        out.append(
            f"| {r['map']} | {r['protocol']} | {rule} | {base} | {r['rate']:.1f} "
            f"| {_fmt(r['paper_rate'], '.2f')} | {r['baseline_rate']:.1f} | {difference_text(r)} "
            f"| {scene_p} | {_p_text(r, 'holm_p')} | {_p_text(r, 'holm_equivalence_p')} "
            f"| {r['reading']}{why} |"
        )
        if not r["family_can_reject"]:
            key = (r["map"], r["protocol"], r["baseline"], r["family"])
            notes[key] = (
                f"{r['map']}, {r['protocol']}, {r['family']} vs {r['baseline']}: a family of "
                f"{r['family_size']} over {r['scenes']} scenes cannot reject (its smallest "
                f"scene p, {r['family_min_p']:.3g}, exceeds {ALPHA:g}/{r['family_size']}); "
                f"it needs more scenes."
            )
    out.append("")
    out += [f"- {n}" for n in notes.values()]
    return [*out, ""] if notes else out


def preregistered_markdown(
    headline: pa.Table, best: pa.Table, by_class: pa.Table, breakdown: pa.Table
) -> str:
    """The four tables as ``results.md`` shows them (by class: ten classes with the most
    queries; every class in ``by_class.parquet``)."""
    out = [
        "## Pre-registered comparison (the paper's settings, fixed in advance)\n",
        f"Paired over the same queries; {INTERVAL_NOTE}; Holm over the scene p-values of "
        "the pre-registered rules of each map, protocol and baseline (the query-level "
        "McNemar p is in preregistered.parquet, not used here: queries of one scene are not "
        f"independent); equivalence: two one-sided sign-flip tests at "
        f"±{100 * EQUIVALENCE_MARGIN:.0f} points (fixed before the run). Paper: the paper's "
        "figure for the rule (Matterport3D; OpenMask3D instances, VLMaps grid).\n",
    ]
    out += _comparison_lines(headline.to_pylist(), "")
    rows = [r for r in best.to_pylist() if r["best"] and not STRATEGIES[r["strategy"]].ablation]
    if rows:
        n = rows[0]["settings_tried"]
        out += _comparison_lines(
            rows,
            f"### Best setting over k, chosen after the fact (Holm over all {n} settings tried)\n",
        )
    if breakdown.num_rows:
        out.append("### Queries no strategy can solve, and same-class siblings\n")
        cols = breakdown.column_names
        out.append("| " + " | ".join(cols) + " |")
        out.append("|" + "---|" * len(cols))
        for r in breakdown.to_pylist():
            cells = [
                _fmt(r[c], ".4g")
                if isinstance(r[c], float)
                else ("" if r[c] is None else str(r[c]))
                for c in cols
            ]
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
    if by_class.num_rows:
        out.append(
            "### By class (pre-registered rules against max confidence; most-queried classes)\n"
        )
        out.append(
            "| map | protocol | rule | class | queries | success | max confidence | wins | losses |"
        )
        out.append("|---|---|---|---|---:|---:|---:|---:|---:|")
        rows = by_class.to_pylist()
        for key in sorted(
            {(r["map"], r["protocol"], r["strategy"], r["criterion"], r["k"]) for r in rows}
        ):
            mine = [
                r
                for r in rows
                if (r["map"], r["protocol"], r["strategy"], r["criterion"], r["k"]) == key
            ]
            for r in sorted(mine, key=lambda r: (-r["n_queries"], r["target"]))[:10]:
                out.append(
                    f"| {r['map']} | {r['protocol']} | {_label(key[2:])} | {r['target']} "
                    f"| {r['n_queries']} | {r['rate']:.1f} | {r['max_confidence_rate']:.1f} "
                    f"| {r['wins']:.3g} | {r['losses']:.3g} |"
                )
        out.append("")
    return "\n".join(out)


@dataclass(frozen=True)
class PreregisteredResult:
    """What :func:`write_preregistered` wrote."""

    markdown: str
    headline: pa.Table
    best_of_k: pa.Table
    by_class: pa.Table
    breakdown: pa.Table
    paths: tuple[Path, ...]


def write_preregistered(
    attempts: pa.Table,
    out: Path,
    *,
    bootstrap: int = PREREGISTERED_BOOTSTRAP,
    seed: int = 0,
    known: Outcomes | None = None,
) -> PreregisteredResult:
    """Write ``preregistered.parquet``, ``best_of_k.parquet``, ``by_class.parquet`` and
    ``query_breakdown.parquet`` under ``out``; returns them and their markdown."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    known = known or outcomes(attempts)
    tables = (
        headline_table(attempts, bootstrap=bootstrap, seed=seed, known=known),
        best_of_k_table(attempts, bootstrap=bootstrap, seed=seed, known=known),
        by_class_table(attempts, known=known),
        query_breakdown(attempts, known=known),
    )
    paths = tuple(out / f"{n}.parquet" for n in TABLE_NAMES)
    for table, path in zip(tables, paths, strict=True):
        write_table_atomic(table, path)
    return PreregisteredResult(preregistered_markdown(*tables), *tables, paths)
