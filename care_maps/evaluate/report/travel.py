"""What replanning costs a robot: path length and SPL of every rule, paired SPL tests, and
success against distance travelled (:mod:`care_maps.evaluate.spl` defines each).

Each (strategy, criterion) is shown at the k of its best SPL. Its SPL is compared, over the
same queries, with max confidence and with the nearest of the top-k set (the non-CARe
baseline a roboticist tries first, at its own best criterion and k): the difference in
percentage points with a paired bootstrap interval (queries resampled as pairs) and the
Wilcoxon signed-rank p-value (:func:`care_maps.evaluate.paired.compare_measure`), uncorrected: the
pre-registered family is the success table's.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import pyarrow as pa

from care_maps.core.outputs import write_atomic
from care_maps.evaluate.config import NO_CRITERION
from care_maps.evaluate.paired import compare_measure, comparison_rng
from care_maps.evaluate.report.paired import difference_text
from care_maps.evaluate.report.rates import MAP_TITLES, QUERY_KEYS, RULE_KEYS, _label, per_episode
from care_maps.evaluate.spl import success_within
from care_maps.replan.strategies import STRATEGIES, StrategyName

__all__ = [
    "PLOTTED",
    "best_spl_rules",
    "plot_travel",
    "spl_pairs",
    "travel_curves",
    "travel_markdown",
]

Rule = tuple[str, str, int]
"""(strategy, criterion, k)."""
MAX_CONF: Rule = (StrategyName.MAX_CONFIDENCE, NO_CRITERION, 0)
PLOTTED = (
    StrategyName.NO_REPLAN,
    StrategyName.MAX_CONFIDENCE,
    StrategyName.RANDOM,
    StrategyName.ORACLE,
    StrategyName.NEAREST_TOPK,
    StrategyName.MAX_ENTROPY,
    StrategyName.MIN_STDERR,
    StrategyName.MIN_PWKL,
    StrategyName.MAX_ENTROPY_NEAR,
    StrategyName.MIN_STDERR_NEAR,
    StrategyName.MIN_PWKL_NEAR,
)
"""Rules of the success-against-distance plot (each at its best SPL over criterion and k)."""


def _measured(summary: pa.Table) -> list[dict]:
    return [r for r in summary.to_pylist() if not r["closed_form"] and r.get("n_travel")]


def best_spl_rules(summary: pa.Table) -> dict[tuple[str, str], list[dict]]:
    """(map, protocol) -> the summary row of each (strategy, criterion) at its best SPL's k
    (ties: the smaller k), in the registry's order."""
    best: dict[tuple, dict] = {}
    for r in _measured(summary):
        key = (r["map"], r["protocol"], r["strategy"], r["criterion"])
        if key not in best or (r["spl"], -r["k"]) > (best[key]["spl"], -best[key]["k"]):
            best[key] = r
    order = {name: i for i, name in enumerate(STRATEGIES)}
    out: dict[tuple[str, str], list[dict]] = {}
    for (kind, protocol, *_), r in sorted(
        best.items(), key=lambda kv: (kv[0][:2], order.get(kv[0][2], 99), kv[0][3])
    ):
        out.setdefault((kind, protocol), []).append(r)
    return out


def _spl_by_rule(queries: pa.Table) -> dict[tuple[str, str], dict[Rule, dict[tuple, float]]]:
    """(map, protocol) -> rule -> query key -> SPL (NaN: no travel)."""
    out: dict = {}
    for r in queries.select([*QUERY_KEYS, *RULE_KEYS, "spl"]).to_pylist():
        rules = out.setdefault((r["map"], r["protocol"]), {})
        rule = (r["strategy"], r["criterion"], r["k"])
        rules.setdefault(rule, {})[tuple(r[c] for c in QUERY_KEYS)] = r["spl"]
    return out


