"""`care run` on the bundled sample: the whole chain, the printed table and the .rrd files."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from care_maps.core.viz import rrd_entity_counts
from care_maps.evaluate.pipeline import SAMPLE

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_care_run_on_the_bundled_sample(tmp_path: Path) -> None:
    if not (SAMPLE / "index.json").is_file():
        pytest.skip("the bundled sample is not present")
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-m",
        "care_maps.cli.main",
        "run",
        "--out",
        str(out),
        "--seeds",
        "3",
        "--workers",
        "1",
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "| Min stderr (confidence, k=4) " in done.stdout  # the pre-registered grid rule
    results = (out / "eval" / "results.md").read_text()
    assert "| Min stderr | confidence |" in results  # every rule and k
    assert "## Travel: path length and SPL" in results  # every rule's SPL, paired tests
    assert (out / "eval" / "plots" / "travel_grid_exclude-1m.png").is_file()
    assert "protocol `instance` (29 queries)" in results  # one query per GT instance
    assert "instance 29" in done.stdout
    assert "rerun " in done.stdout
    assert (out / "eval" / "results.md").is_file()
    counts = rrd_entity_counts(out / "scene_000.eval.rrd")
    assert (
        counts[("/eval/log", "TextLog:text")] == 29 + 23 + 2 * 23
    )  # every query, the grid in both protocols
    assert counts[("/world/eval/first", "Points3D:positions")] >= 29 + 23 + 2 * 23
    assert counts[("/world/eval/target/boxes", "Boxes3D:half_sizes")] == 29 + 23 + 2 * 23
    for chart in ("grid_next-cell", "grid_exclude-1m", "instances_class", "instances_instance"):
        assert counts[(f"/eval/charts/{chart}/min_stderr/confidence", "LineStrips2D:strips")]
        assert counts[(f"/eval/charts/travel_{chart}/max_confidence", "LineStrips2D:strips")]
    for stage in ("ingest", "grid", "instances"):
        assert sum(rrd_entity_counts(out / f"scene_000.{stage}.rrd").values()) > 0
    assert done.stdout.count(".rrd") == 4
    # the README's Python example runs as written, against this output
    readme = (ROOT / "README.md").read_text()
    example = readme.split("From Python, the call a robot stack makes live")[1]
    code = example.split("```python\n", 1)[1].split("```", 1)[0]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    ran = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert ran.returncode == 0, ran.stderr[-2000:]
    # the stage commands share care run's settings: neither map is rebuilt, not a byte changes
    store = out / "stores" / "scene_000"
    maps = [store / "cells.parquet", store / "instances.parquet"]
    before = [(p.read_bytes(), p.stat().st_mtime_ns) for p in maps]
    for kind in ("grid", "instances"):
        fused = subprocess.run([*cmd[:3], "fuse", kind, str(store)], capture_output=True, text=True)
        assert fused.returncode == 0, fused.stderr[-2000:]
    assert [(p.read_bytes(), p.stat().st_mtime_ns) for p in maps] == before
    # 1,000 class and free-text queries over the sample's grid, as one batch
    import polars as pl

    classes = ["chair", "bed", "sofa", "sink", "toilet", "refrigerator", "lamp", "table"]
    free = ["somewhere to sit", "a place to sleep", "where I wash my hands", "a cold box"]
    lines = [classes[i % 8] if i % 2 else f"{free[i % 4]} {i % 9}" for i in range(1000)]
    (tmp_path / "queries.txt").write_text("\n".join(lines) + "\n")
    batch = subprocess.run(
        [*cmd[:3], "query", str(store), "--map", "grid", "--batch", str(tmp_path / "queries.txt")],
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert batch.returncode == 0, batch.stderr[-2000:]
    assert "ms a query" in batch.stdout
    answers = pl.read_parquet(tmp_path / "queries.answers.parquet")
    assert answers["query_index"].n_unique() == 1000
    first = answers.filter((pl.col("strategy") == "ranking") & (pl.col("attempt") == 1))
    assert first.filter(pl.col("query") == "bed")["method"].unique().to_list() == ["vocabulary"]
    free_rows = first.filter(pl.col("query") == "somewhere to sit 0")
    assert free_rows["method"][0].startswith("joins the vocabulary")


def _table_after(lines: list[str], title: str) -> tuple[list[str], list[list[str]]]:
    """The header and rows (cells stripped) of the printed table under the line that
    starts with ``title``."""
    start = next(i for i, line in enumerate(lines) if line.startswith(title))
    rows = []
    for line in lines[start + 1 :]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip().strip("|").split("|")])
    return rows[0], rows[2:]


@pytest.mark.slow
def test_care_run_prints_what_a_user_reads_first(tmp_path: Path) -> None:
    """`care run` on the sample, as the README runs it, prints one small table per map (no
    replan, max confidence, the pre-registered rules, the oracle: success and SPL of each
    protocol, as summary.parquet has them) and where the full report is, in at most 30
    lines of results and no note repeated in the cells; the full tables stay in results.md."""
    import pyarrow.parquet as pq

    from care_maps.evaluate.report.overview import overview_rules
    from care_maps.evaluate.report.rates import MAP_TITLES
    from care_maps.replan.strategies import STRATEGIES

    if not (SAMPLE / "index.json").is_file():
        pytest.skip("the bundled sample is not present")
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "care_maps.cli.main", "run", "--out", str(out), "--workers", "1"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    first = next(i for i, line in enumerate(lines) if not line.startswith(str(out / "stores")))
    last = next(i for i, line in enumerate(lines) if line.startswith("full report"))
    assert last - first + 1 <= 30, done.stdout  # the results, from the first table's title
    assert str(out / "eval" / "results.md") in lines[last]
    assert "no interval" not in done.stdout  # not in every cell: once under each table
    assert done.stdout.count("No 95% intervals: 1 scene;") == 2  # the sample: one scene
    summary = {
        (r["map"], r["protocol"], r["strategy"], r["criterion"], r["k"]): r
        for r in pq.read_table(out / "eval" / "summary.parquet").to_pylist()
        if not r["closed_form"]
    }
    for kind in ("grid", "instances"):
        head, rows = _table_after(lines, MAP_TITLES[kind].split(":")[0])
        protocols = sorted({key[1] for key in summary if key[0] == kind})
        assert head == ["rule", *(c for p in protocols for c in (f"{p} success", "SPL"))]
        rules = overview_rules(kind)
        assert len(rows) == len(rules)
        for (strategy, criterion, k), cells in zip(rules, rows, strict=True):
            assert cells[0].startswith(STRATEGIES[strategy].label)
            if STRATEGIES[strategy].uses_set:
                assert cells[0].endswith(f"({criterion}, k={k})")
            for i, protocol in enumerate(protocols):
                r = summary[kind, protocol, strategy, criterion, k]
                assert cells[1 + 2 * i] == f"{r['rate']:.1f}"
                assert cells[2 + 2 * i] == f"{r['spl']:.1f}"
    results = (out / "eval" / "results.md").read_text()  # nothing lost
    assert "| Max pwKL (ablation) | category |" in results
    assert "## Travel: path length and SPL" in results
    assert "## Pre-registered comparison" in results
