"""The evaluation job end to end on hand-built scenes, against brute-force references."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from scipy.special import softmax
from sklearn.metrics import roc_auc_score

from care_maps.core.errors import CareError, EvalError
from care_maps.core.store import read_table, write_table_atomic
from care_maps.evaluate.job import EvalConfig, evaluate_scene, run_eval, run_scenes, scenes_of
from care_maps.evaluate.report import auroc, per_query
from care_maps.query import load_map
from care_maps.runtime.execution import Backend, Execution
from care_maps.truth.formats.native import read_native

SERIAL = Execution(workers=1, progress=False)
RAY = Execution(backend=Backend.RAY, progress=False)

SMALL = EvalConfig(seeds=3, bootstrap=200, k_instances=(1, 2, 4), k_grid=(4, 16))


def _same(a, b) -> bool:
    """Column-by-column equality with NaN equal to NaN (Arrow's ``equals`` says NaN != NaN)."""
    if a.schema != b.schema or a.num_rows != b.num_rows:
        return False
    for name in a.column_names:
        x = a.column(name).to_numpy(zero_copy_only=False)
        y = b.column(name).to_numpy(zero_copy_only=False)
        if x.dtype.kind == "f":
            if not np.array_equal(x, y, equal_nan=True):
                return False
        elif not np.array_equal(x, y):
            return False
    return True


def _rows(table, **eq):
    mask = None
    for key, value in eq.items():
        m = pc.equal(table.column(key), value)
        mask = m if mask is None else pc.and_(mask, m)
    return table.filter(mask)


def test_first_attempt_matches_brute_force(dataset) -> None:
    scene = scenes_of(dataset)[1]
    table = evaluate_scene(scene, SMALL)
    gt = read_native(scene.recording)
    cmap = load_map(scene.store, "instances")
    vocab = list(cmap.vocabulary)
    P = softmax(
        cmap.logit_scale * cmap.features.astype(np.float64) @ cmap.text.T.astype(np.float64), axis=1
    )
    first = _rows(table, map="instances", protocol="instance", strategy="no_replan")
    assert first.num_rows == 6  # one query per GT instance
    for row in first.to_pylist():
        cls, inst = row["query"].split("#")
        in_room = np.flatnonzero((cmap.positions[:, 0] < 5) == (row["unit"] == "living"))
        best = in_room[np.argmax(P[in_room, vocab.index(cls)])]
        truth = set(np.flatnonzero(gt.point_instance == int(inst)).tolist())
        pred = set(cmap.mask(best).tolist())
        assert row["candidate"] == best
        assert row["success"] == (len(truth & pred) / len(truth | pred) > 0.25)
        assert np.isclose(row["confidence"], P[best, vocab.index(cls)], rtol=1e-4)


def test_oracle_bounds_and_random_seeds_against_closed_form(dataset) -> None:
    table = evaluate_scene(scenes_of(dataset)[0], SMALL)
    q = per_query(table)
    keys = ["map", "protocol", "unit", "query"]
    oracle = {
        tuple(r[k] for k in keys): r["solved"] for r in _rows(q, strategy="oracle").to_pylist()
    }
    for r in q.to_pylist():
        assert r["solved"] <= oracle[tuple(r[k] for k in keys)] + 1e-12, r
    rand = _rows(table, strategy="random")
    assert set(rand.column("seed").to_pylist()) == {0, 1, 2}
    exp = rand.column("expected").to_numpy()
    assert np.all((exp >= 0) & (exp <= 1))
    # where the closed form is certain (0 or 1), every seed must agree with it
    for r in _rows(q, strategy="random").to_pylist():
        if r["expected"] in (0.0, 1.0):
            assert r["solved"] == r["expected"], r
    # attempts never repeat a candidate within an episode
    episode = ["map", "protocol", "unit", "query", "strategy", "criterion", "k", "seed"]
    first = {
        tuple(r[k] for k in episode): r["candidate"] for r in _rows(table, attempt=1).to_pylist()
    }
    second = _rows(table, attempt=2).to_pylist()
    assert second
    assert all(r["candidate"] != first[tuple(r[k] for k in episode)] for r in second)
    assert set(table.column("attempt").to_pylist()) <= {1, 2}


@pytest.mark.slow
def test_run_resumes_and_writes_every_output(dataset, tmp_path) -> None:
    out = tmp_path / "eval"
    report = run_eval(dataset, SMALL, out, run=SERIAL)
    for name in (
        "attempts.parquet",
        "summary.parquet",
        "per_scene.parquet",
        "auroc.parquet",
        "results.md",
    ):
        assert (out / name).is_file(), name
    pngs = sorted((out / "plots").glob("*.png"))
    assert [p.name for p in pngs] == [
        "success_grid_exclude-1m.png",
        "success_grid_next-cell.png",
        "success_instances_class.png",
        "success_instances_instance.png",
    ]
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
    md = report.markdown
    assert "room by room (12 room maps" in md
    assert "| Min stderr | confidence |" in md
    assert "| Random replan (closed form) | - |" in md
    assert "**" in md
    assert "k=40" not in md.split("Grid map")[0]
    cached = {p: p.stat().st_mtime_ns for p in (out / "scenes").glob("*.parquet")}
    assert len(cached) == 3
    again = run_eval(dataset, SMALL, out, run=SERIAL)
    assert {p: p.stat().st_mtime_ns for p in (out / "scenes").glob("*.parquet")} == cached
    assert _same(again.summary, report.summary)
    # a changed config recomputes
    run_scenes(
        scenes_of(dataset)[:1],
        EvalConfig(seeds=2, k_instances=(1,), k_grid=(4,)),
        out,
        run=SERIAL,
    )
    assert (out / "scenes" / "scene_0.parquet").stat().st_mtime_ns != cached[
        out / "scenes" / "scene_0.parquet"
    ]
    # a re-fused map (its table rewritten) recomputes its scene alone
    run_eval(dataset, SMALL, out, run=SERIAL)
    cached = {p.name: p.stat().st_mtime_ns for p in (out / "scenes").glob("*.parquet")}
    table = dataset / "stores" / "scene_1" / "instances.parquet"
    st = table.stat()
    os.utime(table, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    run_eval(dataset, SMALL, out, run=SERIAL)
    now = {p.name: p.stat().st_mtime_ns for p in (out / "scenes").glob("*.parquet")}
    assert now == cached  # touched, not changed: the cache key is the content
    write_table_atomic(read_table(table), table, {b"care.test": b"rewritten"})
    run_eval(dataset, SMALL, out, run=SERIAL)
    now = {p.name: p.stat().st_mtime_ns for p in (out / "scenes").glob("*.parquet")}
    assert now["scene_1.parquet"] != cached["scene_1.parquet"]
    assert now["scene_0.parquet"] == cached["scene_0.parquet"]


def test_auroc_matches_sklearn(dataset) -> None:
    rng = np.random.default_rng(1)
    score = np.round(rng.random(200), 1)
    score[:5] = np.inf
    label = rng.random(200) < 0.4
    finite = np.where(np.isinf(score), 1e9, score)
    assert np.isclose(auroc(score, label), roc_auc_score(label, finite))
    assert np.isnan(auroc(score, np.zeros(200, bool)))


@pytest.mark.slow
def test_process_pool_and_ray_are_bit_identical(dataset, tmp_path, ray_session) -> None:
    scenes = scenes_of(dataset)
    local = run_scenes(scenes, SMALL, tmp_path / "a", run=SERIAL)
    pool = run_scenes(scenes, SMALL, tmp_path / "b", run=Execution(workers=2, progress=False))
    ray_run = run_scenes(scenes, SMALL, tmp_path / "c", run=RAY)
    assert _same(local, pool)
    assert _same(local, ray_run)


def test_bad_inputs_are_one_line_errors(dataset, tmp_path) -> None:
    with pytest.raises(EvalError, match="neither a store"):
        scenes_of(tmp_path)
    (tmp_path / "index.json").write_text('{"recordings": ["nothing.mcap"]}')
    with pytest.raises(EvalError, match=r"no fused store for nothing\.mcap"):
        scenes_of(tmp_path)
    for bad in ({"maps": ("voxels",)}, {"k_instances": (0, 2)}, {"maps": ()}):
        with pytest.raises(EvalError, match="invalid evaluation config"):
            EvalConfig(**bad)


def test_a_failing_ray_task_is_its_own_one_line_error(dataset, tmp_path, ray_session) -> None:
    scenes = scenes_of(dataset)
    (scenes[1].store / "cells.parquet").unlink()
    with pytest.raises(CareError) as err:
        run_scenes(scenes, SMALL, tmp_path / "r", run=RAY)
    assert "cells.parquet" in str(err.value)
    assert "\n" not in str(err.value)
    assert type(err.value).__module__ == "care_maps.core.errors"  # not Ray's wrapper


@pytest.mark.slow
def test_cli_eval_query_replan(dataset, tmp_path) -> None:
    store = dataset / "stores" / "scene_0"
    run = [sys.executable, "-m", "care_maps.cli.main"]
    q = subprocess.run(
        [*run, "query", str(store), "Chair", "--top", "3"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert "class 'chair'" in q.stdout
    lines = q.stdout.strip().splitlines()
    rows = [line for line in lines if line.split()[0].isdigit()]
    assert [row.split()[0] for row in rows] == ["1", "2", "3"]  # --top 3
    # a map without obstacle layers: the answer says no path or clearance was checked
    assert "no paths and no clearance check" in lines[-1]
    r = subprocess.run(
        [
            *run,
            "replan",
            str(store),
            "chair",
            "--visited",
            "0",
            "--strategy",
            "max_confidence",
            "--map",
            "grid",
        ],
        capture_output=True,
        text=True,
        check=True,
    )
    assert '"strategy": "max_confidence"' in r.stdout
    bad = subprocess.run(
        [*run, "replan", str(store), "chair", "--strategy", "best", "--visited", "1"],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2  # a usage error: the choices come from the registry
    assert bad.stderr.startswith("error: Invalid value for '--strategy'")
    assert "'best' is not one of" in bad.stderr
    e = subprocess.run(
        [
            *run,
            "eval",
            str(dataset),
            "--out",
            str(tmp_path / "o"),
            "--seeds",
            "2",
            "--bootstrap",
            "50",
            "--k-instances",
            "1,2",
            "--k-grid",
            "4",
            "--maps",
            "instances",
            "--workers",
            "1",
        ],
        capture_output=True,
        text=True,
    )
    assert e.returncode == 0, e.stderr
    assert "| No replan (top1 acc) | - |" in e.stdout


@pytest.mark.slow
def test_cli_eval_with_ray_matches_the_process_pool(dataset, tmp_path, ray_session) -> None:
    from typer.testing import CliRunner

    from care_maps.cli.main import _register, app

    _register()
    args = ["eval", str(dataset), "--seeds", "2", "--bootstrap", "20", "--k-instances", "2",
            "--k-grid", "4"]  # fmt: skip
    runner = CliRunner()
    ray_run = runner.invoke(app, [*args, "--out", str(tmp_path / "r"), "--ray"])
    assert ray_run.exit_code == 0, ray_run.output
    local = runner.invoke(app, [*args, "--out", str(tmp_path / "l"), "--workers", "1"])
    assert local.exit_code == 0, local.output
    assert _same(
        pq.read_table(tmp_path / "r" / "attempts.parquet"),
        pq.read_table(tmp_path / "l" / "attempts.parquet"),
    )


def test_unreachable_ray_cluster_is_one_clear_error(dataset, tmp_path) -> None:
    """Nothing listens on loopback port 1: one line at once, not minutes of Ray retries."""
    pytest.importorskip("ray")
    out = tmp_path / "out"  # not tmp_path itself: it holds the dataset, and is refused
    run = [sys.executable, "-m", "care_maps.cli.main", "eval", str(dataset), "--out", str(out)]
    bad = subprocess.run(
        [*run, "--ray-address", "127.0.0.1:1"], capture_output=True, text=True, timeout=60
    )
    assert bad.returncode == 1
    assert (
        bad.stderr.strip()
        .splitlines()[-1]
        .startswith("error: cannot reach a Ray cluster at 127.0.0.1:1")
    )
    assert not (tmp_path / "results.md").exists()
