"""`care sample make`: a dataset directory with an index, resumable, with a Rerun view."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from care_maps.cli.main import _register, app
from care_maps.core.viz import rrd_entity_counts
from care_maps.truth.formats.native import read_native

pytestmark = pytest.mark.slow


def _make(out: Path, *extra: str):
    _register()
    args = ["sample", "make", "--out", str(out), "--scenes", "2", "--rooms", "1", "--width", "48",
            "--height", "36", "--frames", "4", *extra]  # fmt: skip
    return CliRunner().invoke(app, args)


def test_make_dataset_index_resume_and_rrd(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    rrd = tmp_path / "world.rrd"
    result = _make(out, "--format", "ros2", "--workers", "2", "--rrd", str(rrd))
    assert result.exit_code == 0, result.output
    index = json.loads((out / "index.json").read_text())
    recs = index["recordings"]
    assert [r["recording"] for r in recs] == ["scene_000", "scene_001"]
    assert recs[0]["seed"] != recs[1]["seed"]
    for r in recs:
        assert (out / r["recording"] / "metadata.yaml").is_file()  # a rosbag2 directory
        gt = read_native(out / r["recording"])
        assert gt.instances.num_rows == r["num_instances"]
        assert not r["skipped"]
    counts = rrd_entity_counts(rrd)
    for scene in ("scene_000", "scene_001"):
        assert counts[(f"/world/{scene}/mesh", "Mesh3D:vertex_positions")] == 1
        assert counts[(f"/world/{scene}/instances", "Boxes3D:half_sizes")] == 1
        assert counts[(f"/world/{scene}/trajectory", "LineStrips3D:strips")] == 1
        assert counts[(f"/world/{scene}/camera", "Transform3D:translation")] == 4
    # re-running with the same settings skips the finished scenes
    stamp = (out / "scene_000.gt.parquet").stat().st_mtime_ns
    again = _make(out, "--format", "ros2", "--workers", "1")
    assert again.exit_code == 0, again.output
    assert all(r["skipped"] for r in json.loads((out / "index.json").read_text())["recordings"])
    assert (out / "scene_000.gt.parquet").stat().st_mtime_ns == stamp


def test_bad_options_are_one_line_errors(tmp_path: Path) -> None:
    import subprocess
    import sys

    for args, words in (
        (["--format", "zip"], "choose mcap, ros2 or ros1"),
        (["--rooms", "9"], "1 to 6 rooms"),
        (["--frames", "0"], "at least one frame"),
        (["--frames", "-3"], "at least one frame"),
    ):
        out = tmp_path / "out"
        proc = subprocess.run(
            [
                sys.executable,
                "-m",
                "care_maps.cli.main",
                "sample",
                "make",
                "--out",
                str(out),
                *args,
            ],
            capture_output=True,
            text=True,
            check=False,
        )
        assert proc.returncode == 1
        assert words in proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1
        assert not out.exists()  # refused before anything is written


def test_make_exports_the_ground_truth_in_every_format(tmp_path: Path) -> None:
    """``--gt-formats all``: each format, read back, holds the native ground truth's instances,
    classes and (where it keeps points) the very same labelled points."""
    import numpy as np

    from care_maps.truth.load import read_ground_truth

    out = tmp_path / "ds"
    result = _make(out, "--gt-formats", "all")
    assert result.exit_code == 0, result.output
    native = read_native(out / "scene_000.mcap")
    unseen = set(native.info.get("unseen_instances") or [])
    seen = {i: n for i, n in native.instance_class_names().items() if i not in unseen}
    order = np.lexsort(native.points.T)
    for name in ("annotations.json", "annotations.yaml", "annotations.csv", "labels.ply",
                 "scannet", "matterport", "replica"):  # fmt: skip
        gt = read_ground_truth(out / f"scene_000.{name}")
        assert gt.instance_class_names() == seen, name
        if len(gt.points):
            back = np.lexsort(gt.points.T)
            np.testing.assert_array_equal(gt.points[back], native.points[order])
            expected = np.where(
                np.isin(native.point_instance, list(unseen)), 0, native.point_instance
            )
            np.testing.assert_array_equal(gt.point_instance[back], expected[order])
    bad = _make(tmp_path / "bad", "--gt-formats", "obj")
    assert bad.exit_code != 0
    assert not (tmp_path / "bad").exists()
