"""``results.md`` and its tables: the success rates, the paired and pre-registered
comparisons and the AUROC of each measure, written together from one run's attempt rows."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa

from care_maps.core.outputs import atomic_write_text
from care_maps.core.store import write_table_atomic
from care_maps.evaluate.config import DEFAULT_BOOTSTRAP
from care_maps.evaluate.report import preregistered
from care_maps.evaluate.report.overview import overview_markdown, overview_rows
from care_maps.evaluate.report.paired import outcomes, paired_markdown, paired_table
from care_maps.evaluate.report.rates import (
    AUROC_MEASURES,
    auroc_table,
    markdown_tables,
    per_query,
    per_scene_markdown,
    plot_success,
    summarise,
)
from care_maps.evaluate.report.travel import plot_travel, spl_pairs, travel_curves, travel_markdown
from care_maps.runtime.parallel import Runner, start_task

__all__ = ["Report", "write_report"]


@dataclass(frozen=True)
class Report:
    """What :func:`write_report` wrote."""

    markdown: str
    """The whole ``results.md``."""
    tables: str
    """Its success-rate tables, every rule and k."""
    summary: pa.Table
    auroc: pa.Table
    paths: tuple[Path, ...]
    travel: str = ""
    """Its travel section: path length, SPL and paired SPL tests."""
    overview: str = ""
    """What ``care run`` prints: per map, success and SPL of no replan, max confidence, the
    pre-registered rules and the oracle (:mod:`care_maps.evaluate.report.overview`); not
    written to ``results.md``, which has all of it."""


def _auroc_markdown(table: pa.Table) -> str:
    out = [
        "### How well each measure of the first attempt predicts its failure (AUROC)\n",
        "| map | protocol | first attempts | failed | " + " | ".join(AUROC_MEASURES) + " |",
        "|---|---|---:|---:|" + "---:|" * len(AUROC_MEASURES),
    ]
    for r in table.to_pylist():
        cells = " | ".join("" if np.isnan(r[m]) else f"{r[m]:.3f}" for m in AUROC_MEASURES)
        out.append(f"| {r['map']} | {r['protocol']} | {r['n_first']} | {r['n_failed']} | {cells} |")
    out.append("\n> 0.5: a higher value goes with failure; < 0.5: with success.\n")
    return "\n".join(out)


def write_report(
    attempts: pa.Table,
    out: Path,
    ks: dict[str, Sequence[int]],
    *,
    bootstrap: int = DEFAULT_BOOTSTRAP,
    header: str = "",
    runner: Runner | None = None,
    walk_from: str = "",
) -> Report:
    """Write ``attempts.parquet``, ``summary.parquet``, ``per_scene.parquet``,
    ``auroc.parquet``, ``paired.parquet``, ``paired_spl.parquet``, ``results.md`` and
    ``plots/*.png`` under ``out``; the plots on ``runner`` (its open pool or Ray) while the
    tables are made here. ``walk_from``: where the walks start, for the travel
    section's text (" from the recording's first pose")."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    queries = per_query(attempts)
    summary = summarise(queries, bootstrap=bootstrap)
    # the plots (matplotlib: about 4 s at 8 scenes) on another worker while the tables are
    # made here; without a pool or Ray they are drawn now, in this process
    plotting = start_task(plot_success, summary, ks, out / "plots", runner=runner or Runner())
    drawing = None
    try:
        scenes = summarise(queries, by_scene=True)
        aucs = auroc_table(attempts)
        known = outcomes(attempts)  # once for the paired and the four pre-registered tables
        paired = paired_table(attempts, bootstrap=bootstrap, known=known)
        pairs = spl_pairs(queries, summary, bootstrap=bootstrap)
        paths = [
            out / "attempts.parquet",
            out / "summary.parquet",
            out / "per_scene.parquet",
            out / "auroc.parquet",
            out / "paired.parquet",
            out / "paired_spl.parquet",
        ]
        tables_out = (attempts, summary, scenes, aucs, paired, pairs)
        for table, path in zip(tables_out, paths, strict=True):
            write_table_atomic(table, path)
        travel = travel_markdown(summary, pairs, walk_from)
        walked = any(r.get("n_travel") for r in summary.to_pylist())
        curves = travel_curves(attempts, summary) if walked else {}
        drawing = start_task(plot_travel, curves, out / "plots", runner=runner or Runner())
        tables = markdown_tables(summary, ks)
        prereg = preregistered.write_preregistered(
            attempts,
            out,
            bootstrap=min(bootstrap, preregistered.PREREGISTERED_BOOTSTRAP),
            known=known,
        )
    except Exception:
        for task in (plotting, drawing):  # a failed report writes nothing after its error
            if task is not None:
                task.exception()
        raise
    plots = [*plotting.result(), *drawing.result()]
    md = "\n".join(
        [
            header,
            "## Success rates\n",
            "**Bold**: best of the column (oracle and closed-form rows excluded). *Italic*: best of the row over k.\n",
            tables,
            "## 95% bootstrap confidence intervals (queries resampled)\n",
            markdown_tables(summary, ks, ci=True),
            paired_markdown(paired),
            travel,
            prereg.markdown,
            _auroc_markdown(aucs),
            per_scene_markdown(summary, scenes),
            "Plots: " + ", ".join(f"`plots/{p.name}`" for p in plots) + "\n",
        ]
    )
    md_path = out / "results.md"
    atomic_write_text(md_path, md)
    overview = overview_markdown(overview_rows(summary, scenes))
    written = (*paths, *prereg.paths, md_path, *plots)
    return Report(md, tables, summary, aucs, written, travel, overview)
