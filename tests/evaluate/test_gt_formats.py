"""Ground truth in every format gives the native ground truth's results; bad ground truth is
one line, exit 1 and no results. Uses the small fused dataset of ``conftest.py``, whose
objects are point clusters inside their boxes and apart from the floor, so even box-only
ground truth labels exactly the same map points."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from care_maps.evaluate.groundtruth import GtSource
from care_maps.evaluate.job import EvalConfig, Scene, run_eval, scenes_of
from care_maps.runtime.execution import Execution
from care_maps.truth.formats.native import read_native
from care_maps.truth.load import EXPORT_FORMATS, export_ground_truth, find_beside

CONFIG = EvalConfig(seeds=2, bootstrap=50, k_instances=(2, 4), k_grid=(4, 8))
ROOMLESS = ("scannet", "replica")
"""Formats with no rooms: compared with the native ground truth evaluated without rooms."""
BEST = {
    "native": "scene_0.gt.json",
    "json": "scene_0.annotations.json",
    "yaml": "scene_0.annotations.yaml",
    "csv": "scene_0.annotations.csv",
    "ply": "scene_0.labels.ply",
    "scannet": "scene_0.scannet",
    "matterport": "scene_0.matterport",
    "replica": "scene_0.replica",
}


def _same(a: pa.Table, b: pa.Table) -> bool:
    """Tables equal value for value, NaN equal to NaN."""
    if a.schema != b.schema or a.num_rows != b.num_rows:
        return False
    for name in a.column_names:
        x = a.column(name).to_numpy(zero_copy_only=False)
        y = b.column(name).to_numpy(zero_copy_only=False)
        if x.dtype.kind == "f":
            if not np.array_equal(x, y, equal_nan=True):
                return False
        elif not (x == y).all():
            return False
    return True


def _eval(scene: Scene, out: Path, config: EvalConfig = CONFIG, **gt) -> tuple[pa.Table, str]:
    report = run_eval([scene], config, out, run=Execution(workers=1, progress=False), **gt)
    return report.summary, report.markdown


@pytest.fixture
def exported(dataset: Path) -> Scene:
    """Scene 0 of the dataset with its ground truth exported in every format."""
    scene = scenes_of(dataset)[0]
    export_ground_truth(read_native(scene.recording), scene.recording, ["all"])
    return scene


@pytest.mark.slow
@pytest.mark.parametrize("fmt", EXPORT_FORMATS)
def test_every_format_gives_the_native_results(exported: Scene, tmp_path: Path, fmt: str) -> None:
    rooms = fmt not in ROOMLESS
    config = EvalConfig(**{**CONFIG.__dict__, "rooms": rooms})
    native, _ = _eval(exported, tmp_path / "native", config)
    path = exported.recording.with_name(BEST[fmt])
    summary, markdown = _eval(exported, tmp_path / fmt, config, gt=[path])
    assert _same(native, summary), fmt
    assert "## Paired comparisons" in markdown


@pytest.mark.slow
def test_ground_truth_is_found_beside_the_recording_and_named_in_the_index(
    dataset: Path, tmp_path: Path
) -> None:
    scene = scenes_of(dataset)[0]
    export_ground_truth(read_native(scene.recording), scene.recording, ["scannet"])
    native, _ = _eval(scene, tmp_path / "native", EvalConfig(**{**CONFIG.__dict__, "rooms": False}))
    # beside by name: without the native files the ScanNet folder is the one found
    for p in (dataset / "scene_0.gt.json", dataset / "scene_0.gt.parquet"):
        p.rename(p.with_name("hidden_" + p.name))
    assert find_beside(scene.recording)[0].name == "scene_0.scannet"
    beside, _ = _eval(scene, tmp_path / "beside", EvalConfig(**{**CONFIG.__dict__, "rooms": False}))
    assert _same(native, beside)
    # named in index.json, relative to the dataset
    index = json.loads((dataset / "index.json").read_text())
    index["recordings"] = [{"recording": "scene_0.mcap", "gt": "scene_0.scannet"}]
    (dataset / "index.json").write_text(json.dumps(index))
    (scenes,) = [scenes_of(dataset)]
    assert scenes[0].gt.path == dataset / "scene_0.scannet"


@pytest.mark.slow
def test_gt_transform_brings_a_scan_into_the_map_frame(dataset: Path, tmp_path: Path) -> None:
    """Ground truth stored in another frame (rotated 90 degrees, shifted) is refused as not
    overlapping, and gives the native results once --gt-transform undoes the move."""
    scene = scenes_of(dataset)[0]
    gt = read_native(scene.recording)
    move = np.array([[0, -1, 0, 3.0], [1, 0, 0, -2.0], [0, 0, 1, 0.5], [0, 0, 0, 1]])
    moved = tmp_path / "scan" / "scene_0.mcap"
    moved.parent.mkdir()
    export_ground_truth(gt.transformed(move, frame="scan"), moved, ["ply"])
    ply = moved.with_name("scene_0.labels.ply")
    with pytest.raises(Exception, match="does not overlap the map"):
        _eval(scene, tmp_path / "bad", gt=[ply])
    assert not (tmp_path / "bad" / "results.md").exists()
    back = GtSource.of(None, None, ",".join(map(str, np.linalg.inv(move).reshape(-1))), None)
    native, _ = _eval(scene, tmp_path / "native")
    summary, _ = _eval(scene, tmp_path / "back", gt=[ply], gt_defaults=back)
    # float32 points moved there and back differ in their last bits, never by 5 cm
    assert _same(native, summary)


def _cli(*args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "care_maps.cli.main", "eval", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=300)


def _bad_inputs(root: Path) -> dict[str, tuple[Path, str]]:
    """Broken ground truth of scene 0, each with the message it must give."""
    bad = root / "bad"
    bad.mkdir()
    out = {}
    (bad / "missing.json").write_text(
        json.dumps({"objects": [{"class": "chair", "center": [1, 1, 0.4]}]})
    )
    out["missing field"] = (bad / "missing.json", "missing field 'size'")
    (bad / "unknown.csv").write_text("chair,1,1,0.4,0.4,0.4,0.4\nwardrobe,3,2,0.4,0.4,0.4,0.4\n")
    out["unknown class"] = (
        bad / "unknown.csv",
        "not in the instances map's vocabulary: 'wardrobe'",
    )
    (bad / "empty.csv").write_text("chair,1,1,0.4,0.4,0.0,0.4\n")
    out["empty box"] = (bad / "empty.csv", "an empty box")
    (bad / "far.csv").write_text("chair,100,100,0.4,0.4,0.4,0.4\n")
    out["no overlap"] = (bad / "far.csv", "does not overlap the map")
    (bad / "corrupt.labels.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\nend_header\n\x00\x01"
    )
    out["corrupt ply"] = (bad / "corrupt.labels.ply", "not a readable PLY file")
    return out


@pytest.mark.slow
def test_bad_ground_truth_is_one_line_and_no_results(dataset: Path, tmp_path: Path) -> None:
    store = dataset / "stores" / "scene_0"
    for case, (path, message) in _bad_inputs(tmp_path).items():
        out = tmp_path / f"out_{case.replace(' ', '_')}"
        done = _cli(str(store), "--out", str(out), "--gt", str(path), "--seeds", "1")
        assert done.returncode == 1, (case, done.stderr)
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1, (case, done.stderr)
        assert lines[0].startswith("error: "), (case, done.stderr)
        assert message in lines[0], (case, lines[0])
        assert not (out / "results.md").exists(), case
        assert not list(out.glob("scenes/*.parquet")), case


def test_an_instance_without_points_is_refused(dataset: Path, tmp_path: Path) -> None:
    """A ScanNet object whose segments hold no vertex: an empty mask, refused by name."""
    scene = scenes_of(dataset)[0]
    export_ground_truth(read_native(scene.recording), scene.recording, ["scannet"])
    agg = scene.recording.with_name("scene_0.scannet") / "scene_0.aggregation.json"
    doc = json.loads(agg.read_text())
    doc["segGroups"].append({"id": 99, "objectId": 99, "segments": [12345], "label": "chair"})
    agg.write_text(json.dumps(doc))
    done = _cli(str(dataset / "stores" / "scene_0"), "--out", str(tmp_path / "o"), "--gt", str(agg))
    assert done.returncode == 1
    assert "instance(s) [100]" in done.stderr
    assert "no points" in done.stderr


@pytest.mark.slow
def test_unknown_classes_can_be_ignored_or_renamed(dataset: Path, tmp_path: Path) -> None:
    store = str(dataset / "stores" / "scene_0")
    gt = tmp_path / "boxes.csv"
    gt.write_text(
        "class,cx,cy,cz,sx,sy,sz\nchair,1,1,0.4,0.4,0.4,0.4\nwardrobe,2,4,0.4,0.4,0.4,0.4\n"
    )
    done = _cli(
        store,
        "--out",
        str(tmp_path / "a"),
        "--gt",
        str(gt),
        "--gt-unknown-classes",
        "ignore",
        "--seeds",
        "1",
        "--bootstrap",
        "20",
    )
    assert done.returncode == 0, done.stderr
    assert (
        "left out (--gt-unknown-classes ignore): scene_0: wardrobe"
        in (tmp_path / "a" / "results.md").read_text()
    )
    table = tmp_path / "map.tsv"
    table.write_text("raw\tnice\nwardrobe\ttable\n")
    done = _cli(
        store,
        "--out",
        str(tmp_path / "b"),
        "--gt",
        str(gt),
        "--gt-class-map",
        f"{table}:raw:nice",
        "--seeds",
        "1",
        "--bootstrap",
        "20",
    )
    assert done.returncode == 0, done.stderr
    assert "protocol `instance` (2 queries)" in (tmp_path / "b" / "results.md").read_text()


def test_help_names_the_formats() -> None:
    done = _cli("--help")
    text = " ".join(done.stdout.split())
    for name in (
        "native",
        "annotations",
        "ply",
        "scannet",
        "matterport",
        "replica",
        "--gt-transform",
    ):
        assert name in text


@pytest.mark.slow
def test_care_run_refuses_bad_ground_truth_before_any_work(dataset: Path, tmp_path: Path) -> None:
    """``care run --gt``: a corrupt file stops the run in one line before the (long) ingest,
    and nothing is written."""
    recording = dataset / "scene_0.mcap"
    bad = tmp_path / "boxes.yaml"
    bad.write_text("objects: [{class: chair, center: [1, 1], size: [1, 1, 1]}]\n")
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "care_maps.cli.main", "run", str(recording), "--out", str(out)]
    done = subprocess.run([*cmd, "--gt", str(bad)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == [
        f"error: {bad}: objects[0]: 'center' should be 3 numbers, got [1, 1]"
    ]
    lonely = tmp_path / "lonely.mcap"
    lonely.write_bytes(b"")
    done = subprocess.run(
        [*cmd[:4], str(lonely), "--out", str(out)], capture_output=True, text=True, timeout=300
    )
    # a recording without ground truth is mapped, not refused (tests/ingest/test_run_own.py);
    # this one is no recording at all: one line, and nothing written
    assert done.returncode == 1
    assert done.stderr.strip().splitlines()[-1].startswith(f"error: {lonely}: ")
    assert not out.exists()


@pytest.mark.slow
def test_a_changed_ground_truth_file_is_not_served_from_the_cache(
    exported: Scene, tmp_path: Path
) -> None:
    """The cached scene results are keyed by the ground truth's files, so editing the
    annotations (or its rooms file beside it) recomputes the scene."""
    csv = exported.recording.with_name("scene_0.annotations.csv")
    first, _ = _eval(exported, tmp_path / "out", gt=[csv])
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join(lines[:-1]) + "\n")  # drop the last object
    second, _ = _eval(exported, tmp_path / "out", gt=[csv])

    def queries(table: pa.Table) -> int:
        return max(r["n_queries"] for r in table.to_pylist() if r["protocol"] == "instance")

    assert queries(second) == queries(first) - 1
