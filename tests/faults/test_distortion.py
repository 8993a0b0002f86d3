"""Lens distortion in a camera info is removed at ingest, checked against OpenCV's projection.

The undistorted twin is real: five frames of livingroom1_clean_micro (halved to 320x240).
Its distorted twin is made here, independently of ingest's remap tables: every distorted
pixel takes what the pinhole image shows where that pixel's ray lands
(``cv2.undistortPoints`` / ``cv2.fisheye.undistortPoints``, checked against
``cv2.projectPoints`` / ``cv2.fisheye.distortPoints``; colour sampled bilinearly by SciPy,
depth by the nearest pixel). Both go into rosbag2 recordings through rosbags' own Writer and
through ``care ingest``; the distorted one must give the twin's views and the twin's map.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from PIL import Image
from scipy.ndimage import map_coordinates
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from care_maps.core.store import Store
from tests.support.faults import assert_fault, read_meta, tables
from tests.support.messages import camera_info_msg, image_msg, tf_msg
from tests.support.recordings import Stamped, write_bag

W, H = 320, 240
K = np.array([[262.5, 0.0, 159.5], [0.0, 262.5, 119.5], [0.0, 0.0, 1.0]])
"""livingroom1_clean_micro's camera (fx = fy = 525, cx = 319.5, cy = 239.5) at half size."""
FRAMES = (0, 50, 100, 150, 200)
STAMPS = [10**9 + i * 100_000_000 for i in range(len(FRAMES))]
LENSES = {
    "plumb_bob": (-0.4, 0.2, 0.002, -0.001, 0.0),
    "rational_polynomial": (-0.3, 0.1, 0.001, 0.002, 0.0, 0.1, 0.0, 0.0),
    "equidistant": (0.05, -0.02, 0.01, 0.0),
}
ZERO = ("plumb_bob", (0.0,) * 5)
BORDER = 8
"""Pixels left out at the image's edge, where interpolation runs out of neighbours."""
CELL = 0.05
_CONVERGED = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)

# -- the twins -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def twin(shared_data: Path) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(rgb, depth in mm, camera-to-world) of five real frames at 320x240."""
    root = shared_data / "rgbd" / "livingroom1_clean_micro"
    lines = (root / "trajectory.log").read_text().split("\n")
    frames = []
    for i in FRAMES:
        pose = np.array([[float(x) for x in row.split()] for row in lines[5 * i + 1 : 5 * i + 5]])
        rgb = Image.open(root / "image" / f"{i:05d}.jpg").convert("RGB").resize((W, H), Image.BOX)
        depth = np.asarray(Image.open(root / "depth" / f"{i:05d}.png"))[::2, ::2]
        frames.append((np.asarray(rgb), np.ascontiguousarray(depth), pose))
    return frames


def _seen_pixel(model: str, d: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """For every pixel of the distorted image, the pinhole pixel (x, y) its ray lands on."""
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    pixels = np.stack([u, v], -1).reshape(-1, 1, 2)
    dist = np.asarray(d, np.float64)
    if model in ("equidistant", "fisheye"):
        seen = cv2.fisheye.undistortPoints(pixels, K, dist, P=K, criteria=_CONVERGED)
        rays = cv2.undistortPoints(seen, K, None)
        back = cv2.fisheye.distortPoints(rays, K, dist)
    else:
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4 names the iterated form apart
            seen = cv2.undistortPointsIter(pixels, K, dist, None, K, _CONVERGED)
        else:
            seen = cv2.undistortPoints(pixels, K, dist, P=K, criteria=_CONVERGED)
        rays = cv2.convertPointsToHomogeneous(cv2.undistortPoints(seen, K, None))
        back, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, dist)
    # the inverse is exact: projecting what each pixel sees lands on that pixel
    assert np.abs(back.reshape(-1, 2) - pixels.reshape(-1, 2)).max() < 1e-6
    seen = seen.reshape(H, W, 2)
    return seen[..., 0], seen[..., 1]


def _distorted(frames: list, model: str, d: tuple[float, ...]) -> list:
    """The frames as the lens (model, d) would have recorded them; 0 where it sees outside."""
    x, y = _seen_pixel(model, d)
    iy, ix = np.rint(y).astype(int), np.rint(x).astype(int)
    inside = (ix >= 0) & (ix < W) & (iy >= 0) & (iy < H)
    out = []
    for rgb, depth, pose in frames:
        channels = [
            map_coordinates(rgb[..., c].astype(np.float64), [y, x], order=1, cval=0.0)
            for c in range(3)
        ]
        colour = np.clip(np.rint(np.stack(channels, -1)), 0, 255).astype(np.uint8)
        near = depth[iy.clip(0, H - 1), ix.clip(0, W - 1)]
        out.append((colour, np.where(inside, near, 0).astype(np.uint16), pose))
    return out


