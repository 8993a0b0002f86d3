"""Faults of ``care fuse``, ``care query``, ``care replan``, ``care eval`` and ``care check``.

Each works on a private copy of a good store (both maps) and evaluation built once per
session, and asserts the fault's one line, exit code, no traceback, nothing half-written,
earlier output intact, and a re-run that succeeds.
"""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from tests.support.cli import care_popen, care_process
from tests.support.faults import (
    EVAL_FLAGS,
    assert_fault,
    chmod,
    leftovers,
    read_meta,
    snapshot,
    tables,
)

MAP_FILES = ("cells.parquet", "cell_views.parquet", "instances.parquet", "instance_views.parquet")


def _truncate(path: Path, keep: int = 600) -> None:
    path.write_bytes(path.read_bytes()[:keep])


# -- fuse ---------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    ("flags", "pattern", "exit_code"),
    [
        (("--cell-size", "nan"), r"'--cell-size'.*nan is not a finite number", 2),
        (("--cell-size", "0"), r"cell_size=0", 1),
        (("--cell-size", "-0.1"), r"cell_size=-0\.1", 1),
        (("--logit-scale", "nan"), r"'--logit-scale'.*nan is not a finite number", 2),
        (("--z-min", "inf"), r"'--z-min'.*inf is not a finite number", 2),
        (("--stride", "0"), r"stride=0", 1),
    ],
    ids=[
        "cell-size-nan",
        "cell-size-0",
        "cell-size-negative",
        "logit-scale-nan",
        "z-min-inf",
        "stride-0",
    ],
)
def test_grid_bad_option(care, copy_good, flags, pattern: str, exit_code: int) -> None:
    store = copy_good("store")
    before = snapshot(store)
    code, _, err = care("fuse", "grid", store, "--overwrite", *flags)
    assert_fault(code, err, pattern, exit_code=exit_code, clean=(store.parent,), intact=before)


@pytest.mark.parametrize(
    ("flags", "pattern", "exit_code"),
    [
        (("--proposals", "magic"), r"'--proposals'.*'magic' is not one of", 2),
        (("--features", "pixels"), r"'--features'", 2),
        (("--set", "cluster_eps=nan"), r"cluster_eps=nan", 1),
        (("--set", "no_such_field=1"), r"--set 'no_such_field=1'", 1),
        (("--voxel-size", "-1"), r"voxel_size=-1", 1),
    ],
    ids=["proposals-unknown", "features-unknown", "set-nan", "set-unknown-field", "voxel-negative"],
)
def test_instances_bad_option(care, copy_good, flags, pattern: str, exit_code: int) -> None:
    store = copy_good("store")
    before = snapshot(store)
    code, _, err = care("fuse", "instances", store, "--overwrite", *flags)
    assert_fault(code, err, pattern, exit_code=exit_code, clean=(store.parent,), intact=before)


def test_grid_too_fine_for_memory_is_refused_before_allocating(care, copy_good) -> None:
    store = copy_good("store")
    before = snapshot(store)
    started = time.perf_counter()
    code, _, err = care("fuse", "grid", store, "--cell-size", "1e-7", "--overwrite")
    assert_fault(
        code,
        err,
        r"--cell-size 1e-07: .* needs .* GiB, more than the .* available; raise --cell-size",
        clean=(store,),
        intact=before,
    )
    assert time.perf_counter() - started < 60
    assert care("fuse", "grid", store, "--cell-size", "0.2")[0] == 0


@pytest.mark.parametrize("table", ["views.parquet", "features.parquet"])
def test_fuse_on_damaged_store(care, copy_good, table: str) -> None:
    store = copy_good("store")
    _truncate(store / table)
    code, _, err = care("fuse", "grid", store, "--cell-size", "0.2")
    assert_fault(
        code,
        err,
        rf"{table}: damaged or truncated table; rebuild it with `care ingest .* --force`",
        clean=(store,),
    )


def test_fuse_store_with_invalid_meta_json(care, copy_good, recording: Path) -> None:
    store = copy_good("store")
    (store / "meta.json").write_text("{not json")
    code, _, err = care("fuse", "instances", store)
    assert_fault(
        code, err, r"meta\.json: not valid JSON .* `care ingest .*scene_000\.mcap", clean=(store,)
    )
    assert care("ingest", recording, "--out", store, "--encoder", "labels")[0] == 0
    assert care("fuse", "instances", store, "--proposals", "labels")[0] == 0


