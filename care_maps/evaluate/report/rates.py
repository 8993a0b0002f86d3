"""From attempt rows to the paper's tables: success rates, their scene-level CIs, per scene, AUROC, plots.

Success of a query under a strategy is "some attempt succeeded" (within the configured number
of attempts); random strategies average it over seeds first, and their closed-form
expectation is reported as its own row. Rates are means over queries of all scenes (each
query counts once, as in the paper); 95% confidence intervals resample queries.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from functools import partial
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from care_maps.core.maps import MapKind
from care_maps.core.outputs import write_atomic
from care_maps.evaluate.config import DEFAULT_BOOTSTRAP, NO_CRITERION
from care_maps.evaluate.paired import comparison_rng, paired_interval
from care_maps.evaluate.scene_test import MIN_SCENES
from care_maps.evaluate.spl import spl
from care_maps.fuse.measures import MEASURE_COLUMNS
from care_maps.replan.strategies import CRITERIA, STRATEGIES, StrategyName

__all__ = [
    "AUROC_MEASURES",
    "PER_SCENE",
    "auroc",
    "auroc_table",
    "markdown_tables",
    "per_episode",
    "per_query",
    "per_scene_markdown",
    "plot_success",
    "summarise",
]

AUROC_MEASURES = MEASURE_COLUMNS
"""Columns of the first attempt whose power to predict its failure is reported."""

QUERY_KEYS = ["scene", "map", "protocol", "unit", "query"]
RULE_KEYS = ["strategy", "criterion", "k"]
"""What a replan rule is in the attempt rows: its strategy, criterion and k (criterion
``care_maps.evaluate.config.NO_CRITERION`` and k 0 for the strategies without a candidate set)."""
MAP_TITLES: dict[str, str] = {
    MapKind.INSTANCES: "Instance map (OpenMask3D-like): retrieval success (%)",
    MapKind.GRID: "Grid map (VLMaps-like): subgoal success (%)",
}


def per_episode(attempts: pa.Table) -> pa.Table:
    """One row per episode (query, strategy, criterion, k, seed): ``solved`` (some attempt
    succeeded), ``expected_max`` and the walk (:mod:`care_maps.evaluate.spl`; NaN without travel):
    ``path`` (metres), ``reached`` (solved at a goal the robot reached) and ``spl``."""
    attempts = _with_travel(attempts)
    hit = pc.and_(attempts.column("success"), pc.is_finite(attempts.column("distance")))
    aggregates = [("success", "max"), ("expected", "max"), ("hit", "max"), ("walked", "max"),
                  ("shortest", "max")]  # fmt: skip
    episodes = (
        attempts.append_column("hit", hit)
        .group_by([*QUERY_KEYS, *RULE_KEYS, "seed"], use_threads=False)
        .aggregate(aggregates)
    )
    path = episodes.column("walked_max").to_numpy(zero_copy_only=False).astype(np.float64)
    shortest = episodes.column("shortest_max").to_numpy(zero_copy_only=False).astype(np.float64)
    reached = episodes.column("hit_max").to_numpy(zero_copy_only=False).astype(np.float64)
    reached[np.isnan(shortest)] = np.nan
    episodes = (
        episodes.append_column("solved", pc.cast(episodes.column("success_max"), pa.float64()))
        .append_column("path", pa.array(path))
        .append_column("reached", pa.array(reached))
        .append_column("spl", pa.array(spl(reached, shortest, path)))
    )
    return episodes.drop_columns(["success_max", "hit_max", "walked_max"])


def per_query(attempts: pa.Table) -> pa.Table:
    """One row per (query, strategy, criterion, k): ``solved`` (mean over seeds of "some
    attempt succeeded"), ``expected`` (closed form, random strategies only) and the walk's
    ``path``, ``reached`` and ``spl`` (:func:`per_episode`), means over seeds."""
    episodes = per_episode(attempts)
    out = episodes.group_by([*QUERY_KEYS, *RULE_KEYS], use_threads=False).aggregate(
        [("solved", "mean"), ("expected_max", "max"), ("path", "mean"), ("reached", "mean"),
         ("spl", "mean")]
    )  # fmt: skip
    names = {"solved_mean": "solved", "expected_max_max": "expected", "path_mean": "path",
             "reached_mean": "reached", "spl_mean": "spl"}  # fmt: skip
    out = out.rename_columns([names.get(n, n) for n in out.column_names])
    return out.sort_by([(k, "ascending") for k in [*QUERY_KEYS, *RULE_KEYS]])


TRAVEL_COLUMNS = ("distance", "walked", "shortest")
"""The attempt rows' travel columns (:data:`care_maps.evaluate.job.ATTEMPT_SCHEMA`)."""


def _with_travel(attempts: pa.Table) -> pa.Table:
    """``attempts`` with NaN travel columns where it has none (rows made without walks)."""
    for name in TRAVEL_COLUMNS:
        if name not in attempts.column_names:
            nan = np.full(attempts.num_rows, np.nan, np.float32)
            attempts = attempts.append_column(name, pa.array(nan))
    return attempts


def _interval(
    values: np.ndarray, scenes: np.ndarray, n: int, seed: int, key: dict
) -> tuple[float, float]:
    """95% interval of a success rate with scenes as the units: the scene-level sign-flip
    test inverted (:func:`care_maps.evaluate.paired.paired_interval` against zero), NaN below
    :data:`care_maps.evaluate.scene_test.MIN_SCENES` scenes, where no interval holds, or with ``n``
    (the report's resamples) 0. The generator is the row's own (:func:`comparison_rng`)."""
    if len(values) == 0 or n <= 0:
        return float("nan"), float("nan")
    rng = comparison_rng(seed, "rate", *key.values())
    lo, hi, _, _ = paired_interval(
        values, np.zeros_like(values), rng=rng, groups=scenes, n_resamples=n
    )
    return lo, hi


def _groups(table: pa.Table, keys: Sequence[str]) -> Iterator[tuple[dict, np.ndarray]]:
    """``(key values, row indices)`` of each distinct combination of ``keys``, in order of
    first appearance (as ``group_by`` orders them), in one sort rather than a scan per group."""
    if table.num_rows == 0:
        return
    values = [table.column(k).to_numpy(zero_copy_only=False) for k in keys]
    code = np.zeros(table.num_rows, np.int64)
    for column in values:
        _, inverse = np.unique(column, return_inverse=True)
        code = code * (int(inverse.max()) + 1) + inverse
    _, first, group = np.unique(code, return_index=True, return_inverse=True)
    members = np.split(np.argsort(group, kind="stable"), np.cumsum(np.bincount(group))[:-1])
    for g in np.argsort(first):
        row = first[g]
        key = {
            k: (v[row].item() if hasattr(v[row], "item") else v[row])
            for k, v in zip(keys, values, strict=True)
        }
        yield key, members[g]


def summarise(
    queries: pa.Table, *, bootstrap: int = DEFAULT_BOOTSTRAP, seed: int = 0, by_scene: bool = False
) -> pa.Table:
    """Success rate (%) with a 95% interval (scenes as units, :func:`_interval`) per (map, protocol, strategy, criterion, k)
    (and scene with ``by_scene``). ``closed_form`` tells the random strategies' expected
    success (their own rows, from the ``expected`` column) from the measured one. Measured
    rows also give the walk over the ``n_travel`` queries that have one: mean ``path`` (m)
    and ``spl`` (%); null without travel."""
    rows = []
    keys = ["map", "protocol", *RULE_KEYS] + (["scene"] if by_scene else [])
    scenes = queries.column("scene").to_numpy(zero_copy_only=False)
    columns = {
        c: queries.column(c).to_numpy(zero_copy_only=False).astype(float)
        if c in queries.column_names
        else np.full(queries.num_rows, np.nan)  # queries made without walks
        for c in ("solved", "expected", "path", "spl")
    }
    for key, idx in _groups(queries, keys):
        for closed_form, column in ((False, "solved"), (True, "expected")):
            values = columns[column][idx]
            random = STRATEGIES[key["strategy"]].random
            if closed_form and (not random or np.isnan(values).all()):
                continue
            known = ~np.isnan(values)
            lo, hi = _interval(
                values[known], scenes[idx][known], 0 if by_scene else bootstrap, seed,
                {**key, "closed_form": closed_form},
            )  # fmt: skip
            values = values[known]
            walked = {c: columns[c][idx] for c in ("path", "spl")}
            walks = ~np.isnan(walked["spl"]) & (not closed_form)
            rows.append(
                {
                    **key,
                    "closed_form": closed_form,
                    "rate": 100 * float(values.mean()) if len(values) else float("nan"),
                    "lo": 100 * lo,
                    "hi": 100 * hi,
                    "n_queries": len(values),
                    "path": float(walked["path"][walks].mean()) if walks.any() else None,
                    "spl": 100 * float(walked["spl"][walks].mean()) if walks.any() else None,
                    "n_travel": int(walks.sum()),
                }
            )
    out = pa.Table.from_pylist(rows)
    for name in ("path", "spl"):  # null, not NaN, without walks: a typed float column
        if name in out.column_names:
            at = out.column_names.index(name)
            out = out.set_column(at, name, out.column(name).cast(pa.float64()))
    return out


def auroc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` for the ``positive`` class: the Mann-Whitney U
    statistic of the positives' scores over the negatives' (``scipy.stats.mannwhitneyu``,
    midranks for ties), divided by n_pos * n_neg; NaN scores are dropped."""
    score = np.asarray(score, dtype=np.float64)
    positive = np.asarray(positive, dtype=bool)
    keep = ~np.isnan(score)
    score, positive = score[keep], positive[keep]
    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    from scipy.stats import mannwhitneyu  # here: scipy.stats costs every scene worker ~2 s

    u = mannwhitneyu(score[positive], score[~positive], method="asymptotic").statistic
    return float(u / (n_pos * n_neg))


def auroc_table(attempts: pa.Table) -> pa.Table:
    """AUROC of each measure of the first attempt for predicting that it fails, per map and
    protocol (> 0.5: a higher value means failure is more likely)."""
    first = attempts.filter(
        pc.and_(
            pc.equal(attempts.column("strategy"), StrategyName.NO_REPLAN),
            pc.equal(attempts.column("attempt"), 1),
        )
    )
    rows = []
    for key in first.group_by(["map", "protocol"], use_threads=False).aggregate([]).to_pylist():
        part = first.filter(
            pc.and_(
                pc.equal(first.column("map"), key["map"]),
                pc.equal(first.column("protocol"), key["protocol"]),
            )
        )
        failed = ~part.column("success").to_numpy(zero_copy_only=False)
        row = {**key, "n_first": part.num_rows, "n_failed": int(failed.sum())}
        for measure in AUROC_MEASURES:
            row[measure] = auroc(part.column(measure).to_numpy(zero_copy_only=False), failed)
        rows.append(row)
    return pa.Table.from_pylist(rows)


Rule = tuple[str, bool, str]
"""A table row: (strategy, closed form, criterion)."""


def _uses_set(strategy: str) -> bool:
    """Whether a strategy's rows have a criterion and k (the registry says, not the name)."""
    return STRATEGIES[strategy].uses_set


def _k_of(strategy: str, k: int) -> int:
    """The k a summary row of ``strategy`` has at column k (0: it takes no candidate set)."""
    return k if _uses_set(strategy) else 0


def _rate_lookup(summary: pa.Table) -> dict[tuple, dict]:
    return {
        (r["map"], r["protocol"], r["strategy"], r["closed_form"], r["criterion"], r["k"]): r
        for r in summary.to_pylist()
    }


def _row_order(summary: pa.Table, kind: str, protocol: str) -> list[Rule]:
    """The rows of one table in the registry's order, each closed form after its strategy."""
    present = {
        (r["strategy"], r["closed_form"], r["criterion"])
        for r in summary.to_pylist()
        if r["map"] == kind and r["protocol"] == protocol
    }
    found = {c for _, _, c in present}
    criteria = sorted(found - set(CRITERIA)) + [c for c in CRITERIA if c in found]
    return [
        (name, closed, criterion)
        for name in STRATEGIES
        for closed in (False, True)
        for criterion in criteria
        if (name, closed, criterion) in present
    ]


def _label(strategy: str, closed_form: bool = False) -> str:
    label = STRATEGIES[strategy].label
    return f"{label} (closed form)" if closed_form else label


def _criterion_cell(strategy: str, criterion: str) -> str:
    return criterion if _uses_set(strategy) else NO_CRITERION


def _ci_cell(row: dict | None) -> str:
    """A rate's interval, or why there is none (too few scenes for one to hold)."""
    if row is None:
        return ""
    if np.isnan(row["lo"]) or np.isnan(row["hi"]):
        return f"– (< {MIN_SCENES} scenes)"
    return f"[{row['lo']:.1f}, {row['hi']:.1f}]"


def markdown_tables(summary: pa.Table, ks: dict[str, Sequence[int]], *, ci: bool = False) -> str:
    """Tables laid out like the paper's Tables 1 and 2: rows strategy x criterion, columns k.

    **Bold**: best of the column (oracle and closed-form rows excluded); *italic*: best of
    the row over k. With ``ci`` each cell is the 95% bootstrap interval instead.
    """
    lookup = _rate_lookup(summary)
    out = []
    for kind, protocol in sorted({(r["map"], r["protocol"]) for r in summary.to_pylist()}):
        kvals = list(ks[kind])
        rows = _row_order(summary, kind, protocol)

        grid = np.array(
            [
                [
                    lookup.get((kind, protocol, s, cf, c, _k_of(s, k)), {}).get("rate", np.nan)
                    for k in kvals
                ]
                for s, cf, c in rows
            ]
        )
        ranked = [
            i for i, (s, cf, _) in enumerate(rows) if not STRATEGIES[s].needs_truth and not cf
        ]
        col_best = np.nanmax(grid[ranked], axis=0) if ranked else np.full(len(kvals), np.nan)
        n_q = max(
            (
                r["n_queries"]
                for r in summary.to_pylist()
                if r["map"] == kind and r["protocol"] == protocol
            ),
            default=0,
        )
        title = f"{MAP_TITLES.get(kind, kind)}, protocol `{protocol}`"
        out.append(f"### {title}{' — 95% CI, scenes as units' if ci else ''} ({n_q} queries)\n")
        out.append(
            "| Replan strategy | Selection criteria | " + " | ".join(f"k={k}" for k in kvals) + " |"
        )
        out.append("|---|---|" + "---:|" * len(kvals))
        for i, (strategy, closed, criterion) in enumerate(rows):
            cells = []
            for j, k in enumerate(kvals):
                value = grid[i, j]
                if ci:
                    r = lookup.get(
                        (kind, protocol, strategy, closed, criterion, _k_of(strategy, k))
                    )
                    cells.append(_ci_cell(r))
                    continue
                text = "" if np.isnan(value) else f"{value:.2f}"
                if i in ranked and _uses_set(strategy) and value == np.nanmax(grid[i]):
                    text = f"*{text}*"
                if i in ranked and value == col_best[j]:
                    text = f"**{text}**"
                cells.append(text)
            out.append(
                f"| {_label(strategy, closed)} | {_criterion_cell(strategy, criterion)} | "
                + " | ".join(cells)
                + " |"
            )
        out.append("")
    return "\n".join(out)


def _best_k(summary: pa.Table) -> dict[tuple[str, str, str, str], int]:
    """(map, protocol, strategy, criterion) -> the k of its measured best rate over all scenes."""
    best: dict[tuple[str, str, str, str], tuple[float, int]] = {}
    for r in summary.to_pylist():
        if r["closed_form"]:
            continue
        key = (r["map"], r["protocol"], r["strategy"], r["criterion"])
        if key not in best or r["rate"] > best[key][0]:
            best[key] = (r["rate"], r["k"])
    return {key: k for key, (_, k) in best.items()}


PER_SCENE = (
    StrategyName.NO_REPLAN,
    StrategyName.MAX_CONFIDENCE,
    StrategyName.RANDOM,
    StrategyName.ORACLE,
    StrategyName.MAX_ENTROPY,
    StrategyName.MIN_STDERR,
    StrategyName.MIN_PWKL,
)
"""Strategies of the per-scene table: baselines, oracle and the paper's CARe rules."""


def per_scene_markdown(summary: pa.Table, scenes: pa.Table) -> str:
    """Per-scene success (%): baselines, oracle and each CARe rule at its best k overall."""
    best = _best_k(summary)
    rows = [r for r in scenes.to_pylist() if not r["closed_form"]]
    out = []
    for kind, protocol in sorted({(r["map"], r["protocol"]) for r in rows}):
        criteria = sorted({c for (m, p, _, c) in best if (m, p) == (kind, protocol)})
        cols = [
            (s, c, best[(kind, protocol, s, c)])
            for s in PER_SCENE
            for c in criteria
            if (kind, protocol, s, c) in best
        ]
        lookup = {
            (r["scene"], r["strategy"], r["criterion"], r["k"]): r["rate"]
            for r in rows
            if r["map"] == kind and r["protocol"] == protocol
        }
        names = sorted({r["scene"] for r in rows if r["map"] == kind and r["protocol"] == protocol})
        out.append(f"### Per scene: {kind}, protocol `{protocol}`\n")
        heads = [f"{s} ({c[:4]}, k={k})" if _uses_set(s) else str(s) for s, c, k in cols]
        out.append("| scene | " + " | ".join(heads) + " |")
        out.append("|---|" + "---:|" * len(cols))
        for name in names:
            cells = [lookup.get((name, s, c, k)) for s, c, k in cols]
            out.append(
                f"| {name} | " + " | ".join("" if v is None else f"{v:.1f}" for v in cells) + " |"
            )
        out.append("")
    return "\n".join(out)


_COLOURS: dict[str, str] = {
    StrategyName.NO_REPLAN: "black",
    StrategyName.ORACLE: "tab:gray",
    StrategyName.MAX_CONFIDENCE: "tab:blue",
    StrategyName.RANDOM: "tab:brown",
    StrategyName.RANDOM_TOPK: "tab:olive",
    StrategyName.MAX_ENTROPY: "tab:orange",
    StrategyName.MIN_STDERR: "tab:green",
    StrategyName.MIN_PWKL: "tab:red",
    StrategyName.MIN_ENTROPY: "tab:pink",
    StrategyName.MAX_PWKL: "tab:purple",
    StrategyName.LARGEST: "tab:cyan",
    StrategyName.MOST_VIEWS: "darkkhaki",
    StrategyName.NEAREST_TOPK: "tab:blue",
    StrategyName.MAX_ENTROPY_NEAR: "tab:orange",
    StrategyName.MIN_STDERR_NEAR: "tab:green",
    StrategyName.MIN_PWKL_NEAR: "tab:red",
}
"""Baselines dark or muted, the paper's three CARe measures strong, the ablations paler; a
travel-aware rule takes its CARe rule's colour (dashed in the travel plot)."""


def plot_success(summary: pa.Table, ks: dict[str, Sequence[int]], out_dir: Path) -> list[Path]:
    """One PNG per (map, protocol): success vs k, one panel per selection criterion.

    Nineteen lines on one axis cannot be read, so each criterion gets its panel; the
    strategies without a candidate set (no replan, oracle, max confidence, random) are
    drawn as dashed horizontal references in both, and a strategy keeps its colour across
    panels and files. Closed-form expectations are left out (the tables carry them).
    """
    import matplotlib as mpl

    mpl.use("Agg")
    import matplotlib.pyplot as plt

    lookup = _rate_lookup(summary)
    paths = []
    out_dir.mkdir(parents=True, exist_ok=True)
    for kind, protocol in sorted({(r["map"], r["protocol"]) for r in summary.to_pylist()}):
        kvals = list(ks[kind])
        rows = [(s, c) for s, cf, c in _row_order(summary, kind, protocol) if not cf]
        criteria: list[str | None] = [c for c in CRITERIA if any(rc == c for _, rc in rows)]
        fig, axes = plt.subplots(
            1, max(len(criteria), 1), figsize=(11, 4.5), sharey=True, squeeze=False
        )
        for ax, panel in zip(axes[0], criteria or [None], strict=True):
            for strategy, criterion in rows:
                reference = not _uses_set(strategy)  # no candidate set: in every panel
                if not (reference or criterion == panel):
                    continue
                values = [
                    lookup.get(
                        (kind, protocol, strategy, False, criterion, _k_of(strategy, k)), {}
                    ).get("rate", np.nan)
                    for k in kvals
                ]
                ax.plot(
                    kvals, values, "--" if reference else "-",
                    color=_COLOURS.get(strategy, "tab:gray"), marker=None if reference else "o",
                    markersize=4, linewidth=1.2 if reference else 1.8,
                    label=_label(strategy),
                )  # fmt: skip
            ax.set_xscale("log")
            ax.xaxis.set_minor_locator(mpl.ticker.NullLocator())
            ax.set_xticks(kvals, [str(k) for k in kvals])
            ax.set_xlabel("k")
            ax.set_title(f"candidate set: top-k {panel}" if panel else "baselines")
            ax.grid(alpha=0.3)
        axes[0][0].set_ylabel("success (%)")
        handles, labels = axes[0][0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="center right", fontsize=8, frameon=False)
        fig.suptitle(f"{MAP_TITLES.get(kind, kind)}, protocol {protocol}", fontsize=11)
        fig.tight_layout(rect=(0, 0, 0.8, 1))
        path = out_dir / f"success_{kind}_{protocol}.png"
        write_atomic(path, partial(fig.savefig, dpi=110, format="png"))
        plt.close(fig)
        paths.append(path)
    return paths
