"""Matterport3D's undistorted frames: the living-room frames laid out as one house of the
download (``data_organization.md`` of github.com/niessner/Matterport), read back by the
Matterport layout.

The writer follows the dataset: three cameras (the living-room frames cropped at three
offsets, so each has its own principal point) with one ``intrinsics_matrix`` line before
each camera's ``scan`` lines, images named ``<panorama>_i<camera>_<yaw>.jpg`` and
``_d<camera>_<yaw>.png``, depth in 0.25 mm units, and the conf's conventions worked out by
hand here: the pose of a camera looking along -z with y up (the optical pose times
``diag(1, -1, -1, 1)``), the principal point in image coordinates from the bottom-left
corner with pixel centres at ``i + 0.5``.
"""

from __future__ import annotations

import enum
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from care_maps.core.errors import IngestError
from care_maps.core.frames import Frame
from care_maps.core.store import Store, read_table
from care_maps.evaluate.groundtruth import GtSource, gt_files
from care_maps.fuse.grid import GridConfig, build_grid
from care_maps.ingest.folders import LAYOUTS
from care_maps.ingest.folders.base import DatasetLayout
from care_maps.ingest.folders.matterport import MatterportLayout
from care_maps.ingest.pipeline import IngestConfig, run_ingest
from care_maps.ingest.write import write_recording
from care_maps.runtime.execution import Execution
from care_maps.truth.formats.common import from_labelled_points
from care_maps.truth.formats.matterport import write_matterport
from care_maps.truth.load import GtFormat
from tests.support.encoders import TinyEncoder
from tests.support.frames import load_livingroom

HOUSE = "17DRP5sb8fy"
COLOUR, DEPTH, CAMERAS = (
    "undistorted_color_images", "undistorted_depth_images", "undistorted_camera_parameters",
)  # fmt: skip
CROP = ((0, 0), (12, 4), (24, 10))
"""(dx, dy) crop offset of each camera's images in the living-room frames."""
MARGIN = 24
"""Pixels cropped off each image's width and height (all cameras' images share one size)."""
YAWS = 2
"""Views of each camera per panorama (the scanner turns to 6 yaws; fewer suffice here)."""
N = 12
QUIET = Execution(progress=False)


class Unzip(enum.Enum):
    """Where ``unzip`` leaves a type's files (``<house>/<type>.zip`` holds ``<house>/<type>/``)."""

    FLAT = "house/type"
    IN_PLACE = "house/house/type"
    PER_TYPE = "house/type/house/type"


def type_folder(house: Path, name: str, unzip: Unzip) -> Path:
    return {
        Unzip.FLAT: house / name,
        Unzip.IN_PLACE: house / HOUSE / name,
        Unzip.PER_TYPE: house / name / HOUSE / name,
    }[unzip]


def view_name(i: int) -> tuple[str, int, int]:
    """``(panorama uuid, camera, yaw)`` of view ``i``: each panorama takes every camera's
    yaws in turn, as the conf lists them."""
    panorama, rest = divmod(i, 3 * YAWS)
    return f"{panorama:032x}", rest // YAWS, rest % YAWS


def camera_K(K: np.ndarray, camera: int) -> np.ndarray:
    """The living-room camera on images cropped at ``CROP[camera]``."""
    dx, dy = CROP[camera]
    out = K.copy()
    out[0, 2] -= dx
    out[1, 2] -= dy
    return out


def cropped(image: np.ndarray, camera: int, height: int, width: int) -> np.ndarray:
    dx, dy = CROP[camera]
    return image[dy : dy + height, dx : dx + width]


