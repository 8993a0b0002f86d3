"""Paired statistics against independent references: a plain resampling loop, statsmodels'
McNemar and Holm, and the per-query outcomes recomputed from the attempt rows."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pyarrow.compute as pc
import pytest
from statsmodels.stats.contingency_tables import mcnemar
from statsmodels.stats.multitest import multipletests

from care_maps.evaluate.job import EvalConfig, run_eval
from care_maps.evaluate.paired import (
    compare,
    comparison_rng,
    holm,
    mcnemar_exact,
    paired_bootstrap_ci,
)
from care_maps.evaluate.report import per_query
from care_maps.evaluate.report.paired import paired_table
from care_maps.evaluate.scene_test import MIN_SCENES
from care_maps.runtime.execution import Execution

SERIAL = Execution(workers=1, progress=False)


def _loop_ci(a, b, rng, n, groups=None):
    """The textbook paired bootstrap, one resample at a time."""
    diff = np.asarray(a, float) - np.asarray(b, float)
    stats = []
    if groups is None:
        draws = rng.integers(0, len(diff), (n, len(diff)))
        stats = [diff[row].mean() for row in draws]
    else:
        names = np.unique(groups)
        draws = rng.integers(0, len(names), (n, len(names)))
        for row in draws:
            picked = np.concatenate([diff[groups == names[g]] for g in row])
            stats.append(picked.mean())
    return np.percentile(stats, [2.5, 97.5])


def test_bootstrap_matches_a_plain_loop() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.random(40) < 0.6, rng.random(40) < 0.4
    got = paired_bootstrap_ci(a, b, rng=np.random.default_rng(5), n_resamples=3000)
    np.testing.assert_allclose(got, _loop_ci(a, b, np.random.default_rng(5), 3000))
    groups = rng.integers(0, 6, 40)
    got = paired_bootstrap_ci(a, b, rng=np.random.default_rng(6), n_resamples=500, groups=groups)
    np.testing.assert_allclose(got, _loop_ci(a, b, np.random.default_rng(6), 500, groups))


@pytest.mark.parametrize(("b", "c"), [(0, 0), (3, 0), (5, 9), (12, 30), (40, 41)])
def test_mcnemar_matches_statsmodels(b: int, c: int) -> None:
    ref = mcnemar([[7, b], [c, 11]], exact=True).pvalue
    assert mcnemar_exact(b, c) == pytest.approx(ref, rel=1e-12)


def test_holm_matches_statsmodels() -> None:
    p = np.array([0.01, 0.04, 0.03, 0.2, np.nan, 0.005])
    ok = ~np.isnan(p)
    expected = multipletests(p[ok], method="holm")[1]
    np.testing.assert_allclose(holm(p)[ok], expected)
    assert np.isnan(holm(p)[4])


def test_compare_counts_discordant_pairs_and_first_ties() -> None:
    a = np.array([1, 1, 0, 1, 0, 1.0])
    b = np.array([1, 0, 0, 1, 1, 0.0])
    first = np.array([1, 0, 0, 1, 0, 0], bool)
    res = compare(a, b, rng=comparison_rng(0, "x"), first_a=first, first_b=first, n_resamples=200)
    assert (res.only_a, res.only_b, res.both, res.neither) == (2, 1, 2, 1)
    assert res.first_ties == 2
    assert res.diff == pytest.approx(1 / 6)
    assert res.p_value == pytest.approx(mcnemar([[2, 2], [1, 1]], exact=True).pvalue)
    # a seed-averaged side has no McNemar test
    assert np.isnan(compare(a, b * 0.5, rng=comparison_rng(0, "y"), n_resamples=10).p_value)


def test_paired_table_against_the_attempt_rows(dataset: Path, tmp_path: Path) -> None:
    config = EvalConfig(seeds=3, bootstrap=200, k_instances=(2, 4), k_grid=(4, 8))
    run_eval(dataset, config, tmp_path / "out", run=SERIAL)
    import pyarrow.parquet as pq

    attempts = pq.read_table(tmp_path / "out" / "attempts.parquet")
    table = pq.read_table(tmp_path / "out" / "paired.parquet")
    assert table.num_rows > 0
    queries = per_query(attempts).to_pylist()
    firsts = attempts.filter(pc.equal(attempts.column("attempt"), 1)).to_pylist()
    qkey = ("scene", "unit", "query")
    for row in table.to_pylist()[:: max(1, table.num_rows // 12)]:

        def solved(strategy, criterion, k, row=row):
            return {
                tuple(q[c] for c in qkey): q["solved"]
                for q in queries
                if (q["map"], q["protocol"], q["strategy"], q["criterion"], q["k"])
                == (row["map"], row["protocol"], strategy, criterion, k)
            }

        mine = solved(row["strategy"], row["criterion"], row["k"])
        base = solved(row["baseline"], row["baseline_criterion"], row["baseline_k"])
        keys = sorted(mine)
        a = np.array([mine[k] for k in keys])
        b = np.array([base[k] for k in keys])
        assert row["n_queries"] == len(keys)
        assert row["diff"] == pytest.approx(100 * (a - b).mean())
        # scenes are the units: the sign-flip p over every pattern of the scenes' summed
        # differences, written out here; too few scenes for an interval in this dataset
        scenes = np.array([k[0] for k in keys])
        sums = np.array([(a - b)[scenes == s].sum() for s in np.unique(scenes)])
        flips = [abs(np.dot(signs, sums)) for signs in itertools.product((1, -1), repeat=len(sums))]
        expected_p = np.mean([f >= abs(sums.sum()) - 1e-9 for f in flips])
        assert row["scenes"] == len(sums) < MIN_SCENES
        assert row["scene_p"] == pytest.approx(expected_p)
        assert np.isnan(row["lo"])
        assert np.isnan(row["hi"])
        if np.isin(b, (0, 1)).all():
            only_a, only_b = int(((a == 1) & (b == 0)).sum()), int(((a == 0) & (b == 1)).sum())
            table2 = [
                [int(((a == 1) & (b == 1)).sum()), only_a],
                [only_b, int(((a == 0) & (b == 0)).sum())],
            ]
            assert row["mcnemar_p"] == pytest.approx(mcnemar(table2, exact=True).pvalue)
        else:
            assert np.isnan(row["mcnemar_p"])
        # first-attempt ties: queries whose (shared) first attempt succeeded
        first_ok = {
            tuple(f[c] for c in qkey)
            for f in firsts
            if (f["map"], f["protocol"], f["strategy"])
            == (row["map"], row["protocol"], "max_confidence")
            and f["success"]
        }
        assert row["first_ties"] == len(first_ok & set(keys))
    assert "## Paired comparisons (same queries)" in (tmp_path / "out" / "results.md").read_text()


@pytest.mark.slow
def test_an_interval_does_not_depend_on_what_else_ran(dataset: Path, tmp_path: Path) -> None:
    """One generator per comparison: dropping strategies leaves the others' intervals as they were."""
    full = EvalConfig(seeds=2, bootstrap=100, k_instances=(2,), k_grid=(4,))
    some = EvalConfig(
        **{
            **full.__dict__,
            "strategies": ("no_replan", "max_confidence", "min_stderr", "random_topk"),
        }
    )
    run_eval(dataset, full, tmp_path / "full", run=SERIAL)
    run_eval(dataset, some, tmp_path / "some", run=SERIAL)
    attempts_full = tmp_path / "full" / "attempts.parquet"
    assert attempts_full.is_file()
    import pyarrow.parquet as pq

    a = {
        (r["map"], r["protocol"], r["strategy"], r["criterion"], r["k"], r["baseline"]): (
            r["lo"],
            r["hi"],
        )
        for r in pq.read_table(tmp_path / "full" / "paired.parquet").to_pylist()
    }
    b = {
        (r["map"], r["protocol"], r["strategy"], r["criterion"], r["k"], r["baseline"]): (
            r["lo"],
            r["hi"],
        )
        for r in pq.read_table(tmp_path / "some" / "paired.parquet").to_pylist()
    }
    shared = [k for k in b if k[2] == "min_stderr" and k[5] == "max_confidence"]
    assert shared
    for key in shared:
        np.testing.assert_equal(a[key], b[key])  # NaN (too few scenes) equals NaN here
    assert paired_table(pq.read_table(attempts_full), bootstrap=100).num_rows == len(a)
