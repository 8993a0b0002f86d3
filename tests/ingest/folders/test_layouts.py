"""Dataset folders as downloaded give the map their frames give as a recording: the same 40
living-room frames laid out as Redwood, TUM RGB-D, ETH3D SLAM, Bonn RGB-D Dynamic, 7-Scenes,
Replica (NICE-SLAM) and our generic layout, each in its dataset's own conventions
(``tests/support/layouts.py``), and written as an MCAP bag by the real writer. Every store
has the bag's views and poses, and the same grid, cell for cell within 1%. Where the
dataset's own camera is not the living room's (TUM without a sensor in the folder's name,
Bonn, 7-Scenes) the living room's is given with --intrinsics, as a user of such frames
would."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from care_maps.core.store import Store, read_table
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.ingest.folders import LAYOUTS as ALL_LAYOUTS
from care_maps.ingest.folders import DatasetLayout, detect_layout
from care_maps.ingest.folders.base import FolderOptions
from care_maps.ingest.folders.frames import FolderFrames, open_frames
from care_maps.ingest.folders.tum import TumLayout
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.source import ReadOptions
from care_maps.ingest.write import write_recording
from care_maps.runtime.execution import Execution
from tests.support import layouts
from tests.support.encoders import TinyEncoder

QUIET = Execution(progress=False)
PRIMESENSE = FolderOptions.of(ReadOptions(intrinsics="primesense"))
CELL = 0.05
LAYOUTS = ("redwood", "tum", "eth3d", "bonn", "7scenes", "replica", "generic")
FOLDERS = {
    "redwood": ("redwood", "livingroom_redwood"),
    "tum": ("tum", "rgbd_dataset_livingroom"),
    "eth3d": ("eth3d", "sofa_1"),
    "bonn": ("bonn", "rgbd_bonn_livingroom"),
    "7scenes": ("seven_scenes", "livingroom/seq-01"),
    "replica": ("replica", "Replica"),
    "generic": ("generic", "generic"),
}
"""Writer (``tests/support/layouts.py``) and folder name of each layout."""
LIVING_ROOM_CAMERA = {
    "tum": "primesense",
    "bonn": "primesense",
    "7scenes": "525,525,319.5,239.5",
}
"""``--intrinsics`` of the layouts whose own camera is not the living room's."""


def write_layout(layout: str, root: Path, frames) -> Path:
    """``frames`` in ``layout`` under ``root`` (Replica: the scene inside its release)."""
    writer, name = FOLDERS[layout]
    return getattr(layouts, writer)(root / name, frames)


def read_options(layout: str) -> ReadOptions:
    return ReadOptions(intrinsics=LIVING_ROOM_CAMERA.get(layout))


@pytest.fixture(scope="module")
def sources(tmp_path_factory, livingroom40) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("layouts")
    written = {name: write_layout(name, root, livingroom40) for name in LAYOUTS}
    return {"bag": write_recording(root / "rec.mcap", livingroom40, fmt="mcap"), **written}