def write_house(root: Path, frames: list[Frame], unzip: Unzip = Unzip.FLAT) -> Path:
    """``frames`` as the undistorted frames of one house under ``root / HOUSE``."""
    house = root / HOUSE
    folders = {name: type_folder(house, name, unzip) for name in (COLOUR, DEPTH, CAMERAS)}
    for folder in folders.values():
        folder.mkdir(parents=True)
    height, width = frames[0].height - MARGIN, frames[0].width - MARGIN
    lines = [
        "dataset matterport", f"n_images {len(frames)}",
        "depth_directory undistorted_depth_images", "color_directory undistorted_color_images", "",
    ]  # fmt: skip
    last_camera = None
    for i, f in enumerate(frames):
        uuid, camera, yaw = view_name(i)
        if camera != last_camera:
            K = camera_K(f.K, camera)
            cx, cy = K[0, 2] + 0.5, height - 0.5 - K[1, 2]  # bottom-left origin, centres at +0.5
            lines.append(f"intrinsics_matrix {K[0, 0]} 0 {cx}  0 {K[1, 1]} {cy}  0 0 1")
            last_camera = camera
        colour, depth = f"{uuid}_i{camera}_{yaw}.jpg", f"{uuid}_d{camera}_{yaw}.png"
        rgb = cropped(f.rgb, camera, height, width)
        Image.fromarray(rgb).save(folders[COLOUR] / colour, quality=95)
        metres = cropped(f.depth_m, camera, height, width).astype(np.float64)
        Image.fromarray(np.round(metres * 4000).astype(np.uint16)).save(folders[DEPTH] / depth)
        opengl = f.cam_to_world @ np.diag([1.0, -1.0, -1.0, 1.0])  # view -z, up +y
        lines.append(f"scan {depth} {colour} " + " ".join(f"{v:.12g}" for v in opengl.ravel()))
    (folders[CAMERAS] / f"{HOUSE}.conf").write_text("\n".join(lines) + "\n")
    return house


@pytest.fixture(scope="module")
def living(livingroom_root: Path) -> list[Frame]:
    return load_livingroom(livingroom_root, 2 * N)[::2]


@pytest.fixture(scope="module")
def house(living: list[Frame], tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_house(tmp_path_factory.mktemp("scans"), living)


def test_detected_as_matterport_only(house: Path) -> None:
    layouts = {**LAYOUTS, DatasetLayout.MATTERPORT: MatterportLayout}
    assert {k for k, cls in layouts.items() if cls.detect(house)} == {DatasetLayout.MATTERPORT}


def test_views_in_conf_order_one_second_apart(house: Path) -> None:
    layout = MatterportLayout(house, max_dt=0.02)
    views = layout.views()
    want = [f"{u}_i{c}_{y}.jpg" for u, c, y in map(view_name, range(N))]
    assert [v.colour.name for v in views] == want
    assert [v.stamp_ns for v in views] == [i * 10**9 for i in range(N)]
    assert layout.dropped == Counter()


def _world_points(frame: Frame, pixels: np.ndarray) -> np.ndarray:
    """World points of ``pixels`` (rows of u, v) through the frame's K, depth and pose."""
    u, v = pixels.T
    z = frame.depth_m[v, u].astype(np.float64)
    K = frame.K
    cam = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])
    return (frame.cam_to_world[:3, :3] @ cam).T + frame.cam_to_world[:3, 3]


@pytest.mark.parametrize("unzip", list(Unzip))
def test_frames_equal_the_living_room(living: list[Frame], tmp_path: Path, unzip: Unzip) -> None:
    house = write_house(tmp_path, living, unzip)
    layout = MatterportLayout(house, max_dt=0.02)
    assert layout.detect(house)
    height, width = living[0].height - MARGIN, living[0].width - MARGIN
    w, h = width - 1, height - 1
    pixels = np.array([[0, 0], [w, 0], [17, h], [300, 200], [w, h]])
    for i, (view, ref) in enumerate(zip(layout.views(), living, strict=True)):
        camera = view_name(i)[1]
        frame = layout.load(view)
        np.testing.assert_allclose(frame.cam_to_world, ref.cam_to_world, rtol=0, atol=1e-6)
        np.testing.assert_allclose(frame.K, camera_K(ref.K, camera), rtol=0, atol=1e-9)
        want = cropped(ref.depth_m, camera, height, width)
        np.testing.assert_allclose(frame.depth_m, want, rtol=0, atol=1.25e-4)  # half of 0.25 mm
        rgb = cropped(ref.rgb, camera, height, width).astype(np.float64)
        assert np.abs(frame.rgb.astype(np.float64) - rgb).mean() < 3.0
        # the same pixel lands on the same world point as in the uncropped living-room frame
        uncropped = pixels + np.array(CROP[camera])
        np.testing.assert_allclose(
            _world_points(frame, pixels), _world_points(ref, uncropped), rtol=0, atol=1e-5
        )


