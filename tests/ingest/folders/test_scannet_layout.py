"""ScanNet's exported frames: the living-room frames laid out as ScanNet's SensReader
exports a scene (``SensReader/python/SensorData.py``), read back by the ScanNet layout.

The writer follows the exporter: colour as 1296x968 JPEG (``imageio.imwrite``'s default
quality, 75) named by the .sens frame index, depth as 16-bit millimetre PNG at 640x480,
``pose/<i>.txt`` and the 4x4 intrinsics written row by row with ``np.savetxt(fmt="%f")``,
a lost pose as ``-inf`` in every entry. The colour camera is the living room's scaled to
1296x968 (pixel centres kept), so resampling it into the depth camera must give back the
living room's own image, pixel for pixel up to the JPEG's loss.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.ndimage import shift as shift_image

from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame
from care_maps.core.store import Store, read_table
from care_maps.evaluate.groundtruth import GtSource, gt_files
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.ingest.folders import LAYOUTS
from care_maps.ingest.folders.base import DatasetLayout
from care_maps.ingest.folders.frames import FolderFrames
from care_maps.ingest.folders.scannet import ScanNetLayout, colour_in_depth_camera
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.write import write_recording
from care_maps.runtime.execution import Execution
from care_maps.truth.load import GtFormat
from tests.support.encoders import TinyEncoder
from tests.support.frames import load_livingroom

SCENE = "scene0000_00"
COLOUR_SIZE = (1296, 968)
"""ScanNet's colour resolution (width, height)."""
SKIP = 10
"""Exported with a frame skip: the files are named 0, 10, 20, ... (the .sens indices)."""
LOST = 2
"""The view whose pose is written as lost (-inf)."""
N = 6
QUIET = Execution(progress=False)


def _savetxt(path: Path, matrix: np.ndarray) -> None:
    """As SensorData.save_mat_to_file: each row through ``np.savetxt(fmt='%f')``."""
    with path.open("w") as fh:
        for row in matrix:
            np.savetxt(fh, row[np.newaxis], fmt="%f")