def _write_bag(path: Path, frames: list, lens: tuple[str, tuple[float, ...]] = ZERO) -> Path:
    """A rosbag2 (mcap storage) of rgb8 colour, 16UC1 depth, camera info with the given
    distortion model and D, and the camera poses on /tf, 100 ms apart."""
    messages: list[Stamped] = []
    for t, (rgb, depth, pose) in zip(STAMPS[: len(frames)], frames, strict=True):
        q = Rotation.from_matrix(pose[:3, :3]).as_quat()
        info = camera_info_msg(t, K, W, H, distortion_model=lens[0], d=lens[1])
        messages += [
            ("/tf", t, tf_msg(t, "map", "camera_optical_frame", pose[:3, 3], q)),
            ("/camera/color/camera_info", t, info),
            ("/camera/color/image_raw", t, image_msg(t, rgb, "rgb8")),
            ("/camera/depth/image_raw", t, image_msg(t, depth, "16UC1")),
        ]
    return write_bag(path, messages)


def _views(store: Path) -> list:
    return [frame for _, frame in Store(store).iter_frames(extras=False, in_map=False)]


def _features(root: Path) -> Path:
    """A precomputed feature file (one constant 4-d cell a view) and its two class names:
    the grid needs features, and the map's geometry is what is compared."""
    path = root / "features.parquet"
    feature = np.array([1.0, 0.0, 0.0, 0.0], np.float16)
    table = pa.table(
        {
            "stamp_ns": pa.array(STAMPS, pa.int64()),
            "fh": [1] * len(STAMPS),
            "fw": [1] * len(STAMPS),
            "feature": pa.array([feature] * len(STAMPS), pa.list_(pa.float16())),
        }
    )
    pq.write_table(table, path)
    text = pa.table({"name": ["thing", "other"], "embedding": [[1.0, 0, 0, 0], [0, 1.0, 0, 0]]})
    pq.write_table(text, root / "features.text.parquet")
    return path


@pytest.fixture(scope="module")
def twin_store(tmp_path_factory: pytest.TempPathFactory, twin: list) -> Path:
    """The undistorted twin ingested (views and constant features) and its grid fused."""
    from care_maps.core.encoders import EncoderOptions
    from care_maps.fuse.grid import GridConfig, build_grid
    from care_maps.ingest.pipeline import IngestConfig, run_ingest
    from care_maps.runtime.execution import Execution

    root = tmp_path_factory.mktemp("distortion_twin")
    store = run_ingest(
        _write_bag(root / "pinhole", twin),
        root / "store",
        IngestConfig(
            encoder="precomputed",
            encoder_options=EncoderOptions(precomputed=_features(root)),
            vocabulary="thing,other",
        ),
        run=Execution(progress=False),
    )
    build_grid(store, GridConfig(cell_size=CELL))
    return store


# -- views ---------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("model", sorted(LENSES))
def test_distorted_views_match_the_undistorted_twin(
    care, twin: list, twin_store: Path, tmp_path: Path, model: str
) -> None:
    lens = (model, LENSES[model])
    recorded = _distorted(twin, *lens)
    bag = _write_bag(tmp_path / "bag", recorded, lens)
    code, _, err = care("ingest", bag, "--out", tmp_path / "store")
    assert code == 0, err
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    for want, got, (raw_rgb, raw_depth, _) in zip(
        _views(twin_store), _views(tmp_path / "store"), recorded, strict=True
    ):
        np.testing.assert_array_equal(got.K, K)  # the stored intrinsics stay K
        colour = np.abs(got.rgb[inner].astype(int) - want.rgb[inner].astype(int)).mean()
        as_recorded = np.abs(raw_rgb[inner].astype(int) - want.rgb[inner].astype(int)).mean()
        assert colour < 4.0, colour
        assert as_recorded > 15.0, as_recorded
        a, b = want.depth_m[inner], got.depth_m[inner]
        both = (a > 0) & (b > 0)
        assert abs(both.mean() - (a > 0).mean()) < 0.01  # the same pixels have depth
        close = (np.abs(a - b)[both] < 0.01).mean()
        r = raw_depth[inner] * 0.001
        close_as_recorded = (np.abs(a - r)[(a > 0) & (r > 0)] < 0.01).mean()
        assert close > 0.93, close
        assert close_as_recorded < 0.7, close_as_recorded
        # depth is picked, never blended: every valid stored depth is one the twin has
        mm = np.rint(got.depth_m[got.depth_m > 0] * 1000)
        assert np.isin(mm, np.rint(want.depth_m * 1000)).all()
    assert read_meta(tmp_path / "store")["distortion"] == [{"model": model, "D": list(lens[1])}]


