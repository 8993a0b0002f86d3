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


def _overview_queries(scenes: int, n: int = 120) -> pa.Table:
    """Queries of the grid in two protocols under the overview's rules, and one it leaves out."""
    from care_maps.evaluate.report.overview import overview_rules

    rng = np.random.default_rng(11)
    rules = [*overview_rules("grid"), (StrategyName.RANDOM_TOPK.value, "confidence", 4)]
    rows = [
        {"scene": f"s{i % scenes}", "map": "grid", "protocol": protocol, "unit": "u",
         "query": str(i), "strategy": str(s), "criterion": str(c), "k": k,
         "solved": float(rng.random() < 0.5), "expected": np.nan}
        for protocol in ("exclude-1m", "next-cell")
        for s, c, k in rules
        for i in range(n)
    ]  # fmt: skip
    return pa.Table.from_pylist(rows)


@pytest.mark.parametrize("scenes", [1, 20])
def test_overview_is_the_rules_a_user_reads_first(scenes: int) -> None:
    """``care run``'s table: a row per rule of no replan, max confidence, the pre-registered
    rules and the oracle, each protocol's success in its columns, equal to the summary's;
    an interval column only where intervals hold, and with one scene the reason said once
    under the table, not in every cell. No SPL column where no query walked."""
    from care_maps.evaluate.report.overview import (
        overview_markdown,
        overview_rows,
        overview_rules,
    )
    from care_maps.evaluate.report.preregistered import PAPER_SETTINGS
    from care_maps.evaluate.scene_test import MIN_SCENES

    queries = _overview_queries(scenes)
    summary = summarise(queries, bootstrap=200)
    rows = overview_rows(summary, summarise(queries, by_scene=True))
    rules = overview_rules("grid")
    assert rules[2:-1] == PAPER_SETTINGS["grid"]
    assert [(r["strategy"], r["criterion"], r["k"]) for r in rows] == [*rules, *rules]
    assert {r["scenes"] for r in rows} == {scenes}
    rates = {
        (r["protocol"], r["strategy"], r["criterion"], r["k"]): r["rate"]
        for r in summary.to_pylist()
    }
    text = overview_markdown(rows)
    lines = text.splitlines()
    note = scenes < MIN_SCENES
    assert len(lines) == 1 + 2 + len(rules) + note  # title, head, rows, the note
    assert "Random from top-k" not in text
    assert "SPL" not in text
    table = lines[3 : 3 + len(rules)]
    for row, line in zip(rows[: len(rules)], table, strict=True):
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[0] == row["rule"]
        numbers = [c for c in cells[1:] if not c.startswith("[")]
        for protocol, cell in zip(("exclude-1m", "next-cell"), numbers, strict=True):
            key = (protocol, row["strategy"], row["criterion"], row["k"])
            assert cell == f"{rates[key]:.1f}"
        assert "interval" not in line
    if note:
        assert "95% CI" not in text
        assert text.count(f"an interval holds from {MIN_SCENES} scenes") == 1
    else:
        assert lines[1].count("95% CI") == 2
        assert "No 95% intervals" not in text