def test_text_embeddings_of_another_dimension(care, copy_good) -> None:
    """A store whose text embeddings do not match its features' dimension (another tool wrote
    text.parquet): one line naming both dimensions."""
    from care_maps.core.outputs import file_digest

    store = copy_good("store")
    text = pq.read_table(store / "text.parquet")
    names = text.column("name").to_pylist()
    short = pa.table(
        {"name": names, "embedding": [[0.5] * 7 for _ in names]},
        schema=pa.schema([("name", pa.string()), ("embedding", pa.list_(pa.float32()))]),
    ).replace_schema_metadata(text.schema.metadata)
    pq.write_table(short, store / "text.parquet")
    meta = read_meta(store)
    meta["tables"]["text.parquet"] = file_digest(store / "text.parquet")
    (store / "meta.json").write_text(json.dumps(meta))
    code, _, err = care("fuse", "grid", store, "--cell-size", "0.2", "--overwrite")
    assert_fault(
        code,
        err,
        r"text\.parquet: text embeddings of dimension 7, but the store's features have \d+",
        clean=(store,),
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    ("table", "kind", "rebuild"),
    [
        ("cells.parquet", "grid", "care fuse grid"),
        ("cell_views.parquet", "grid", "care fuse grid"),
        ("instances.parquet", "instances", "care fuse instances"),
        ("instance_views.parquet", "instances", "care fuse instances"),
    ],
)
def test_damaged_map_is_found_and_rebuilt(
    care, copy_good, good: Path, table, kind, rebuild
) -> None:
    store = copy_good("store")
    _truncate(store / table)
    code, _, err = care("check", store)
    assert_fault(code, err, rf"{table}: .*rebuild it with `{rebuild} .* --overwrite`")
    if not table.endswith("_views.parquet"):  # queries read the candidate tables only
        code, _, err = care("query", store, "chair", "--map", kind)
        assert_fault(code, err, rf"{table}: damaged or truncated table; rebuild it with `{rebuild}")
    flags = ("--cell-size", "0.1") if kind == "grid" else ("--proposals", "labels")
    code, _, err = care("fuse", kind, store, *flags)  # no --overwrite: it knows it is damaged
    assert code == 0, err
    assert care("check", store)[0] == 0
    assert care("query", store, "chair", "--map", kind)[0] == 0
    assert tables(store) == tables(good / "store")  # rebuilt byte for byte


def test_fuse_rrd_is_a_user_file(care, copy_good, tmp_path: Path) -> None:
    store = copy_good("store")
    rrd = tmp_path / "holiday.jpg"
    rrd.write_bytes(b"\xff\xd8\xff\xe0 my photo")
    before = snapshot(rrd, store)
    code, _, err = care("fuse", "grid", store, "--cell-size", "0.2", "--rrd", rrd)
    assert_fault(
        code,
        err,
        r"holiday\.jpg: exists and is not a file care wrote",
        clean=(tmp_path,),
        intact=before,
    )
    assert care("fuse", "grid", store, "--cell-size", "0.2", "--rrd", tmp_path / "g.rrd")[0] == 0
    assert snapshot(rrd) == {str(rrd): before[str(rrd)]}


@pytest.mark.slow
def test_fuse_disk_full_keeps_previous_map(care, copy_good) -> None:
    store = copy_good("store")
    before = snapshot(store)
    r = care_process("fuse", "grid", store, "--cell-size", "0.07", fsize=40_000)
    assert_fault(
        r.returncode,
        r.stderr,
        r"file-size limit reached .*free on",
        clean=(store.parent,),
        intact=before,
    )
    code, _, err = care("fuse", "grid", store, "--cell-size", "0.07")
    assert code == 0, err
    assert care("check", store)[0] == 0


@pytest.mark.slow
def test_killed_fuse_is_swept_by_the_next_run(care, copy_good) -> None:
    store = copy_good("store")
    proc = care_popen("fuse", "grid", store, "--cell-size", "0.05")
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list(store.glob(".cell_views.parquet.tmp-*")):
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    stale = list(store.glob(".cell_views.parquet.tmp-*"))
    assert care("check", store)[0] == 0  # the old map still whole
    code, _, err = care("fuse", "grid", store, "--cell-size", "0.05")
    assert code == 0, err
    assert not any(p.exists() for p in stale)
    assert not leftovers(store.parent)


@pytest.mark.slow
def test_fuse_store_directory_not_writable(care, copy_good) -> None:
    store = copy_good("store")
    before = snapshot(store)
    with chmod(store, 0o555):
        r = care_process("fuse", "grid", store, "--cell-size", "0.07")
    assert_fault(r.returncode, r.stderr, r"permission denied", clean=(store.parent,), intact=before)
    assert care("fuse", "grid", store, "--cell-size", "0.07")[0] == 0