def test_a_pixel_lands_where_matterports_own_code_puts_it(house: Path) -> None:
    """The ray of a pixel as Matterport's GAPS code casts it (``RGBDImage::PixelWorldRay``):
    image position (ix + 0.5, iy + 0.5) with iy counted from the bottom row, camera point
    ((x - cx) / fx, (y - cy) / fy, -1) taken to the world by the conf's matrix; scaled to the
    pixel's z distance it is the point our frame gives for that pixel."""
    layout = MatterportLayout(house, max_dt=0.02)
    view = layout.views()[8]
    frame = layout.load(view)
    conf = next(house.glob(f"{CAMERAS}/*.conf")).read_text().splitlines()
    intrinsics = [line for line in conf if line.startswith("intrinsics_matrix")]
    fx, _, cx, _, fy, cy = (float(v) for v in intrinsics[view_name(8)[1]].split()[1:7])
    scan = next(line for line in conf if view.colour.name in line)
    M = np.array([float(v) for v in scan.split()[3:]]).reshape(4, 4)
    height = frame.depth_m.shape[0]
    for u, v in ((5, 7), (400, 300), (100, height - 3)):
        iy = height - 1 - v
        z = float(frame.depth_m[v, u])
        gaps = M @ np.array([(u + 0.5 - cx) / fx * z, (iy + 0.5 - cy) / fy * z, -z, 1.0])
        np.testing.assert_allclose(_world_points(frame, np.array([[u, v]]))[0], gaps[:3], atol=1e-9)


def test_broken_conf_and_missing_depth(living: list[Frame], tmp_path: Path) -> None:
    house = write_house(tmp_path / "a", living[:6])
    conf = house / CAMERAS / f"{HOUSE}.conf"
    next(house.glob(f"{DEPTH}/*_d1_0.png")).unlink()
    layout = MatterportLayout(house, max_dt=0.02)
    assert len(layout.views()) == 5
    assert layout.dropped == Counter(no_depth=1)
    lines = conf.read_text().splitlines()
    conf.write_text("\n".join(lines[:-1]) + "\n")  # a truncated copy
    with pytest.raises(IngestError, match=r"line 2 declares 6 images but the file has 5 scan"):
        MatterportLayout(house, max_dt=0.02).views()
    conf.write_text("\n".join(line for line in lines if not line.startswith("intrinsics")) + "\n")
    with pytest.raises(IngestError, match=r"a scan before any intrinsics_matrix line"):
        MatterportLayout(house, max_dt=0.02).views()


@pytest.mark.parametrize("unzip", list(Unzip))
def test_ground_truth_is_found_in_the_house(
    living: list[Frame], tmp_path: Path, unzip: Unzip
) -> None:
    """The house's region segmentations beside its undistorted frames, unzipped as those
    are, are the recording's ground truth, read from the segmentation files only (not the
    images beside them)."""
    house = write_house(tmp_path, living[:6], unzip)
    source = GtSource()
    assert not source.available(house)
    points = np.random.default_rng(0).uniform(-1, 1, (30, 3))
    instance = np.repeat([0, 1, 2], 10)
    gt = from_labelled_points(points, instance, {1: "chair", 2: "sofa"}, path=house, frame="m")
    root = type_folder(house, "region_segmentations", unzip).parent
    written = write_matterport(gt, root, HOUSE)
    assert source.available(house)
    assert source.resolve(house) == (root, GtFormat.MATTERPORT)
    names = source.load(house).instances.column("class_name").to_pylist()
    assert sorted(names) == ["chair", "sofa"]
    assert sorted(gt_files(source, house)) == sorted(written)


