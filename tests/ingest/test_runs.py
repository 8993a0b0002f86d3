"""Several exploration runs of one place in one store: the third-party living-room frames as
two runs that overlap (the robot came back), written by the real writers (a ROS 1 bag and an
MCAP file), one of them localised in a map shifted by a known transform or in another frame.

The appended run's views follow the first run's, posed in the store's frame (the transform
the user gives undoes the known shift, checked against scipy's rotations); a run whose depths
disagree with the store's where they overlap, or that names another world frame, is refused
in one line; re-running either ingest changes nothing."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from care_maps.core.errors import IngestError
from care_maps.core.store import Store
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.runs import RunOptions, WorldTransform
from tests.support.cli import InProcessCli
from tests.support.faults import assert_fault, snapshot
from tests.support.frames import load_livingroom
from tests.support.recordings import Container, robot_messages, write_bag

pytestmark = pytest.mark.slow

FIRST = slice(0, 8)
SECOND = slice(4, 12)
"""The second run sees the first run's last four places again."""
SHIFT_XYZ = (0.4, -0.25, 0.0)
SHIFT_YAW_DEG = 20.0


def _shift() -> np.ndarray:
    """Where the second run's map lies in the first's: a mis-localised run."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", SHIFT_YAW_DEG, degrees=True).as_matrix()
    T[:3, 3] = SHIFT_XYZ
    return T


def _placement_text(T: np.ndarray) -> str:
    """``--world-transform`` for a run whose frame lies at ``T`` in the store's."""
    return ",".join(f"{v:.12g}" for v in (*T[:3, 3], *Rotation.from_matrix(T[:3, :3]).as_quat()))


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory, livingroom_root: Path) -> dict:
    folder = tmp_path_factory.mktemp("runs")
    frames = load_livingroom(livingroom_root, 12)
    # the second run's poses in a map that is the first's moved by the inverse shift
    shifted = np.linalg.inv(_shift())
    return {
        "frames": frames,
        "first": write_bag(folder / "day1.bag", robot_messages(frames[FIRST]), Container.ROS1),
        "second": write_bag(folder / "day2.mcap", robot_messages(frames[SECOND]), Container.MCAP),
        "shifted": write_bag(
            folder / "day2_shifted.mcap",
            robot_messages(frames[SECOND], world_from_frames=shifted),
            Container.MCAP,
        ),
        "odom": write_bag(
            folder / "day2_odom.mcap",
            robot_messages(frames[SECOND], world="odom", world_from_frames=shifted),
            Container.MCAP,
        ),
    }


def _poses(store: Path) -> np.ndarray:
    return Store(store).poses(in_map=False)


def _append(recording: Path, store: Path, transform: str | None = None) -> Path:
    placement = RunOptions(
        append=True,
        world_transform=None if transform is None else WorldTransform.from_text(transform),
    )
    return run_ingest(recording, store, placement=placement)


def test_an_appended_run_follows_the_first(runs: dict, tmp_path: Path) -> None:
    store = run_ingest(runs["first"], tmp_path / "store")
    _append(runs["second"], store)
    opened = Store(store)
    expected = np.stack([f.cam_to_world for f in runs["frames"][FIRST] + runs["frames"][SECOND]])
    assert opened.num_views == 16
    np.testing.assert_allclose(_poses(store), expected, atol=1e-6)  # through TF's quaternions
    first, second = opened.meta.runs
    assert (first.first_view, first.num_views) == (0, 8)
    assert (second.first_view, second.num_views) == (8, 8)
    assert (first.source.name, second.source.name) == ("day1.bag", "day2.mcap")
    assert second.alignment is not None
    assert second.alignment["status"] == "agree"
    assert opened.meta.counts["frames"] == first.counts["frames"] + second.counts["frames"]
    # the views of the first run are its store's, byte for byte
    alone = run_ingest(runs["first"], tmp_path / "alone")
    kept = [f.rgb.tobytes() for v, f in opened.iter_frames(extras=False) if v < 8]
    assert kept == [f.rgb.tobytes() for _, f in Store(alone).iter_frames(extras=False)]


def test_re_running_either_ingest_changes_nothing(runs: dict, tmp_path: Path) -> None:
    store = run_ingest(runs["first"], tmp_path / "store")
    _append(runs["second"], store)
    stamp = (store / "views.parquet").stat().st_mtime_ns
    _append(runs["second"], store)  # the run is there already
    run_ingest(runs["first"], store)  # the script's first step: the runs after it are kept
    assert (store / "views.parquet").stat().st_mtime_ns == stamp
    assert len(Store(store).meta.runs) == 2


