"""The report's statistics come from scipy and its rows are typed, not display strings."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from care_maps.evaluate.report import markdown_tables, summarise
from care_maps.replan.strategies import STRATEGIES, StrategyName


def _queries(n: int = 400, scenes: int = 1) -> pa.Table:
    rng = np.random.default_rng(7)
    rows = []
    for name in (StrategyName.MAX_CONFIDENCE, StrategyName.RANDOM):
        solved = (rng.random(n) < 0.3).astype(float)
        expected = np.full(n, 0.31) if STRATEGIES[name].random else np.full(n, np.nan)
        rows += [
            {"scene": f"s{i % scenes}", "map": "grid", "protocol": "class", "unit": "u", "query": str(i),
             "strategy": name.value, "criterion": "-", "k": 0,
             "solved": solved[i], "expected": expected[i]}
            for i in range(n)
        ]  # fmt: skip
    return pa.Table.from_pylist(rows)


def test_rate_interval_has_scenes_as_units_and_is_seeded() -> None:
    """With 20 scenes of independent queries the scene-level interval of a Bernoulli mean is,
    at n = 400, within 1.5 points of the normal approximation p +- 1.96 sqrt(p (1 - p) / n);
    the same seed gives the same bytes; one scene gives no interval, and the table says so."""
    queries = _queries(scenes=20)
    summary = summarise(queries, bootstrap=2000, seed=3)
    again = summarise(queries, bootstrap=2000, seed=3)
    assert summary.equals(again)
    for r in summary.to_pylist():
        p = r["rate"] / 100
        half = 196 * np.sqrt(p * (1 - p) / r["n_queries"])
        if r["closed_form"]:  # a constant: every scene says the same
            assert r["lo"] == pytest.approx(r["rate"])
            assert r["hi"] == pytest.approx(r["rate"])
            continue
        assert abs(r["lo"] - (r["rate"] - half)) < 1.5
        assert abs(r["hi"] - (r["rate"] + half)) < 1.5
    one = summarise(_queries(), bootstrap=2000, seed=3)
    assert np.isnan(one.column("lo").to_numpy()).all()
    assert "– (< 6 scenes)" in markdown_tables(one, {"grid": [4]}, ci=True)


def test_rows_are_typed_columns() -> None:
    summary = summarise(_queries(50), bootstrap=50)
    assert summary.schema.field("closed_form").type == pa.bool_()
    assert set(summary.column("strategy").to_pylist()) == {"max_confidence", "random"}
    assert summary.filter(summary.column("closed_form")).column("strategy").to_pylist() == [
        "random"
    ]
    md = markdown_tables(summary, {"grid": [4, 8]})
    assert "| Random replan (closed form) | - | 31.00 | 31.00 |" in md