def colour_camera(K: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """The 640x480 camera ``K`` scaled to ``size`` with pixel centres kept: pixel u of the
    small image spans [u, u + 1) of its width, so its centre u + 0.5 lands at
    (u + 0.5) * s, i.e. c' = (c + 0.5) * s - 0.5 and f' = f * s."""
    sx, sy = size[0] / 640, size[1] / 480
    return np.array([
        [K[0, 0] * sx, 0.0, (K[0, 2] + 0.5) * sx - 0.5],
        [0.0, K[1, 1] * sy, (K[1, 2] + 0.5) * sy - 0.5],
        [0.0, 0.0, 1.0],
    ])  # fmt: skip


def write_export(folder: Path, frames: list[Frame]) -> Path:
    """``frames`` as SensReader's export of one scene into ``folder``."""
    for name in ("color", "depth", "pose", "intrinsic"):
        (folder / name).mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        index = i * SKIP
        big = Image.fromarray(f.rgb).resize(COLOUR_SIZE, Image.Resampling.BICUBIC)
        big.save(folder / "color" / f"{index}.jpg", quality=75)
        mm = np.round(f.depth_m.astype(np.float64) * 1000).astype(np.uint16)
        Image.fromarray(mm).save(folder / "depth" / f"{index}.png")
        pose = np.full((4, 4), -np.inf) if i == LOST else f.cam_to_world
        _savetxt(folder / "pose" / f"{index}.txt", pose)
    K4 = np.eye(4)
    K4[:3, :3] = frames[0].K
    _savetxt(folder / "intrinsic" / "intrinsic_depth.txt", K4)
    K4[:3, :3] = colour_camera(frames[0].K, COLOUR_SIZE)
    _savetxt(folder / "intrinsic" / "intrinsic_color.txt", K4)
    for name in ("extrinsic_color.txt", "extrinsic_depth.txt"):
        _savetxt(folder / "intrinsic" / name, np.eye(4))
    return folder


@pytest.fixture(scope="module")
def living(livingroom_root: Path) -> list[Frame]:
    return load_livingroom(livingroom_root, 3 * N)[::3]


@pytest.fixture(scope="module")
def scene(living: list[Frame], tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_export(tmp_path_factory.mktemp("scans") / SCENE, living)


def test_detected_as_scannet_only(scene: Path) -> None:
    layouts = {**LAYOUTS, DatasetLayout.SCANNET: ScanNetLayout}
    assert {kind for kind, cls in layouts.items() if cls.detect(scene)} == {DatasetLayout.SCANNET}


def test_views_skip_the_lost_pose_and_are_stamped_by_frame_index(scene: Path) -> None:
    layout = ScanNetLayout(scene, max_dt=0.02)
    views = layout.views()
    indices = [i * SKIP for i in range(N) if i != LOST]
    assert [v.colour.name for v in views] == [f"{i}.jpg" for i in indices]
    assert layout.dropped == Counter(no_pose=1)
    for view, index in zip(views, indices, strict=True):
        assert abs(view.stamp_ns - index * 1e9 / 30) < 1_000  # 30 Hz, within a microsecond


def test_frames_equal_the_living_room(scene: Path, living: list[Frame]) -> None:
    layout = ScanNetLayout(scene, max_dt=0.02)
    kept = [f for i, f in enumerate(living) if i != LOST]
    for view, ref in zip(layout.views(), kept, strict=True):
        frame = layout.load(view)
        np.testing.assert_allclose(frame.cam_to_world, ref.cam_to_world, rtol=0, atol=1e-6)
        np.testing.assert_allclose(frame.depth_m, ref.depth_m, rtol=0, atol=1e-6)
        np.testing.assert_allclose(frame.K, ref.K, rtol=0, atol=1e-6)
        assert frame.rgb.shape == ref.rgb.shape
        assert frame.rgb.dtype == np.uint8


def test_colour_lands_on_the_living_room_pixels(scene: Path, living: list[Frame]) -> None:
    """Upscaled, JPEG-coded and resampled back, the colour differs from the living room's
    by the coding loss only, and is centred on it: the parabola through the errors against
    the living room shifted by -0.5, 0 and +0.5 pixels has its vertex within 0.05 pixels of
    zero along each axis (a registration off by half a scaled pixel would put it near
    0.25; interpolating the shifted image blurs it alike on both sides)."""
    layout = ScanNetLayout(scene, max_dt=0.02)
    frame = layout.load(layout.views()[0])
    ref = living[0].rgb.astype(np.float64)
    got = frame.rgb.astype(np.float64)
    crop = (slice(4, -4), slice(4, -4))

    def error(dx: float, dy: float) -> float:
        moved = shift_image(ref, (dy, dx, 0), order=1, mode="nearest")
        return float(np.abs(got - moved)[crop].mean())

    at_zero, h = error(0.0, 0.0), 0.5
    assert at_zero < 4.0
    for axis in ((1, 0), (0, 1)):
        minus, plus = error(-h * axis[0], -h * axis[1]), error(h * axis[0], h * axis[1])
        vertex = h * (minus - plus) / (2 * (minus - 2 * at_zero + plus))
        assert abs(vertex) < 0.05, (axis, vertex)


def test_colour_through_both_intrinsics() -> None:
    """ScanNet's own calibrations (scene0709_00.txt: colour fx 1170.19 at 1296x968, depth fx
    571.62 at 640x480) are not proportional: the colour pixel of a depth ray is found through
    both. A colour image that is a function of the ray direction, g(x/z, y/z), must come out
    as the same function of the depth camera's rays; the depth camera's wider view reaches
    past the colour image's edge, and those pixels are marked outside."""
    Kc = np.array([[1170.19, 0, 647.75], [0, 1170.19, 483.75], [0, 0, 1]])
    Kd = np.array([[571.62, 0, 319.5], [0, 571.62, 239.5], [0, 0, 1]])

    def pattern(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.stack(
            [128 + 100 * np.sin(3 * x), 128 + 100 * np.cos(2 * y), 128 + 60 * x * y], -1
        )

    vc, uc = np.mgrid[0:968, 0:1296].astype(np.float64)
    colour = pattern((uc - Kc[0, 2]) / Kc[0, 0], (vc - Kc[1, 2]) / Kc[1, 1])
    rgb, inside = colour_in_depth_camera(np.round(colour).astype(np.uint8), Kc, Kd, 640, 480)
    vd, ud = np.mgrid[0:480, 0:640].astype(np.float64)
    want = pattern((ud - Kd[0, 2]) / Kd[0, 0], (vd - Kd[1, 2]) / Kd[1, 1])
    # hand-worked: depth column u sees colour column 2.04715 u - 6.314, inside [-0.5, 1295.5]
    # for u in 3..635; row v sees colour row 2.04715 v - 6.541, inside [-0.5, 967.5] for 3..475
    columns = np.zeros(640, bool)
    columns[3:636] = True
    rows = np.zeros(480, bool)
    rows[3:476] = True
    np.testing.assert_array_equal(inside, rows[:, None] & columns[None, :])
    diff = np.abs(rgb.astype(np.float64) - want)[5:-5, 8:-8]
    assert diff.max() < 3.0


def test_missing_intrinsics_and_resized_colour_are_refused(
    living: list[Frame], tmp_path: Path
) -> None:
    folder = write_export(tmp_path / SCENE, living[:2])
    (folder / "intrinsic" / "intrinsic_depth.txt").unlink()
    with pytest.raises(IngestError, match=r"intrinsic_depth\.txt: missing.*--export_intrinsics"):
        ScanNetLayout(folder, max_dt=0.02).views()
    folder = write_export(tmp_path / "resized", living[:2])
    Image.fromarray(living[0].rgb).save(folder / "color" / "0.jpg")  # 640x480, not 1296x968
    layout = ScanNetLayout(folder, max_dt=0.02)
    with pytest.raises(IngestError, match=r"0\.jpg: 640x480 image, but intrinsic/intrinsic_color"):
        layout.load(layout.views()[0])


def write_annotation(folder: Path, points: np.ndarray, labels: dict[int, str]) -> None:
    """A ScanNet annotation as the dataset ships it (README, "Data Organization"): a
    vertex-only ``_vh_clean_2.ply``, its over-segmentation (one segment per object, segment
    0 the rest) and the aggregation naming each segment group's label."""
    from plyfile import PlyData, PlyElement

    vertex = np.zeros(len(points), [("x", "f4"), ("y", "f4"), ("z", "f4")])
    vertex["x"], vertex["y"], vertex["z"] = points.T
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(folder / f"{SCENE}_vh_clean_2.ply"))
    segments = np.zeros(len(points), np.int64)
    for seg in labels:
        segments[seg * 10 : seg * 10 + 10] = seg
    segs = {"params": {"kThresh": "0.0001"}, "sceneId": SCENE, "segIndices": segments.tolist()}
    (folder / f"{SCENE}_vh_clean_2.0.010000.segs.json").write_text(json.dumps(segs))
    groups = [
        {"id": n, "objectId": n, "segments": [seg], "label": name}
        for n, (seg, name) in enumerate(labels.items())
    ]
    agg = {"sceneId": f"scannet.{SCENE}", "segGroups": groups}
    (folder / f"{SCENE}.aggregation.json").write_text(json.dumps(agg))


def test_ground_truth_is_found_in_the_scene_folder(living: list[Frame], tmp_path: Path) -> None:
    """The export written into the downloaded scene folder: the scan's annotation beside the
    frames is the recording's ground truth, read from its three files only (not the frames,
    not the multi-gigabyte .sens beside them)."""
    folder = write_export(tmp_path / SCENE, living[:2])
    source = GtSource()
    assert not source.available(folder)
    points = np.random.default_rng(0).uniform(-1, 1, (40, 3))
    write_annotation(folder, points, {1: "chair", 2: "sofa"})
    (folder / f"{SCENE}.sens").write_bytes(b"\0" * 64)
    assert source.available(folder)
    assert source.resolve(folder) == (folder / f"{SCENE}.aggregation.json", GtFormat.SCANNET)
    gt = source.load(folder)
    assert sorted(gt.instances.column("class_name").to_pylist()) == ["chair", "sofa"]
    names = sorted(p.name for p in gt_files(source, folder))
    assert names == sorted(
        f"{SCENE}{s}"
        for s in ("_vh_clean_2.ply", "_vh_clean_2.0.010000.segs.json", ".aggregation.json")
    )


def _cells(store: Path) -> set[tuple[int, int]]:
    table = read_table(store / "cells.parquet", ["ix", "iy"])
    return set(zip(table.column("ix").to_pylist(), table.column("iy").to_pylist(), strict=True))


@pytest.mark.slow
def test_the_scene_folder_gives_the_bags_grid(
    scene: Path, living: list[Frame], tmp_path: Path
) -> None:
    """Ingested as a folder, the scene has the views and poses of the same frames written as
    an MCAP bag (the lost one left out), and the same grid within 1% of its cells."""
    kept = [f for i, f in enumerate(living) if i != LOST]
    sources = {"bag": write_recording(tmp_path / "rec.mcap", kept, fmt="mcap"), "scannet": scene}
    stores = {}
    for name, source in sources.items():
        config = IngestConfig(vocabulary="red,green,blue")
        stores[name] = run_ingest(source, tmp_path / name, config, run=QUIET, encoder=TinyEncoder())
        build_grid(stores[name], GridConfig(cell_size=0.05, stride=2), run=QUIET)
    store = Store(stores["scannet"])
    assert store.meta.topics["layout"] == "scannet"
    assert store.meta.world_frame == "scannet_world"
    poses = {
        name: np.stack(
            [f.cam_to_world for _, f in Store(s).iter_frames(extras=False, in_map=False)]
        )
        for name, s in stores.items()
    }
    np.testing.assert_allclose(poses["scannet"], poses["bag"], rtol=0, atol=1e-6)
    ours, bag = _cells(stores["scannet"]), _cells(stores["bag"])
    assert len(ours ^ bag) <= 0.01 * len(bag), (len(ours), len(bag), len(ours ^ bag))


@pytest.mark.slow
def test_care_run_evaluates_a_scannet_scene_folder(
    living: list[Frame], tmp_path: Path, run_cli, save_tiny_clip
) -> None:
    """`care run` on a downloaded scene folder holding the export and the scan's annotation:
    the frames are mapped and the annotation beside them evaluates the maps. The annotated
    objects are the world points of the first view's left and right thirds."""
    folder = write_export(tmp_path / "scans" / SCENE, living)
    first = living[0]
    v, u = np.mgrid[0 : first.height : 8, 0 : first.width : 8]
    z = first.depth_m[v, u].astype(np.float64)
    ok = z > 0
    u, v, z = u[ok], v[ok], z[ok]
    K, T = first.K, first.cam_to_world
    cam = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])
    world = (T[:3, :3] @ cam).T + T[:3, 3]
    segment = np.where(u < first.width / 3, 1, np.where(u > 2 * first.width / 3, 2, 0))
    write_annotation(folder, world[np.argsort(segment, kind="stable")], {})
    segs = {"params": {}, "sceneId": SCENE, "segIndices": np.sort(segment).tolist()}
    (folder / f"{SCENE}_vh_clean_2.0.010000.segs.json").write_text(json.dumps(segs))
    groups = [{"id": 0, "objectId": 0, "segments": [1], "label": "chair"},
              {"id": 1, "objectId": 1, "segments": [2], "label": "sofa"}]  # fmt: skip
    agg = {"sceneId": f"scannet.{SCENE}", "segGroups": groups}
    (folder / f"{SCENE}.aggregation.json").write_text(json.dumps(agg))
    weights = save_tiny_clip(tmp_path / "tiny-clip", layers=2)
    code, out, err = run_cli(
        "run", folder, "--out", tmp_path / "out", "--encoder", "clip", "--weights", weights,
        "--vocabulary", "chair,sofa,table", "--workers", "1",
    )  # fmt: skip
    assert code == 0, err
    assert "no ground truth" not in out
    results = (tmp_path / "out" / "eval" / "results.md").read_text()
    assert "ground truth: scannet" in results
    assert (
        "subgoal success (%), protocol `exclude-1m` (2 queries)" in results
    )  # chair and sofa, in the map frame
    assert Store(tmp_path / "out" / "stores" / SCENE).meta.topics["layout"] == "scannet"