# -- query / replan -----------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "pattern", "exit_code"),
    [
        (("query", "{store}", "chair", "--top", "-5"), r"'--top'", 2),
        (("query", "{store}", "chair", "--map", "voxels"), r"'--map'", 2),
        (
            ("replan", "{store}", "chair", "--visited", "0", "--criterion", "bogus"),
            r"'--criterion'.*'bogus' is not one of",
            2,
        ),
        (
            ("replan", "{store}", "chair", "--visited", "0", "--strategy", "guess"),
            r"'--strategy'",
            2,
        ),
        (
            (
                "replan",
                "{store}",
                "chair",
                "--visited",
                "0",
                "--exclude-radius",
                "-1",
                "--map",
                "grid",
            ),
            r"exclude_radius=-1",
            1,
        ),
        (
            (
                "replan",
                "{store}",
                "chair",
                "--visited",
                "0",
                "--exclude-radius",
                "nan",
                "--map",
                "grid",
            ),
            r"'--exclude-radius'.*nan is not a finite number",
            2,
        ),
        (
            ("replan", "{store}", "chair", "--visited", "999999"),
            r"visited candidate ids must lie in 0\.\.",
            1,
        ),
        (
            ("replan", "{store}", "chair", "--visited", "a,b"),
            r"--visited 'a,b': give a candidate id \(12\) or a map position x,y",
            1,
        ),
        (
            ("replan", "{store}", "chair", "--map", "grid", "--visited", "500,-500"),
            r"visited position 500,-500 lies outside the map \(its candidates span x ",
            1,
        ),
        (("replan", "{store}", "chair", "-k", "0", "--visited", "0"), r"'-k'", 2),
        (
            ("query", "{store}/meta.json", "chair"),
            r"meta\.json/instances\.parquet: no such table",
            1,
        ),
    ],
    ids=[
        "top-negative",
        "map-unknown",
        "criterion-unknown",
        "strategy-unknown",
        "exclude-negative",
        "exclude-nan",
        "visited-out-of-range",
        "visited-not-int",
        "visited-outside-the-map",
        "k-0",
        "store-is-a-file",
    ],
)
def test_query_replan_bad_input(care, good: Path, args, pattern: str, exit_code: int) -> None:
    store = good / "store"
    before = snapshot(store)
    code, _, err = care(*(a.format(store=store) for a in args))
    assert_fault(code, err, pattern, exit_code=exit_code, intact=before)
    assert care("replan", store, "chair", "--visited", "0")[0] == 0


@pytest.mark.slow
def test_query_store_without_maps(care, recording: Path, tmp_path: Path) -> None:
    assert care("ingest", recording, "--out", tmp_path / "store", "--encoder", "labels")[0] == 0
    code, _, err = care("query", tmp_path / "store", "chair", "--map", "grid")
    assert_fault(code, err, r"cells\.parquet: no such table; build it first")
    assert care("fuse", "grid", tmp_path / "store", "--cell-size", "0.2")[0] == 0
    assert care("query", tmp_path / "store", "chair", "--map", "grid")[0] == 0


# -- eval ---------------------------------------------------------------------------------


@pytest.mark.slow
def test_eval_out_is_a_file(care, good: Path, tmp_path: Path) -> None:
    out = tmp_path / "results.csv"
    out.write_text("a,b\n1,2\n")
    before = snapshot(out)
    code, _, err = care("eval", good / "store", "--out", out, *EVAL_FLAGS)
    assert_fault(
        code,
        err,
        r"results\.csv: is a regular file; not replaced",
        clean=(tmp_path,),
        intact=before,
    )
    assert care("eval", good / "store", "--out", tmp_path / "eval", *EVAL_FLAGS)[0] == 0


def test_eval_out_is_a_user_directory(care, good: Path, tmp_path: Path) -> None:
    user = tmp_path / "papers"
    user.mkdir()
    (user / "draft.md").write_text("# draft")
    before = snapshot(user)
    code, _, err = care("eval", good / "store", "--out", user, *EVAL_FLAGS)
    assert_fault(
        code,
        err,
        r"papers: directory holds files care did not write",
        clean=(tmp_path,),
        intact=before,
    )


@pytest.mark.slow
def test_eval_out_inside_a_store(care, copy_good) -> None:
    store = copy_good("store")
    before = snapshot(store)
    code, _, err = care("eval", store, "--out", store / "eval", *EVAL_FLAGS)
    assert_fault(code, err, r"is the input .* or inside it", clean=(store,), intact=before)


