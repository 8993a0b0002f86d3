"""``care run`` on a small dataset gives the same bytes serially, in a process pool, on a
local Ray and on a two-node Ray cluster started with ``ray start``; a failing recording is
one line and the others complete; a re-run, even of a moved dataset, redoes nothing."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import pytest

from care_maps.evaluate.job import EvalConfig
from care_maps.evaluate.pipeline import RunConfig, run_all
from care_maps.runtime.execution import Backend, Execution
from care_maps.world.record import DatasetConfig, make_dataset

ROOT = Path(__file__).resolve().parents[2]
CONFIG = RunConfig(evaluation=EvalConfig(attempts=2, seeds=1), rrd_ingest=False)
"""What ``care run --seeds 1 --no-rrd-ingest`` builds (the cluster run goes through the CLI)."""
SERIAL = Execution(workers=1, progress=False)


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("parallel") / "data"
    make_dataset(
        DatasetConfig(
            out=out, scenes=2, width=160, height=120, frames=12, num_rooms=1, workers=1,
            progress=False,
        )
    )  # fmt: skip
    return out


def _outputs(out: Path) -> dict[str, bytes]:
    """Every file of the stores and of the evaluation (its tables, ``results.md`` and the
    plots, drawn by a worker in a pool or on Ray), by path relative to ``out``."""
    files = [p for d in ("stores", "eval") for p in (out / d).rglob("*") if p.is_file()]
    assert out / "eval" / "attempts.parquet" in files
    assert any(p.suffix == ".png" for p in files)
    return {str(p.relative_to(out)): p.read_bytes() for p in files}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            time.sleep(0.3)
    pytest.fail(f"the Ray head did not listen on port {port} within {timeout} s")


def _cluster_run(dataset: Path, out: Path) -> subprocess.CompletedProcess[str]:
    """``care run --ray-address`` against a head and a second node started with
    ``ray start --block`` (so ending those two processes stops exactly this cluster)."""
    ray = shutil.which("ray") or pytest.skip("no ray command")
    port = _free_port()
    env = {**os.environ, "RAY_AUTH_MODE": "token", "PYTHONPATH": str(ROOT)}
    temp = tempfile.mkdtemp(prefix="care-ray-")  # short: Ray's socket paths must fit
    node = ["--node-ip-address=127.0.0.1", "--num-cpus=1", "--block", "--disable-usage-stats"]
    head = subprocess.Popen(
        [ray, "start", "--head", f"--port={port}", "--include-dashboard=false",
         f"--temp-dir={temp}", *node],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    nodes = [head]
    try:
        _wait_port(port, 60)
        nodes.append(
            subprocess.Popen(
                [ray, "start", f"--address=127.0.0.1:{port}", *node],
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
        return subprocess.run(
            [sys.executable, "-m", "care_maps.cli.main", "run", str(dataset), "--out", str(out),
             "--seeds", "1", "--no-rrd-ingest", "--ray-address", f"127.0.0.1:{port}"],
            env=env, capture_output=True, text=True, timeout=900, cwd=ROOT,
        )  # fmt: skip
    finally:
        for proc in reversed(nodes):
            proc.terminate()
        for proc in reversed(nodes):
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
        shutil.rmtree(temp, ignore_errors=True)


@pytest.fixture(scope="module")
def serial_run(dataset: Path) -> Path:
    """A serial run beside the dataset: what every other way must give, byte for byte."""
    out = dataset.parent / "serial"
    run_all(dataset, out, CONFIG, run=SERIAL)
    return out


@pytest.fixture(scope="module")
def serial(serial_run: Path) -> dict[str, bytes]:
    outputs = _outputs(serial_run)
    assert any(name.endswith("cells.parquet") for name in outputs)
    assert any(name.endswith("instances.parquet") for name in outputs)
    return outputs


def _differences(expected: dict[str, bytes], out: Path) -> list[str]:
    got = _outputs(out)
    return sorted(set(got) ^ set(expected)) + [k for k in expected if got.get(k) != expected[k]]


def _rrd_counts(out: Path) -> dict[str, object]:
    """Entities and components logged in each Rerun file of a run (its bytes hold times)."""
    from care_maps.core.viz import rrd_entity_counts

    return {p.name: rrd_entity_counts(p) for p in sorted(out.glob("*.rrd"))}


@pytest.mark.slow
def test_same_bytes_serial_pool_and_local_ray(
    dataset: Path, serial: dict[str, bytes], ray_session: object
) -> None:
    # beside the serial run: a store names its recording relative to itself
    run_all(dataset, dataset.parent / "pool", CONFIG, run=replace(SERIAL, workers=2))
    assert _differences(serial, dataset.parent / "pool") == []
    ray = Execution(backend=Backend.RAY, progress=False)
    run_all(dataset, dataset.parent / "ray", CONFIG, run=ray)  # shared session
    assert _differences(serial, dataset.parent / "ray") == []
    # each scene's grid, instance and evaluation recordings, logged by the workers' tasks
    logged = _rrd_counts(dataset.parent / "serial")
    assert len(logged) == 3 * 2
    assert all(sum(c.values()) > 0 for c in logged.values())
    assert _rrd_counts(dataset.parent / "pool") == logged
    assert _rrd_counts(dataset.parent / "ray") == logged


@pytest.mark.slow
def test_same_bytes_on_a_two_node_cluster(dataset: Path, serial: dict[str, bytes]) -> None:
    done = _cluster_run(dataset, dataset.parent / "cluster")
    assert done.returncode == 0, done.stderr[-2000:]
    assert _differences(serial, dataset.parent / "cluster") == []


@pytest.mark.slow
def test_moved_dataset_and_outputs_are_current(serial_run: Path, tmp_path: Path) -> None:
    """The dataset and the run's outputs copied to another directory (as to another
    machine): nothing is rebuilt or re-evaluated, and the bytes are the same."""
    moved = tmp_path / "elsewhere"
    others = shutil.ignore_patterns("*.rrd", "pool", "ray", "cluster")  # the other tests' runs
    shutil.copytree(serial_run.parent, moved, ignore=others)
    out = moved / serial_run.name
    kept = [*(out / "stores").rglob("*.parquet"), *(out / "eval" / "scenes").glob("*.parquet")]
    made = {p: p.stat().st_mtime_ns for p in kept}  # stores, maps, cached scene results
    run_all(moved / "data", out, CONFIG, run=SERIAL)
    assert {p: p.stat().st_mtime_ns for p in made} == made
    stores = "\n".join(p.read_text() for p in (out / "stores").glob("*/*.json"))
    assert str(serial_run.parent) not in stores  # no absolute path of the old place


@pytest.mark.slow
def test_failing_recording_is_one_line_and_the_others_complete(
    dataset: Path, tmp_path: Path, run_cli
) -> None:
    folder = tmp_path / "recordings"
    folder.mkdir()
    shutil.copy(dataset / "scene_000.mcap", folder / "good.mcap")
    (folder / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"not an mcap" * 100)
    out = tmp_path / "out"
    code, _stdout, stderr = run_cli("run", folder, "--out", out, "--seeds", "1", "--no-rrd-ingest")
    assert code == 1
    lines = [line for line in stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 2, stderr  # its error, then the run's summary naming it
    assert lines[0].startswith("error: broken: ")
    assert "Traceback" not in stderr
    assert lines[1] == "error: 1 recording(s) failed: broken"
    assert (out / "stores" / "good" / "cells.parquet").is_file()
    assert (out / "stores" / "good" / "instances.parquet").is_file()
    assert not (out / "stores" / "broken" / "meta.json").exists()


def test_workers_start_with_the_process_settings(ray_session: object) -> None:
    """Pool and Ray workers run :func:`care_maps.runtime.parallel.setup_worker` (its last step hides the
    workers' own progress bars), the driver does not."""
    from care_maps.runtime.parallel import Runner, openmp_threads, run_tasks

    for runner in (Runner(workers=2), Runner(backend=Backend.RAY)):
        got = dict(run_tasks(os.getenv, ["TQDM_DISABLE", "OMP_NUM_THREADS"], runner))
        assert got["TQDM_DISABLE"] == "1", runner
        # and one OpenMP thread per worker, like its other pools (open3d's results do not
        # depend on it; two workers on two cores would otherwise run four threads)
        assert got["OMP_NUM_THREADS"] == openmp_threads() == "1", runner
    assert os.environ.get("TQDM_DISABLE") is None


def test_a_started_task_runs_on_the_runner_and_keeps_its_one_line_error(
    ray_session: object,
) -> None:
    """:func:`care_maps.runtime.parallel.start_task` (the report draws its plots so): on an open pool or
    on Ray the task runs in a worker while the caller goes on; without either, here. A
    project error comes out of ``result()``, and out of :func:`~care_maps.runtime.parallel.run_tasks`, as
    itself, not wrapped by the pool or Ray."""
    from care_maps.core.errors import StoreError
    from care_maps.core.store import Store
    from care_maps.runtime.parallel import Runner, open_runner, run_tasks, start_task

    for runner in (Runner(workers=1), Runner(workers=2), Runner(backend=Backend.RAY)):
        with open_runner(runner) as live:
            pid = start_task(os.getpid, runner=live).result()
            assert (pid == os.getpid()) == (runner.workers == 1 and not runner.uses_ray)
            assert start_task(divmod, 17, 5, runner=live).result() == (3, 2)
            failing = start_task(Store, Path("/nowhere/store"), runner=live)
            with pytest.raises(StoreError, match=r"^/nowhere/store: not a complete feature store"):
                failing.result()
            with pytest.raises(StoreError, match=r"^/nowhere/store: not a complete feature store"):
                list(run_tasks(Store, [Path("/nowhere/store"), Path("/nowhere/store")], live))


def test_the_driver_of_a_run_imports_no_stage() -> None:
    """``care run``'s module leaves the stages (torch, numba, Rerun) to the tasks: a pool's
    or Ray's driver, which never fuses, started its workers 3.5 s later when it imported
    them."""
    code = (
        "import sys, care_maps.evaluate.pipeline; "
        "print(sorted(m for m in ('torch', 'numba', 'rerun', 'open3d') if m in sys.modules))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True
    )
    assert done.stdout.strip() == "[]"


@pytest.mark.slow
def test_a_failing_report_leaves_no_plot_to_land_after_its_error(
    serial_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The report's plots are drawn on a worker while the driver makes its tables: when a
    table fails, the error leaves only once the plots are written, so nothing lands in the
    output after the run has said it failed."""
    import pyarrow.parquet as pq

    import care_maps.evaluate.report.preregistered
    from care_maps.evaluate.report import write_report
    from care_maps.query.map import MAP_TABLES
    from care_maps.runtime.parallel import Runner, open_runner

    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("a table failed")

    monkeypatch.setattr(care_maps.evaluate.report.preregistered, "write_preregistered", broken)
    attempts = pq.read_table(serial_run / "eval" / "attempts.parquet")
    ks = {kind: CONFIG.evaluation.ks(kind) for kind in MAP_TABLES}
    with open_runner(Runner(workers=2)) as live:
        with pytest.raises(RuntimeError, match="a table failed"):
            write_report(attempts, tmp_path / "eval", ks, runner=live)
        drawn = sorted(p.name for p in (tmp_path / "eval" / "plots").glob("*.png"))
    assert drawn == sorted(p.name for p in (serial_run / "eval" / "plots").glob("*.png"))
    assert drawn