def test_a_shifted_run_is_refused_and_placed_by_its_transform(
    runs: dict, tmp_path: Path, run_cli: InProcessCli
) -> None:
    store = run_ingest(runs["first"], tmp_path / "store")
    before = (store / "meta.json").read_bytes()
    code, _, err = run_cli("ingest", runs["shifted"], "--out", store, "--append")
    assert_fault(
        code, err, rf"{runs['shifted']}: its views disagree with {store}'s where they overlap"
    )
    assert "--world-transform" in err
    assert (store / "meta.json").read_bytes() == before  # nothing written
    text = _placement_text(_shift())
    code, _, err = run_cli(
        "ingest", runs["shifted"], "--out", store, "--append", "--world-transform", text
    )
    assert code == 0, err
    expected = np.stack([f.cam_to_world for f in runs["frames"][SECOND]])
    np.testing.assert_allclose(_poses(store)[8:], expected, atol=1e-6)
    code, out, err = run_cli("check", store)
    assert code == 0, err
    assert (
        f"{store}: run 2 of 2: views 8-15 from day2_shifted.mcap in world frame 'map', placed by --world-transform"
        in out
    )
    meta = json.loads((store / "meta.json").read_text())
    assert meta["runs"][1]["world_transform"] == pytest.approx([float(v) for v in text.split(",")])


def test_a_run_in_another_world_frame_is_refused_unless_placed(
    runs: dict, tmp_path: Path, run_cli: InProcessCli
) -> None:
    store = run_ingest(runs["first"], tmp_path / "store")
    code, _, err = run_cli("ingest", runs["odom"], "--out", store, "--append")
    assert_fault(code, err, rf"{runs['odom']}: its views are in world frame 'odom' but")
    assert "'map'" in err
    _append(runs["odom"], store, _placement_text(_shift()))
    expected = np.stack([f.cam_to_world for f in runs["frames"][SECOND]])
    np.testing.assert_allclose(_poses(store)[8:], expected, atol=1e-6)
    assert Store(store).meta.runs[1].world_frame == "odom"


def test_a_run_encoded_otherwise_is_refused(runs: dict, tmp_path: Path) -> None:
    store = run_ingest(runs["first"], tmp_path / "store")
    config = IngestConfig(vocabulary="tv,sofa")
    with pytest.raises(
        IngestError, match=r"its vocabulary would be 'tv,sofa', the store's is None"
    ):
        run_ingest(runs["second"], store, config, placement=RunOptions(append=True))


def test_appending_needs_a_store(runs: dict, tmp_path: Path, run_cli: InProcessCli) -> None:
    code, _, err = run_cli("ingest", runs["second"], "--out", tmp_path / "none", "--append")
    assert_fault(code, err, rf"{tmp_path / 'none'}: no store to append to")
    assert not (tmp_path / "none").exists()


def test_append_and_force_together_are_refused(
    runs: dict, tmp_path: Path, run_cli: InProcessCli
) -> None:
    store = run_ingest(runs["first"], tmp_path / "store")
    before = snapshot(store)
    code, _, err = run_cli("ingest", runs["second"], "--out", store, "--append", "--force")
    assert_fault(code, err, r"--force rebuilds the store .* --append adds it", intact=before)


def test_a_failure_while_the_maps_are_carried_leaves_the_store_whole(
    runs: dict,
    tmp_path: Path,
    run_cli: InProcessCli,
    monkeypatch: pytest.MonkeyPatch,
    save_tiny_clip,
) -> None:
    """The disk fills while an append carries the maps into the store with one more run:
    one line, and the store, its maps and their marker are as they were, no temporary
    beside them (the carry runs in the staged store, before it takes the old one's place)."""
    import errno

    import care_maps.ingest.runs

    weights = save_tiny_clip(tmp_path / "weights", layers=1)
    model = ("--encoder", "clip", "--weights", weights, "--vocabulary", "chair,sofa")
    store = tmp_path / "store"
    code, _, err = run_cli("ingest", runs["first"], "--out", store, *model)
    assert code == 0, err
    code, _, err = run_cli("fuse", "grid", store)
    assert code == 0, err
    assert (store / "cells.parquet").is_file()
    before = snapshot(store, weights)
    carried: list[str] = []

    def fills(src: str, dst: str) -> None:
        if carried:  # the second file carried finds the disk full
            raise OSError(errno.ENOSPC, "No space left on device", dst)
        carried.append(src)
        real(src, dst)

    real = care_maps.ingest.runs.link_or_copy
    monkeypatch.setattr(care_maps.ingest.runs, "link_or_copy", fills)
    code, _, err = run_cli("ingest", runs["second"], "--out", store, "--append", *model)
    assert carried  # the carry had begun
    assert_fault(code, err, r"store: no space left on device", clean=(tmp_path,), intact=before)
    assert len(Store(store).meta.runs) == 0  # one run, as before: no runs list yet


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("1,2,3", "expected seven numbers"),
        ("0,0,0,0,0,0,0", "the quaternion qx,qy,qz,qw is zero"),
        ("0,0,0,0,0,0.5,0.5", "has length 0.7071, not 1"),  # not normalised silently
    ],
)
def test_a_bad_transform_is_a_usage_error(
    runs: dict, tmp_path: Path, run_cli: InProcessCli, text: str, why: str
) -> None:
    code, _, err = run_cli(
        "ingest", runs["second"], "--out", tmp_path / "s", "--world-transform", text
    )
    assert code == 2
    assert why in err


