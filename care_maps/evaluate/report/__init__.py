"""The evaluation's report: ``results.md``, its parquet tables and plots, from attempt rows.

Its modules import one way: :mod:`~care_maps.evaluate.report.rates` (success rates, AUROC, plots), then
:mod:`~care_maps.evaluate.report.paired` (paired comparisons and the per-query outcomes), then
:mod:`~care_maps.evaluate.report.travel` (path length, SPL and its paired tests, success against
distance) and :mod:`~care_maps.evaluate.report.preregistered` (the paper's settings fixed in advance),
then :mod:`~care_maps.evaluate.report.overview` (the small table ``care run`` prints), then
:mod:`~care_maps.evaluate.report.write`, which writes them all as one report.
"""

from __future__ import annotations

from care_maps.evaluate.report.rates import (
    AUROC_MEASURES,
    PER_SCENE,
    auroc,
    auroc_table,
    markdown_tables,
    per_query,
    plot_success,
    summarise,
)
from care_maps.evaluate.report.write import Report, write_report

__all__ = [
    "AUROC_MEASURES",
    "PER_SCENE",
    "Report",
    "auroc",
    "auroc_table",
    "markdown_tables",
    "per_query",
    "plot_success",
    "summarise",
    "write_report",
]
