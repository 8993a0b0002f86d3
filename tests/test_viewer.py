"""The four recordings of ``care run`` on the sample, and the answer recordings of
``care query`` and ``care replan`` on its store, opened in the real Rerun viewer.

``scripts/check_viewer.py`` drives the viewer shipped in rerun-sdk headless (software Vulkan:
``mesa-vulkan-drivers``, installed by ``scripts/install.sh``), shows every view, and reads the
errors the viewer itself reports in each view's corner. These tests skip only when that viewer
cannot start on the machine; anything else (a view with an error, a blank screenshot, a
recording that does not load in time) fails.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from care_maps.evaluate.pipeline import SAMPLE
from care_maps.evaluate.viz import first_failed_step

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "check_viewer.py"
STAGES = ("ingest", "grid", "instances", "eval")
MIN_VIEWS = {"ingest": 4, "grid": 7, "instances": 4, "eval": 6}
"""Views each stage's blueprint has at least (the layout a person opens)."""

pytestmark = pytest.mark.slow


def _check(*args: str | Path, timeout: float) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(SCRIPT), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


@pytest.fixture(scope="session")
def viewer() -> None:
    """Skip when (and only when) the real viewer cannot start here."""
    done = _check("--probe", timeout=180)
    if done.returncode == 3:
        pytest.skip(done.stderr.strip().splitlines()[-1])
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.fixture(scope="session")
def sample_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One ``care run`` of the bundled sample, shared by the viewer tests."""
    if not (SAMPLE / "index.json").is_file():
        pytest.skip("the bundled sample is not present")
    out = tmp_path_factory.mktemp("viewer") / "out"
    cmd = [sys.executable, "-m", "care_maps.cli.main", "run", "--out", str(out), "--seeds", "2"]
    done = subprocess.run(
        [*cmd, "--workers", "1"], capture_output=True, text=True, timeout=900, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return out


def _care(*args: str | Path) -> None:
    """One ``care`` command in a fresh process, which must succeed."""
    done = subprocess.run(
        [sys.executable, "-m", "care_maps.cli.main", *map(str, args)],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]


def _views_without_errors(rrd: Path, shots: Path) -> dict[str, list[str]]:
    """The viewer's report of ``rrd`` (view -> errors), every view free of errors and the
    screenshot not blank."""
    done = _check(rrd, "--shots", shots, "--json", shots / "report.json", timeout=300)
    report = json.loads((shots / "report.json").read_text())[str(rrd)]
    assert done.returncode == 0, done.stdout + done.stderr[-2000:]
    assert not {view: errs for view, errs in report.items() if errs}
    assert _not_blank(shots / f"{rrd.name.removesuffix('.rrd')}.png")
    return report


def _not_blank(png: Path) -> bool:
    """Something is drawn: the commonest colour (the background) covers under 99.5% of it."""
    from PIL import Image

    pixels = np.asarray(Image.open(png).convert("RGB")).reshape(-1, 3)
    if not len(pixels):
        return False
    _, counts = np.unique(pixels, axis=0, return_counts=True)
    return counts.max() / len(pixels) < 0.995


@pytest.mark.parametrize("stage", STAGES)
def test_every_view_renders_without_errors(
    viewer: None, sample_run: Path, tmp_path: Path, stage: str
) -> None:
    rrd = sample_run / f"scene_000.{stage}.rrd"
    assert rrd.is_file()
    args: list[str | Path] = [rrd, "--shots", tmp_path, "--json", tmp_path / "report.json"]
    if stage == "eval":  # step to a query whose first attempt failed: every entity shows
        attempts = pq.read_table(sample_run / "eval" / "attempts.parquet")
        step = first_failed_step(attempts, "scene_000", ["instances", "grid"])
        assert step is not None
        args += ["--time", f"query={step}"]
    if stage == "instances":  # an instance with fewer chosen views than others: ranks cleared
        views = pq.read_table(sample_run / "stores" / "scene_000" / "instance_views.parquet")
        counts = np.bincount(views.column("instance_id").to_numpy())
        args += ["--time", f"instance={int(np.argmin(counts))}"]
    done = _check(*args, "--settle", "3", timeout=540)
    report = json.loads((tmp_path / "report.json").read_text())[str(rrd)]
    assert done.returncode == 0, done.stdout + done.stderr[-2000:]
    assert len(report) >= MIN_VIEWS[stage], report
    assert not {view: errs for view, errs in report.items() if errs}
    shots = sorted((tmp_path / f"scene_000.{stage}").glob("*.png"))
    assert len(shots) == len(report)  # a screenshot per view
    assert all(_not_blank(p) for p in shots), [p.name for p in shots if not _not_blank(p)]
    assert _not_blank(tmp_path / f"scene_000.{stage}.png")


@pytest.mark.parametrize("command", ["query", "replan"])
def test_answer_recordings_render_without_errors(
    viewer: None, sample_run: Path, tmp_path: Path, command: str
) -> None:
    """``--rrd`` of ``care query`` (three attempts, each from where the last ended) and of
    ``care replan`` (a visited candidate, the way to the next) over the sample's grid."""
    store = sample_run / "stores" / "scene_000"
    rrd = tmp_path / f"scene_000.{command}.rrd"
    extra = ["--visited", "0"] if command == "replan" else []
    _care(command, store, "sofa", "--map", "instances", *extra, "--rrd", rrd)
    report = _views_without_errors(rrd, tmp_path)
    assert len(report) == 2, report


def test_checker_reports_a_view_error(viewer: None, tmp_path: Path) -> None:
    """The check is not vacuous: a 2D view without a pinhole root over a camera image is
    reported with the viewer's own error and a non-zero exit."""
    import rerun as rr
    import rerun.blueprint as rrb

    rrd = tmp_path / "bad.rrd"
    rec = rr.RecordingStream("care_test", recording_id="bad")
    rec.save(rrd)
    rec.log(
        "world/camera",
        rr.Transform3D(translation=[1.0, 0.0, 0.0]),
        rr.Pinhole(focal_length=100.0, width=64, height=48),
        static=True,
    )
    rec.log("world/camera/rgb", rr.Image(np.zeros((48, 64, 3), np.uint8)), static=True)
    rec.send_blueprint(rrb.Blueprint(rrb.Spatial2DView(origin="world", name="no root")))
    rec.flush()
    rec.disconnect()
    done = _check(rrd, "--shots", tmp_path, "--json", tmp_path / "r.json", timeout=300)
    assert done.returncode == 1
    errors = json.loads((tmp_path / "r.json").read_text())[str(rrd)]["no root"]
    assert any("pinhole" in e for e in errors)


def test_a_store_of_two_runs_renders_without_errors(
    viewer: None, tmp_path: Path, livingroom_root: Path
) -> None:
    """``care ingest --append --rrd``: the store's two runs, each on its own timeline (the
    third-party living room written as a ROS 1 bag and an MCAP file by the real writers)."""
    from tests.support.frames import load_livingroom
    from tests.support.recordings import Container, robot_messages, write_bag

    frames = load_livingroom(livingroom_root, 12)
    first = write_bag(tmp_path / "day1.bag", robot_messages(frames[0:8]), Container.ROS1)
    second = write_bag(tmp_path / "day2.mcap", robot_messages(frames[4:12]), Container.MCAP)
    store, rrd = tmp_path / "store", tmp_path / "runs.rrd"
    _care("ingest", first, "--out", store)
    _care("ingest", second, "--out", store, "--append", "--rrd", rrd)
    report = _views_without_errors(rrd, tmp_path)
    assert len(report) >= MIN_VIEWS["ingest"], report