@pytest.mark.slow
def test_eval_out_is_a_store(care, copy_good, good: Path) -> None:
    store = copy_good("store")
    before = snapshot(store)
    code, _, err = care("eval", good / "store", "--out", store, *EVAL_FLAGS)
    assert_fault(code, err, r"is a care store directory, not a eval", clean=(store,), intact=before)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("flags", "pattern", "exit_code"),
    [
        (("--k-grid", "0"), r"k=0", 1),
        (("--k-grid", "4,x"), r"--k-grid: '4,x': expected comma-separated int values", 2),
        (("--exclude-radii", "0,nan"), r"'--exclude-radii'.*nan is not a finite number", 2),
        (("--exclude-radii", "1,1"), r"--exclude-radii \(1.0, 1.0\) repeats a radius", 1),
        (("--strategies", "psychic"), r"'psychic'.*choose from no_replan, oracle, ", 2),
        (("--maps", "voxels"), r"'voxels'.*choose from instances, grid", 2),
        (("--attempts", "0"), r"attempts=0", 1),
    ],
    ids=[
        "k-0",
        "k-not-int",
        "exclude-nan",
        "exclude-repeated",
        "strategy-unknown",
        "map-unknown",
        "attempts-0",
    ],
)
def test_eval_bad_option(
    care, good: Path, tmp_path: Path, flags, pattern: str, exit_code: int
) -> None:
    code, _, err = care("eval", good / "store", "--out", tmp_path / "eval", *EVAL_FLAGS, *flags)
    assert_fault(code, err, pattern, clean=(tmp_path,), exit_code=exit_code)
    assert not (tmp_path / "eval").exists()


def test_eval_bad_index_json(care, world: Path, tmp_path: Path) -> None:
    import shutil

    ds = tmp_path / "ds"
    shutil.copytree(world, ds)
    (ds / "index.json").write_text('{"scenes": [')
    code, _, err = care("eval", ds, "--out", tmp_path / "eval", *EVAL_FLAGS)
    assert_fault(code, err, r"index\.json", clean=(tmp_path,))


@pytest.mark.slow
def test_eval_disk_full_keeps_previous_results(care, copy_good, good: Path) -> None:
    out = copy_good("eval")
    before = snapshot(out)
    r = care_process("eval", good / "store", "--out", out, *EVAL_FLAGS, "--seeds", "3", fsize=3_000)
    assert_fault(r.returncode, r.stderr, r"file-size limit reached", clean=(out.parent,))
    # the tables of the earlier evaluation are whole (each is replaced atomically or not at all)
    for name in ("attempts.parquet", "summary.parquet"):
        assert pq.read_table(out / name).num_rows > 0
    assert snapshot(out / "results.md") == {
        str(out / "results.md"): before[str(out / "results.md")]
    }
    code, _, err = care("eval", good / "store", "--out", out, *EVAL_FLAGS, "--seeds", "3")
    assert code == 0, err


@pytest.mark.slow
def test_eval_twice_same_bytes(care, good: Path, tmp_path: Path) -> None:
    """Determinism: the same evaluation twice (and a re-run into its own output) gives
    byte-identical tables."""
    out = tmp_path / "eval"
    assert care("eval", good / "store", "--out", out, *EVAL_FLAGS)[0] == 0
    first = tables(out)
    assert first == tables(good / "eval")
    assert care("eval", good / "store", "--out", out, *EVAL_FLAGS)[0] == 0
    assert tables(out) == first


# -- check and the unexpected -------------------------------------------------------------


def test_check_a_path_that_is_no_store(care, tmp_path: Path) -> None:
    code, _, err = care("check", tmp_path)
    assert_fault(code, err, r"not a complete feature store")


@pytest.mark.slow
def test_unexpected_error_is_one_line_and_a_traceback_file(
    care, good: Path, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from care_maps.query.openvocab import QueryTarget

    def broken(*args, **kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(QueryTarget, "confidence", broken)
    monkeypatch.setenv("CARE_TRACEBACK_DIR", str(tmp_path))
    code, _, err = care("query", good / "store", "chair")
    line = assert_fault(
        code,
        err,
        r"internal error ZeroDivisionError: a bug; full traceback in .* \(re-run with --debug",
    )
    path = Path(line.split("full traceback in ")[1].split(" (re-run")[0])
    assert "ZeroDivisionError: a bug" in path.read_text()
    with pytest.raises(ZeroDivisionError):
        care("query", good / "store", "chair", "--debug")
