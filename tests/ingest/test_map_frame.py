"""Any world frame: the living-room frames (a rendered scene with an estimated trajectory, in
the first camera's y-down frame) written through the real writers into MCAP, ROS 2 and ROS 1
recordings, and into an MCAP in a z-up frame turned and shifted by a known transform, give the
same grid and instance map once each store's map transform is applied.

The map frame is checked against what we know independently: the floor of the room lies along
the trajectory's +y axis (cameras held level, y down), so up must be -y of the y-down world and
(T applied) +z of the z-up one; the floor points land at z = 0."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from care_maps.core.frames import Frame
from care_maps.core.mapframe import MapFrame, UpAxis
from care_maps.core.store import Store, read_table
from care_maps.fuse.frame import ensure_map_frame, sample_points
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.fuse.instances import InstanceConfig, build_instances
from care_maps.geometry.mapframe import FloorNotFoundError, estimate_map_frame
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.write import write_recording
from care_maps.runtime.execution import Execution
from tests.support.encoders import TinyEncoder
from tests.support.frames import load_livingroom, synthetic_frames

QUIET = Execution(progress=False)

CELL = 0.05
ZUP_FROM_YDOWN = np.eye(4)
ZUP_FROM_YDOWN[:3, :3] = (
    Rotation.from_euler("z", 30, degrees=True) * Rotation.from_euler("x", -90, degrees=True)
).as_matrix()
ZUP_FROM_YDOWN[:3, 3] = [1.0, -2.0, 1.2]  # the floor ends up near z = 0.8


def _half(frame: Frame, pose: np.ndarray) -> Frame:
    """The frame at half resolution (320 x 240) with the given pose."""
    K = frame.K.copy()
    K[:2] /= 2
    K[:2, 2] = (frame.K[:2, 2] - 0.5) / 2
    return Frame(
        frame.stamp_ns, frame.rgb[::2, ::2].copy(), frame.depth_m[::2, ::2].copy(), K, pose
    )


@pytest.fixture(scope="module")
def frames(livingroom_root: Path) -> list[Frame]:
    return [_half(f, f.cam_to_world) for f in load_livingroom(livingroom_root, 200)[::5]]


@pytest.fixture(scope="module")
def stores(frames, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("frames")
    zup = [_half(f, ZUP_FROM_YDOWN @ f.cam_to_world) for f in frames]
    cases = {
        "mcap": (frames, "mcap", "rec.mcap"),
        "ros2": (frames, "ros2", "rec_ros2"),
        "ros1": (frames, "ros1", "rec.bag"),
        "zup": (zup, "mcap", "zup.mcap"),
    }
    out = {}
    for name, (fr, fmt, file) in cases.items():
        rec = write_recording(root / file, fr, fmt=fmt, ros2_storage="mcap")
        config = IngestConfig(vocabulary="red,green,blue")
        out[name] = run_ingest(rec, root / name, config, run=QUIET, encoder=TinyEncoder())
        build_grid(out[name], GridConfig(cell_size=CELL, stride=2))
    return out


def _frame(store: Path) -> MapFrame:
    return Store(store).map_frame


@pytest.mark.slow
def test_up_axis_and_floor_found_from_the_data(stores) -> None:
    ydown, zup = _frame(stores["mcap"]), _frame(stores["zup"])
    assert ydown.up == (0.0, -1.0, 0.0)  # snapped: the trajectory's y axis, exactly
    up_in_zup = ZUP_FROM_YDOWN[:3, :3] @ np.array([0.0, -1.0, 0.0])
    assert np.degrees(np.arccos(np.clip(np.dot(zup.up, up_in_zup), -1, 1))) < 3.0
    points, poses = sample_points(Store(stores["mcap"]))
    z = (points @ ydown.map_from_world[:3, :3].T + ydown.map_from_world[:3, 3])[:, 2]
    assert abs(np.percentile(z, 2)) < 0.05  # the floor at z = 0
    heights = (ydown.map_from_world @ poses)[:, 2, 3]
    assert heights.min() > 0.2
    assert heights.max() < 1.8


def test_the_sample_is_the_same_on_any_number_of_decoding_threads(stores) -> None:
    from care_maps.fuse.frame import _sample_points

    one, two, five = (_sample_points(Store(stores["mcap"]), n) for n in (1, 2, 5))
    for other in (two, five):
        assert other[0].tobytes() == one[0].tobytes()
        assert other[1].tobytes() == one[1].tobytes()


def test_every_format_and_frame_gives_the_same_grid(stores) -> None:
    def cells_in_ydown_map(name: str) -> np.ndarray:
        table = read_table(stores[name] / "cells.parquet", ["x", "y", "z_max"])
        pts = np.stack([table.column(c).to_numpy() for c in ("x", "y", "z_max")], 1)
        world = _points(np.linalg.inv(_frame(stores[name]).map_from_world), pts)
        if name == "zup":
            world = _points(np.linalg.inv(ZUP_FROM_YDOWN), world)
        return _points(_frame(stores["mcap"]).map_from_world, world)

    ref = cells_in_ydown_map("mcap")
    for name in ("ros2", "ros1"):  # the same world frame: the very same cells
        np.testing.assert_allclose(cells_in_ydown_map(name), ref, atol=1e-6)
    other = cells_in_ydown_map("zup")
    for a, b in ((other, ref), (ref, other)):
        d, _ = cKDTree(b[:, :2]).query(a[:, :2])
        assert np.mean(d <= CELL) > 0.97, np.percentile(d, [50, 90, 99])
    assert 0.9 < len(other) / len(ref) < 1.1
    meta = json.loads((stores["zup"] / "map_frame.json").read_text())
    assert meta["frame"]["method"] == "floor plane"


def test_instance_maps_agree(stores) -> None:
    centres = {}
    for name in ("mcap", "zup"):
        build_instances(stores[name], InstanceConfig(voxel_size=0.03))
        table = read_table(stores[name] / "instances.parquet", ["center", "num_points"])
        c = np.asarray(table.column("center").to_pylist(), np.float64).reshape(-1, 3)
        world = _points(np.linalg.inv(_frame(stores[name]).map_from_world), c)
        if name == "zup":
            world = _points(np.linalg.inv(ZUP_FROM_YDOWN), world)
        centres[name] = world
    a, b = centres["mcap"], centres["zup"]
    assert abs(len(a) - len(b)) <= max(1, len(a) // 5)
    d, _ = cKDTree(b).query(a)
    assert np.median(d) < 0.1


def test_degenerate_frames_are_one_clear_error() -> None:
    rng = np.random.default_rng(0)
    poses = np.repeat(np.eye(4)[None], 3, axis=0)  # level cameras looking along +z, y down
    wall = np.c_[rng.random(500), rng.random(500), np.full(500, 2.0)]  # only the wall ahead
    with pytest.raises(FloorNotFoundError, match="--up-axis"):
        estimate_map_frame(wall, poses)
    given = estimate_map_frame(wall, poses, up_axis=UpAxis.NY, floor=-1.5)
    assert given.method == "given"
    np.testing.assert_allclose(given.map_from_world[:3, :3] @ [0, -1.0, 0], [0, 0, 1.0])
    np.testing.assert_allclose(_points(given.map_from_world, np.array([[0, 1.5, 0]]))[0, 2], 0.0)


def _points(transform: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ transform[:3, :3].T + transform[:3, 3]


def test_cli_up_axis_option_replaces_the_frame(stores) -> None:
    frame = ensure_map_frame(stores["ros1"], UpAxis.NY)
    assert frame.up == (0.0, -1.0, 0.0)
    assert frame.method == "given"


@pytest.mark.slow
def test_cli_no_floor_is_one_line_and_no_map(tmp_path: Path) -> None:
    """A camera looking at a wall (the synthetic tilted plane, no floor in view): one line
    naming --up-axis, exit 1, no map; with the axis given the grid is built."""
    import subprocess
    import sys

    rec = write_recording(tmp_path / "wall.mcap", synthetic_frames(6), fmt="mcap")
    store = run_ingest(
        rec, tmp_path / "store", IngestConfig(vocabulary="a,b"), run=QUIET, encoder=TinyEncoder()
    )
    care = [sys.executable, "-m", "care_maps.cli.main", "fuse", "grid", str(store)]
    done = subprocess.run(care, capture_output=True, text=True)
    assert done.returncode == 1
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, done.stderr
    assert "no floor found" in lines[0]
    assert "--up-axis" in lines[0]
    assert not (store / "cells.parquet").exists()
    given = subprocess.run(
        [*care, "--up-axis", "+z", "--floor-z", "0", "--z-max", "4"], capture_output=True, text=True
    )
    assert given.returncode == 0, given.stderr[-1500:]
    assert (store / "cells.parquet").is_file()


def test_care_frame_says_what_to_publish(stores, run_cli) -> None:
    """The y-down store's goals are in care_map, published under the world frame by the
    printed command; the z-up store's are in the world frame when its floor is level."""
    from care_maps.query.goals import GoalMaker

    code, out, err = run_cli("frame", stores["mcap"])
    assert code == 0, err
    world = Store(stores["mcap"]).meta.world_frame
    assert "'care_map'" in out
    assert f"--frame-id {world} --child-frame-id care_map" in out
    code, out, err = run_cli("frame", stores["mcap"], "--json")
    tf = json.loads(out)
    assert tf["child_frame_id"] == "care_map"
    t, q = tf["transform"]["translation"], tf["transform"]["rotation"]
    world_from_map = np.eye(4)
    world_from_map[:3, :3] = Rotation.from_quat([q[k] for k in "xyzw"]).as_matrix()
    world_from_map[:3, 3] = [t[k] for k in "xyz"]
    np.testing.assert_allclose(
        world_from_map @ _frame(stores["mcap"]).map_from_world, np.eye(4), atol=1e-9
    )
    zup = _frame(stores["zup"])
    plan = GoalMaker.plan(stores["zup"])
    assert plan.publish == (not zup.is_gravity_aligned)