def spl_pairs(queries: pa.Table, summary: pa.Table, *, bootstrap: int, seed: int = 0) -> pa.Table:
    """One row per (map, protocol, rule at its best SPL, baseline): the paired SPL
    comparison (module docstring). ``queries``: :func:`care_maps.evaluate.report.rates.per_query`."""
    spl = _spl_by_rule(queries)
    rows = []
    for (kind, protocol), shown in best_spl_rules(summary).items():
        rules = spl.get((kind, protocol), {})
        nearest = [r for r in shown if r["strategy"] == StrategyName.NEAREST_TOPK]
        bases = [MAX_CONF] if MAX_CONF in rules else []
        if nearest:
            top = max(nearest, key=lambda r: (r["spl"], -r["k"]))
            bases.append((top["strategy"], top["criterion"], top["k"]))
        for r in shown:
            rule = (r["strategy"], r["criterion"], r["k"])
            if STRATEGIES[r["strategy"]].needs_truth:
                continue
            for base in bases:
                if base == rule:
                    continue
                keys = sorted(q for q in rules[rule] if q in rules[base])
                res = compare_measure(
                    np.array([rules[rule][q] for q in keys], np.float64),
                    np.array([rules[base][q] for q in keys], np.float64),
                    rng=comparison_rng(seed, "spl", kind, protocol, *rule, *base),
                    n_resamples=bootstrap,
                    groups=np.array([q[0] for q in keys], dtype=object),
                )
                rows.append(
                    {
                        "map": kind, "protocol": protocol, "strategy": rule[0],
                        "criterion": rule[1], "k": rule[2], "baseline": base[0],
                        "baseline_criterion": base[1], "baseline_k": base[2],
                        "n_queries": res.n, "spl": 100 * res.mean_a,
                        "baseline_spl": 100 * res.mean_b, "diff": 100 * res.diff,
                        "lo": 100 * res.lo, "hi": 100 * res.hi, "better": res.better,
                        "worse": res.worse, "wilcoxon_p": res.p_value,
                        "scene_p": res.scene_p, "scenes": res.scenes,
                    }
                )  # fmt: skip
    return pa.Table.from_pylist(rows)


def _fmt(value: float | None, spec: str) -> str:
    return "" if value is None or np.isnan(value) else format(value, spec)


def _base_name(rule: Rule) -> str:
    label = STRATEGIES[rule[0]].label
    return label if rule[1] == NO_CRITERION else f"{label} ({rule[1]}, k={rule[2]})"


def travel_markdown(summary: pa.Table, pairs: pa.Table, start: str = "") -> str:
    """The travel section of ``results.md``: per map and protocol, each rule at its best
    SPL's k with success, SPL, path length and its paired SPL difference against each
    baseline. ``start``: where the walks start (" from the
    recording's first pose"), empty when travel is off: then no section."""
    shown = best_spl_rules(summary)
    if not shown:  # travel asked for (``start``) and no query walked: say why
        return (
            f"## Travel: path length and SPL\n\nNo query walked{start}: no scene has the grid's "
            "free space (its obstacle layers), or, from the first pose, views whose first "
            "pose lies on it.\n"
            if start
            else ""
        )
    pair_rows = pairs.to_pylist() if pairs.num_rows else []
    out = [
        "## Travel: path length and SPL\n",
        f"Each attempt sequence walks{start}: to the first goal, then from each goal reached "
        "to the next, along the free space a robot of the set clearance can drive "
        "(an unreachable goal is an attempt that adds no distance and leaves the robot where "
        "it was). SPL = S l / max(p, l) (Anderson et al. 2018): S a success at a goal the "
        "robot reached, p the metres walked, l the shortest path to the nearest success; "
        "means over the queries with travel, in %. Each rule at the k of its best SPL; "
        "ΔSPL: the paired difference against each baseline (percentage points, 95% paired "
        "bootstrap interval, Wilcoxon signed-rank p, uncorrected). Every pair: "
        "`paired_spl.parquet`; success within a distance: `plots/travel_*.png`.\n",
    ]
    for (kind, protocol), rows in shown.items():
        here = [p for p in pair_rows if p["map"] == kind and p["protocol"] == protocol]
        bases = list(
            dict.fromkeys((p["baseline"], p["baseline_criterion"], p["baseline_k"]) for p in here)
        )
        title = MAP_TITLES.get(kind, kind).split(":")[0]
        walked, asked = rows[0]["n_travel"], rows[0]["n_queries"]
        out.append(f"### {title}, protocol `{protocol}` ({walked} of {asked} queries walked)\n")
        heads = "".join(f" | ΔSPL vs {_base_name(b)} | p" for b in bases)
        out.append(f"| rule | criterion | k | success | SPL | path (m){heads} |")
        out.append("|---|---|---:|---:|---:|---:|" + "---|---:|" * len(bases))
        for r in rows:
            cells = []
            for b in bases:
                match = [
                    p for p in here
                    if (p["strategy"], p["criterion"], p["k"]) == (r["strategy"], r["criterion"], r["k"])
                    and (p["baseline"], p["baseline_criterion"], p["baseline_k"]) == b
                ]  # fmt: skip
                if not match:
                    cells += ["", ""]
                    continue
                m = match[0]
                cells += [
                    difference_text(m),
                    _fmt(m["wilcoxon_p"], ".3g"),
                ]
            k = str(r["k"]) if STRATEGIES[r["strategy"]].uses_set else ""
            crit = r["criterion"] if STRATEGIES[r["strategy"]].uses_set else NO_CRITERION
            tail = "".join(f" | {c}" for c in cells)
            out.append(
                f"| {_label(r['strategy'])} | {crit} | {k} | {r['rate']:.1f} | {r['spl']:.1f} "
                f"| {r['path']:.2f}{tail} |"
            )
        out.append("")
    return "\n".join(out)