@pytest.fixture(scope="module")
def stores(sources, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("stores")
    out = {}
    for name, source in sources.items():
        config = IngestConfig(vocabulary="red,green,blue", read=read_options(name))
        out[name] = run_ingest(source, root / name, config, run=QUIET, encoder=TinyEncoder())
        build_grid(out[name], GridConfig(cell_size=CELL, stride=2), run=QUIET)
    return out


def _poses(store: Path) -> np.ndarray:
    return np.stack(
        [f.cam_to_world for _, f in Store(store).iter_frames(extras=False, in_map=False)]
    )


def _cells(store: Path) -> set[tuple[int, int]]:
    table = read_table(store / "cells.parquet", ["ix", "iy"])
    return set(zip(table.column("ix").to_pylist(), table.column("iy").to_pylist(), strict=True))


def test_each_layout_is_detected_by_its_names(tmp_path, livingroom40) -> None:
    frames = livingroom40[:2]
    for name in LAYOUTS:
        folder = write_layout(name, tmp_path, frames)
        found = [kind for kind, cls in ALL_LAYOUTS.items() if cls.detect(folder)]
        assert found == [DatasetLayout(name)], (name, found)  # one layout per folder
        assert detect_layout(folder) == DatasetLayout(name)
    assert detect_layout(tmp_path / "Replica") is None  # the release folder above the scene
    assert detect_layout(tmp_path / "livingroom") is None  # a 7-Scenes scene: its sequences
    bag = write_recording(tmp_path / "rec.mcap", frames, fmt="mcap")
    assert detect_layout(bag) is None  # a file


@pytest.mark.slow
@pytest.mark.parametrize("layout", LAYOUTS)
def test_a_dataset_folder_gives_the_bags_views_and_grid(stores, layout: str) -> None:
    meta = json.loads((stores[layout] / "meta.json").read_text())
    assert meta["topics"]["layout"] == layout
    assert meta["counts"]["frames"] == 40
    assert "format" not in meta["config"]["read"]  # only picks the layout, recorded in topics
    if layout in LIVING_ROOM_CAMERA:
        assert meta["topics"]["intrinsics"]["source"] == "--intrinsics"
    # TUM, Bonn: poses interpolated between 100 Hz samples of a trajectory that is itself
    # linear between the images, so it cuts the corners at them (under a millimetre); TUM,
    # ETH3D, Bonn and generic: quaternions written with six decimals; 7-Scenes: eight digits
    atol = {"tum": 1e-3, "bonn": 1e-3, "eth3d": 1e-5, "generic": 1e-5}.get(layout, 1e-6)
    np.testing.assert_allclose(_poses(stores[layout]), _poses(stores["bag"]), atol=atol)
    ours, bag = _cells(stores[layout]), _cells(stores["bag"])
    assert len(ours ^ bag) <= 0.01 * len(bag), (len(ours), len(bag), len(ours ^ bag))


def test_tum_associates_depth_and_interpolates_the_ground_truth(tmp_path, livingroom40) -> None:
    frames = livingroom40[:16]
    folder = layouts.tum(tmp_path / "rgbd_dataset_livingroom", frames)
    layout = TumLayout(folder, max_dt=0.02, options=PRIMESENSE)
    views = layout.views()
    assert len(views) == 16
    assert not layout.dropped
    first = frames[0]
    for view, frame in zip(views, frames, strict=True):
        seconds = layouts.tum_seconds(frame, first)
        assert view.colour.name == f"{seconds:.6f}.png"
        assert view.depth.name == f"{seconds + 0.007:.6f}.png"  # the depth 7 ms later
        assert view.stamp_ns == round(seconds * 1e6) * 1000  # microseconds, exactly
        np.testing.assert_allclose(view.cam_to_world, frame.cam_to_world, atol=1e-3)
    # depth further than --max-dt away: no colour image has depth
    assert not TumLayout(folder, max_dt=0.005, options=PRIMESENSE).views()


def test_tum_drops_colour_without_depth_or_ground_truth(tmp_path, livingroom40) -> None:
    folder = layouts.tum(tmp_path / "rgbd_dataset_livingroom", livingroom40[:12])
    depth = (folder / "depth.txt").read_text().splitlines()
    (folder / "depth.txt").write_text("\n".join(depth[:3] + depth[4:]) + "\n")  # image 0's
    gt = (folder / "groundtruth.txt").read_text().splitlines()
    lost = [i for i, line in enumerate(gt) if not line.startswith("#")][20:40]  # 0.2 s lost
    (folder / "groundtruth.txt").write_text(
        "\n".join(line for i, line in enumerate(gt) if i not in set(lost)) + "\n"
    )
    with FolderFrames(folder, ReadOptions(intrinsics="primesense")) as frames:
        got = list(frames)
        stats = frames.stats
    assert stats.rgb_messages == 12
    assert stats.dropped == {"no_depth": 1, "no_pose": 12 - 1 - len(got)}
    assert 0 < stats.dropped["no_pose"] < 5
    assert stats.frames == len(got)


def test_tum_camera_from_the_folder_name_or_intrinsics_json(tmp_path, livingroom40) -> None:
    frames = livingroom40[:3]
    fr1 = layouts.tum(tmp_path / "rgbd_dataset_freiburg1_xyz", frames)
    with open_frames(fr1) as opened:
        assert isinstance(opened, FolderFrames)
        K = next(iter(opened)).K
        lens = opened.distortions
    assert (K[0, 0], K[1, 1], K[0, 2], K[1, 2]) == (517.3, 516.5, 318.6, 255.3)
    assert lens[0].coefficients == (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)
    (fr1 / "intrinsics.json").write_text(json.dumps({"fx": 500, "fy": 501, "cx": 320, "cy": 240}))
    with FolderFrames(fr1) as opened:
        frame = next(iter(opened))
        topics = opened.describe()["topics"]
    assert frame.K[0, 0] == 500.0
    assert topics["depth_scale"] == 5000.0  # TUM's, the file gives none
    assert topics["intrinsics"]["source"] == "intrinsics.json"
    assert opened.distortions == []


@pytest.mark.slow
def test_a_forced_layout_equal_to_the_detected_one_keeps_the_store(stores, sources) -> None:
    before = (stores["redwood"] / "meta.json").read_bytes()
    config = IngestConfig(
        vocabulary="red,green,blue", read=ReadOptions(format=DatasetLayout.REDWOOD)
    )
    run_ingest(sources["redwood"], stores["redwood"], config, run=QUIET, encoder=TinyEncoder())
    assert (stores["redwood"] / "meta.json").read_bytes() == before


@pytest.mark.slow
def test_care_ingest_and_topics_read_the_living_room_folder_as_it_is(
    livingroom_root: Path, tmp_path: Path, run_cli
) -> None:
    """The living-room folder (read-only, third-party) is itself an Open3D / Redwood folder."""
    code, out, err = run_cli("topics", livingroom_root)
    assert code == 0, err
    assert "layout redwood: 211 views of 211 colour images" in out
    assert "camera_intrinsic.json" in out
    code, out, err = run_cli("ingest", livingroom_root, "--out", tmp_path / "store", "--end", "0.5")
    assert code == 0, err
    store = Store(tmp_path / "store")
    assert store.num_views == 16  # 0.5 s at 30 Hz, from the first view
    assert store.meta.topics["layout"] == "redwood"
    assert store.meta.world_frame == "redwood_world"
    code, out, _ = run_cli("topics", livingroom_root, "--stamps")
    assert code == 0
    assert out.split()[:2] == ["0", "33333333"]


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["replica", "redwood", "tum", "generic"])
def test_care_run_maps_a_dataset_folder(
    tmp_path: Path, livingroom40, run_cli, save_tiny_clip, layout: str
) -> None:
    """`care run` on a scene folder of each layout: one recording, mapped, not evaluated
    (no ground truth beside it). ScanNet and Matterport3D folders, with their ground truth:
    their own tests. Folders of scene folders: ``test_folder_errors``."""
    import json

    from care_maps.core.frames import Frame

    small = []
    for f in livingroom40[::5]:  # 8 frames at a quarter resolution
        K = f.K.copy()
        K[:2] /= 4
        K[:2, 2] = (f.K[:2, 2] - 1.5) / 4
        rgb, depth = f.rgb[::4, ::4].copy(), f.depth_m[::4, ::4].copy()
        small.append(Frame(f.stamp_ns, rgb, depth, K, f.cam_to_world))
    if layout == "replica":
        scene = layouts.replica(tmp_path / "Replica", small, "room0")
    else:
        scene = getattr(layouts, layout)(tmp_path / "room0", small)
    if layout == "tum":  # frames of another size than the benchmark's Kinects: their camera
        K = small[0].K
        camera = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
        (scene / "intrinsics.json").write_text(json.dumps(camera))
    weights = save_tiny_clip(tmp_path / "tiny-clip", layers=2)
    code, out, err = run_cli(
        "run", scene, "--out", tmp_path / "out", "--encoder", "clip", "--weights", weights,
        "--vocabulary", "chair,sofa,table",
    )  # fmt: skip
    assert code == 0, err
    assert "no ground truth for room0" in out
    store = tmp_path / "out" / "stores" / "room0"
    assert (store / "cells.parquet").is_file()
    assert (store / "instances.parquet").is_file()
    assert Store(store).meta.topics["layout"] == layout
    assert Store(store).num_views == 8