def test_a_run_labelled_otherwise_is_refused(runs: dict, tmp_path: Path) -> None:
    """Class names taken from a recording's labels (no --vocabulary) must be the store's:
    its label ids and text table index one list of names."""
    from care_maps.ingest.runs import check_same_names

    store = Store(run_ingest(runs["first"], tmp_path / "store"))
    check_same_names(store, (), (), "day2.mcap")  # unlabelled, as the store
    with pytest.raises(IngestError, match=r"day2.mcap: cannot be appended to .*: its label "
                       r"names are 'chair,sofa', the store's are none"):  # fmt: skip
        check_same_names(store, (), ("chair", "sofa"), "day2.mcap")
    with pytest.raises(IngestError, match=r"its class names are 'chair,sofa', the store's"):
        check_same_names(store, ("chair", "sofa"), ("chair", "sofa"), "day2.mcap")


def _timelines(rrd: Path, entity: str) -> set[str]:
    """The timelines ``entity``'s rows are logged on in the file ``rrd``."""
    from rerun.chunk import RrdReader

    return {
        name
        for chunk in RrdReader(rrd).stream()
        if chunk.entity_path == entity
        for name in chunk.to_record_batch().schema.names
        if name.startswith("run ") or name == "stamp"
    }


def test_the_rerun_file_shows_each_run_on_its_own_timeline(
    runs: dict, tmp_path: Path, run_cli: InProcessCli
) -> None:
    from care_maps.core.viz import rrd_entity_counts
    from care_maps.ingest import viz

    store = run_ingest(runs["first"], tmp_path / "store")
    rrd = tmp_path / "runs.rrd"
    code, _, err = run_cli("ingest", runs["second"], "--out", store, "--append", "--rrd", rrd)
    assert code == 0, err
    counts = rrd_entity_counts(rrd)
    assert counts[("/" + viz.RGB_ENTITY, "EncodedImage:blob")] == 16  # both runs' views
    first, second = (f"/{viz.TRAJECTORY_ENTITY}/run_{k}" for k in (1, 2))
    assert counts[(first, "LineStrips3D:strips")] == 7  # the path so far, from its 2nd view
    assert counts[(second, "LineStrips3D:strips")] == 7
    assert ("/" + viz.TRAJECTORY_ENTITY, "LineStrips3D:strips") not in counts
    assert _timelines(rrd, first) == {"run 1"}
    assert _timelines(rrd, second) == {"run 2"}
    # written again from the store when asked of a store that is current: the same runs
    again = tmp_path / "again.rrd"
    code, _, err = run_cli("ingest", runs["second"], "--out", store, "--append", "--rrd", again)
    assert code == 0, err
    assert rrd_entity_counts(again) == counts


def test_topics_says_what_an_append_would_find(
    runs: dict, tmp_path: Path, run_cli: InProcessCli
) -> None:
    store = run_ingest(runs["first"], tmp_path / "store")
    code, out, err = run_cli("topics", runs["second"], "--store", store)
    assert code == 0, err
    assert f"run 2 of {store}: agrees with the earlier runs where they overlap" in out
    code, out, _ = run_cli("topics", runs["shifted"], "--store", store)
    assert f"ingest --append would refuse: {runs['shifted']}: its views disagree" in out
    text = _placement_text(_shift())
    code, out, err = run_cli("topics", runs["shifted"], "--store", store, "--world-transform", text)
    assert code == 0, err
    assert f"run 2 of {store}: agrees" in out
    code, out, _ = run_cli("topics", runs["odom"], "--store", store)
    assert "ingest --append would refuse" in out
    assert "world frame 'odom'" in out


def test_an_encoder_option_that_differs_is_named_and_how_it_runs_may_differ(
    runs: dict, tmp_path: Path
) -> None:
    from care_maps.core.encoders import EncoderOptions

    store = run_ingest(runs["first"], tmp_path / "store")
    seeded = IngestConfig(encoder_options=EncoderOptions(seed=5))
    with pytest.raises(
        IngestError, match=r"its seed would be 5, the store's is 0; pass the store's --seed"
    ):
        run_ingest(runs["second"], store, seeded, placement=RunOptions(append=True))
    batched = IngestConfig(encoder_options=EncoderOptions(batch_size=3))  # how, not what
    run_ingest(runs["second"], store, batched, placement=RunOptions(append=True))
    assert len(Store(store).meta.runs) == 2


def test_topics_with_no_store_says_so(runs: dict, tmp_path: Path, run_cli: InProcessCli) -> None:
    """``care topics REC --store DIR`` where DIR holds no store: that, in one line, not a
    failure of the recording's auto-detection."""
    (tmp_path / "empty").mkdir()
    code, _, err = run_cli("topics", runs["second"], "--store", tmp_path / "empty")
    assert_fault(code, err, rf"{tmp_path / 'empty'}: not a complete feature store")