def _as_cropped(frames: list[Frame]) -> list[Frame]:
    """The frames each camera of :func:`write_house` sees: cropped, with their own K."""
    height, width = frames[0].height - MARGIN, frames[0].width - MARGIN
    out = []
    for i, f in enumerate(frames):
        camera = view_name(i)[1]
        rgb = np.ascontiguousarray(cropped(f.rgb, camera, height, width))
        depth = np.ascontiguousarray(cropped(f.depth_m, camera, height, width))
        out.append(Frame(i * 10**9, rgb, depth, camera_K(f.K, camera), f.cam_to_world))
    return out


def _cells(store: Path) -> set[tuple[int, int]]:
    table = read_table(store / "cells.parquet", ["ix", "iy"])
    return set(zip(table.column("ix").to_pylist(), table.column("iy").to_pylist(), strict=True))


@pytest.mark.slow
def test_the_house_gives_the_bags_grid(house: Path, living: list[Frame], tmp_path: Path) -> None:
    """Ingested as a folder, the house has the views and poses of its cropped frames written
    as an MCAP bag, and the same grid within 1% of its cells."""
    bag = write_recording(tmp_path / "rec.mcap", _as_cropped(living), fmt="mcap")
    stores = {}
    for name, source in (("bag", bag), ("matterport", house)):
        config = IngestConfig(vocabulary="red,green,blue")
        stores[name] = run_ingest(source, tmp_path / name, config, run=QUIET, encoder=TinyEncoder())
        build_grid(stores[name], GridConfig(cell_size=0.05, stride=2), run=QUIET)
    assert Store(stores["matterport"]).meta.topics["layout"] == "matterport"
    poses = {
        name: np.stack(
            [f.cam_to_world for _, f in Store(s).iter_frames(extras=False, in_map=False)]
        )
        for name, s in stores.items()
    }
    np.testing.assert_allclose(poses["matterport"], poses["bag"], rtol=0, atol=1e-6)
    ours, bag_cells = _cells(stores["matterport"]), _cells(stores["bag"])
    assert len(ours ^ bag_cells) <= 0.01 * len(bag_cells), (len(ours), len(bag_cells))


@pytest.mark.slow
def test_care_run_evaluates_a_matterport_house(
    living: list[Frame], tmp_path: Path, run_cli, save_tiny_clip
) -> None:
    """`care run` on a house holding its undistorted frames and region segmentations: the
    segmentations (two objects: the world points of the first view's left and right thirds)
    evaluate the maps, in the map frame."""
    house = write_house(tmp_path / "scans", living)
    first = living[0]
    v, u = np.mgrid[0 : first.height : 8, 0 : first.width : 8]
    z = first.depth_m[v, u].astype(np.float64)
    u, v, z = u[z > 0], v[z > 0], z[z > 0]
    K, T = first.K, first.cam_to_world
    cam = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])
    world = (T[:3, :3] @ cam).T + T[:3, 3]
    instance = np.where(u < first.width / 3, 1, np.where(u > 2 * first.width / 3, 2, 0))
    gt = from_labelled_points(world, instance, {1: "chair", 2: "sofa"}, path=house, frame="m")
    write_matterport(gt, house, HOUSE)
    weights = save_tiny_clip(tmp_path / "tiny-clip", layers=2)
    code, out, err = run_cli(
        "run", house, "--out", tmp_path / "out", "--encoder", "clip", "--weights", weights,
        "--vocabulary", "chair,sofa,table", "--workers", "1",
    )  # fmt: skip
    assert code == 0, err
    assert "no ground truth" not in out
    results = (tmp_path / "out" / "eval" / "results.md").read_text()
    assert "ground truth: matterport" in results
    assert "subgoal success (%), protocol `exclude-1m` (2 queries)" in results