def test_depth_outside_the_colour_view_is_counted(living: list[Frame], tmp_path: Path) -> None:
    """Depth pixels whose ray leaves the colour image are zeroed and counted as
    ``outside_colour_view``, the count equal to one made here: every valid depth pixel
    back-projected through the depth camera and projected through a colour camera 15%
    narrower (ScanNet's own two calibrations differ so), outside the colour image's pixel
    edges. The colour and depth cameras share the viewpoint (identity extrinsics)."""
    folder = write_export(tmp_path / SCENE, living[:3])
    K4 = np.eye(4)
    K4[:3, :3] = colour_camera(living[0].K, COLOUR_SIZE)
    K4[0, 0] *= 1.15
    K4[1, 1] *= 1.15
    _savetxt(folder / "intrinsic" / "intrinsic_color.txt", K4)
    Kd_inv = np.linalg.inv(living[0].K)
    expected = valid_total = 0
    for i, f in enumerate(living[:3]):
        if i == LOST:
            continue
        mm = np.round(f.depth_m.astype(np.float64) * 1000)  # as exported
        v, u = np.nonzero(mm > 0)
        rays = Kd_inv @ np.stack([u, v, np.ones_like(u)]).astype(np.float64)
        seen = K4[:3, :3] @ rays
        uc, vc = seen[0] / seen[2], seen[1] / seen[2]
        inside = (uc >= -0.5) & (uc <= COLOUR_SIZE[0] - 0.5)
        inside &= (vc >= -0.5) & (vc <= COLOUR_SIZE[1] - 0.5)
        expected += int((~inside).sum())
        valid_total += len(u)
    with FolderFrames(folder) as opened:
        got = list(opened)
        lost = dict(opened.stats.lost_pixels)
        counts = opened.stats.as_dict()
    assert len(got) == 2
    assert lost == {"outside_colour_view": expected}
    assert counts["lost_pixels"] == {"outside_colour_view": expected}
    assert 0.1 * valid_total < expected < 0.5 * valid_total
    assert sum(int((f.depth_m > 0).sum()) for f in got) == valid_total - expected