@pytest.mark.slow
def test_zero_distortion_stores_the_recording_as_it_was(
    care, twin: list, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """All-zero D, whatever the model, stores the same bytes as ingest without any
    undistortion step, and records no distortion."""
    frames = twin[:2]
    stores = {}
    for name, lens in {
        "plumb_bob": ZERO,
        "rational_polynomial": ("rational_polynomial", (0.0,) * 8),
        "equidistant": ("equidistant", (0.0,) * 4),
        "no model": ("", ()),
        "unknown model": ("some_future_model", (0.0,) * 6),
    }.items():
        bag = _write_bag(tmp_path / f"bag {name}", frames, lens)
        code, _, err = care("ingest", bag, "--out", tmp_path / name)
        assert code == 0, err
        assert read_meta(tmp_path / name)["distortion"] == []
        stores[name] = tables(tmp_path / name)["views.parquet"]
    monkeypatch.setattr("care_maps.ingest.source.undistort", lambda image, *_, **__: image)
    code, _, err = care("ingest", tmp_path / "bag plumb_bob", "--out", tmp_path / "no step")
    assert code == 0, err
    assert set(stores.values()) == {tables(tmp_path / "no step")["views.parquet"]}


@pytest.mark.slow
def test_nonzero_distortion_changes_the_store(care, twin: list, tmp_path: Path) -> None:
    frames = twin[:2]
    for name, lens in {"zero": ZERO, "distorted": ("plumb_bob", LENSES["plumb_bob"])}.items():
        code, _, err = care("ingest", _write_bag(tmp_path / name, frames, lens), "--out",
                            tmp_path / f"store {name}")  # fmt: skip
        assert code == 0, err
    zero, distorted = (read_meta(tmp_path / f"store {n}") for n in ("zero", "distorted"))
    assert zero["fingerprint"] != distorted["fingerprint"]
    views = [_views(tmp_path / f"store {n}") for n in ("zero", "distorted")]
    for a, b in zip(*views, strict=True):
        assert not np.array_equal(a.rgb, b.rgb)
        assert not np.array_equal(a.depth_m, b.depth_m)


def test_ros1_camera_info_names_d_in_capitals() -> None:
    from rosbags.typesys import Stores, get_typestore

    from care_maps.ingest import decode

    T = get_typestore(Stores.ROS1_NOETIC).types
    header = T["std_msgs/msg/Header"](
        seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="cam"
    )
    roi = T["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    msg = T["sensor_msgs/msg/CameraInfo"](
        header=header, height=H, width=W, distortion_model="plumb_bob",
        D=np.array(LENSES["plumb_bob"]), K=K.ravel(), R=np.eye(3).ravel(),
        P=np.c_[K, np.zeros(3)].ravel(), binning_x=0, binning_y=0, roi=roi,
    )  # fmt: skip
    assert decode.distortion(msg, "/info") == ("plumb_bob", LENSES["plumb_bob"])


@pytest.mark.slow
def test_unknown_model_with_nonzero_d_is_refused(care, twin: list, tmp_path: Path) -> None:
    bag = _write_bag(tmp_path / "bag", twin[:1], ("kannala_brandt8", (0.1, 0.0, 0.0, 0.0)))
    code, _, err = care("ingest", bag, "--out", tmp_path / "store")
    assert_fault(
        code,
        err,
        r"bag: topic /camera/color/camera_info: camera_info distortion_model "
        r"'kannala_brandt8' with non-zero D .* not supported .*; record rectified images",
        clean=(tmp_path,),
    )
    assert not (tmp_path / "store").exists()


# -- the map -------------------------------------------------------------------------------


def _occupied(store: Path) -> np.ndarray:
    """(N, 2) cell centres (x, y) of the grid map."""
    table = pq.read_table(store / "cells.parquet", columns=["x", "y"])
    return np.c_[table["x"].to_numpy(), table["y"].to_numpy()]


def _within_a_cell(a: np.ndarray, b: np.ndarray) -> float:
    """Share of ``a``'s cells with a cell of ``b`` at most one cell away (the 8 around it)."""
    distance, _ = cKDTree(b).query(a, p=np.inf)
    return float((distance <= CELL * 1.01).mean())


@pytest.mark.slow
@pytest.mark.parametrize("model", ["equidistant", "plumb_bob"])
def test_distorted_recording_gives_the_twins_map(
    care, twin: list, twin_store: Path, tmp_path: Path, model: str
) -> None:
    features = _features(tmp_path)
    recorded = _distorted(twin, model, LENSES[model])
    maps = {}
    # "kept": the distorted images under a zero-D camera info, as ingest stored them before
    for name, lens in {"undistorted": (model, LENSES[model]), "kept": ZERO}.items():
        bag = _write_bag(tmp_path / f"bag {name}", recorded, lens)
        store = tmp_path / name
        code, _, err = care("ingest", bag, "--out", store, "--encoder", "precomputed",
                            "--precomputed", features, "--vocabulary", "thing,other")  # fmt: skip
        assert code == 0, err
        code, _, err = care("fuse", "grid", store, "--cell-size", CELL)
        assert code == 0, err
        maps[name] = _occupied(store)
    twin_map = _occupied(twin_store)
    got = maps["undistorted"]
    assert abs(len(got) - len(twin_map)) <= 0.02 * len(twin_map), (len(got), len(twin_map))
    assert _within_a_cell(twin_map, got) >= 0.995
    assert _within_a_cell(got, twin_map) >= 0.995
    kept = maps["kept"]
    assert (
        abs(len(kept) - len(twin_map)) > 0.05 * len(twin_map)
        or _within_a_cell(twin_map, kept) < 0.97
    )