def travel_curves(attempts: pa.Table, summary: pa.Table) -> dict[tuple[str, str], list[tuple]]:
    """(map, protocol) -> (strategy, label, path, solved at a goal reached, weight: one over
    the seeds) of the episodes of each plotted rule."""
    episodes = per_episode(attempts).to_pylist()
    wanted: dict[tuple, str] = {}
    for (kind, protocol), rows in best_spl_rules(summary).items():
        best: dict[str, dict] = {}
        for r in rows:
            if r["strategy"] in PLOTTED and (
                r["strategy"] not in best or r["spl"] > best[r["strategy"]]["spl"]
            ):
                best[r["strategy"]] = r
        for r in best.values():
            label = _label(r["strategy"])
            if STRATEGIES[r["strategy"]].uses_set:
                label += f" ({r['criterion'][:4]}, k={r['k']})"
            wanted[kind, protocol, r["strategy"], r["criterion"], r["k"]] = label
    grouped: dict[tuple, list[tuple[float, float, int]]] = {}
    for e in episodes:
        key = (e["map"], e["protocol"], e["strategy"], e["criterion"], e["k"])
        if key in wanted and not np.isnan(e["spl"]):
            grouped.setdefault(key, []).append((e["path"], e["reached"], e["seed"]))
    out: dict = {}
    for key, label in wanted.items():
        eps = np.array(grouped.get(key, []), np.float64).reshape(-1, 3)
        if len(eps) == 0:  # no walk of this rule here (another scene's, or no travel)
            continue
        seeds = len(np.unique(eps[:, 2]))
        out.setdefault(key[:2], []).append(
            (key[2], label, eps[:, 0], eps[:, 1] > 0, np.full(len(eps), 1.0 / seeds))
        )
    return out


def plot_travel(curves: dict[tuple[str, str], list[tuple]], out_dir: Path) -> list[Path]:
    """One PNG per (map, protocol): the share of queries solved (at a goal reached) within
    each distance travelled, one step curve per plotted rule (:data:`PLOTTED`; ``curves``:
    :func:`travel_curves`, small arrays, so the drawing can run on another worker)."""
    if not curves:
        return []
    import matplotlib as mpl

    mpl.use("Agg")
    import matplotlib.pyplot as plt

    from care_maps.evaluate.report.rates import _COLOURS

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for (kind, protocol), lines in sorted(curves.items()):
        top = max((float(p.max()) for _, _, p, _, _ in lines if len(p)), default=1.0)
        budgets = np.linspace(0.0, max(top, 1e-3) * 1.02, 400)
        fig, ax = plt.subplots(figsize=(9, 4.5))
        for strategy, label, path, solved, weight in lines:
            share = 100 * success_within(path, solved, budgets, weight)
            dashed = STRATEGIES[strategy].travel
            ax.step(
                budgets, share, where="post", label=label, linestyle="--" if dashed else "-",
                color=_COLOURS.get(strategy, "tab:gray"), linewidth=1.6,
            )  # fmt: skip
        ax.set_xlabel("distance travelled (m)")
        ax.set_ylabel("queries solved at a goal reached (%)")
        ax.grid(alpha=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8, frameon=False)
        ax.set_title(f"{MAP_TITLES.get(kind, kind).split(':')[0]}, protocol {protocol}")
        fig.tight_layout()
        path = out_dir / f"travel_{kind}_{protocol}.png"
        write_atomic(path, partial(fig.savefig, dpi=110, format="png"))
        plt.close(fig)
        paths.append(path)
    return paths
