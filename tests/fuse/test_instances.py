"""The instance map end to end on a tiny rendered room (open3d ray casting as the renderer).

The room: a 3 x 3 m floor, four 2.4 m walls and three boxes of known classes. Views are
rendered with :class:`open3d.t.geometry.RaycastingScene` (depth, instance and class ids,
shaded colours); the dense features are one-hot class vectors plus noise, so the true
class of each box is known and every measure has something to measure. Ground truth for
the scene points comes from the same meshes (closest triangle within a few cm).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import duckdb
import numpy as np
import open3d as o3d
import polars as pl
import pytest

from care_maps.core.encoders.base import Encoder, RecordingContext
from care_maps.core.errors import FuseError
from care_maps.core.frames import Frame
from care_maps.core.store import EncoderInfo, Store, StoreWriter, read_table
from care_maps.core.viz import rrd_entity_counts
from care_maps.fuse.evaluate_proposals import best_iou, instance_map_iou
from care_maps.fuse.instances import InstanceConfig, build_instances, recompute_instances
from care_maps.fuse.measures import class_distribution, entropy, pwkl_pairwise
from care_maps.fuse.pointcloud import VoxelAccumulator, fuse_scene_points, read_scene_points
from care_maps.fuse.proposals import label_proposals
from care_maps.runtime.execution import Execution

CLASSES = ["void", "wall", "floor", "chair", "table", "bed"]
# (min corner, max corner, class id); instance id = index + 1
BOXES = [
    ((0.3, 0.3, 0.0), (0.8, 0.9, 0.6), 3),
    ((-1.0, 0.2, 0.0), (-0.4, 0.7, 0.9), 4),
    ((0.1, -1.1, 0.0), (0.8, -0.5, 0.45), 5),
]
BASE_COLOURS = {
    1: (200, 200, 190),
    2: (120, 90, 60),
    3: (220, 40, 40),
    4: (40, 200, 40),
    5: (40, 40, 220),
}
W, H, F = 120, 90, 80.0
FH, FW, DIM = 15, 20, 8
VOXEL = 0.04


def _box_mesh(lo: Sequence[float], hi: Sequence[float]) -> o3d.t.geometry.TriangleMesh:
    size = np.subtract(hi, lo)
    mesh = o3d.geometry.TriangleMesh.create_box(*size)
    mesh.translate(lo)
    return o3d.t.geometry.TriangleMesh.from_legacy(mesh)


def _scene() -> tuple[o3d.t.geometry.RaycastingScene, dict[int, tuple[int, int]]]:
    """The raycasting scene and geometry id -> (instance id, class id)."""
    scene = o3d.t.geometry.RaycastingScene()
    ids: dict[int, tuple[int, int]] = {}
    structure = [
        ((-1.5, -1.5, -0.05), (1.5, 1.5, 0.0), 2),
        ((-1.55, -1.5, 0.0), (-1.5, 1.5, 2.4), 1),
        ((1.5, -1.5, 0.0), (1.55, 1.5, 2.4), 1),
        ((-1.5, -1.55, 0.0), (1.5, -1.5, 2.4), 1),
        ((-1.5, 1.5, 0.0), (1.5, 1.55, 2.4), 1),
    ]
    for lo, hi, cls in structure:
        ids[scene.add_triangles(_box_mesh(lo, hi))] = (0, cls)
    for i, (lo, hi, cls) in enumerate(BOXES):
        ids[scene.add_triangles(_box_mesh(lo, hi))] = (i + 1, cls)
    return scene, ids


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Optical-frame camera-to-world pose (x right, y down, z forward), world z up."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def _render(scene, ids, pose: np.ndarray, K: np.ndarray, stamp: int) -> Frame:
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, float)], -1)
    d_world = d_cam @ pose[:3, :3].T
    rays = np.concatenate([np.broadcast_to(pose[:3, 3], d_world.shape), d_world], -1)
    hit = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
    t = hit["t_hit"].numpy()  # direction has unit z in the camera: t is the depth
    gid = hit["geometry_ids"].numpy()
    normal = hit["primitive_normals"].numpy()
    valid = np.isfinite(t)
    lut_inst = np.zeros(max(ids) + 2, np.uint16)
    lut_cls = np.zeros(max(ids) + 2, np.uint16)
    for g, (inst, cls) in ids.items():
        lut_inst[g], lut_cls[g] = inst, cls
    g = np.where(valid, gid, len(lut_inst) - 1).astype(np.int64)
    cls = lut_cls[g]
    base = np.array([BASE_COLOURS.get(c, (0, 0, 0)) for c in range(len(CLASSES))], float)[cls]
    shade = 0.6 + 0.4 * np.abs(normal @ np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8]))
    rgb = np.clip(base * shade[..., None], 0, 255).astype(np.uint8)
    return Frame(
        stamp_ns=stamp,
        rgb=rgb,
        depth_m=np.where(valid, t, 0).astype(np.float32),
        K=K,
        cam_to_world=pose,
        extras={"instance": lut_inst[g], "class": cls},
    )


def _features(frame: Frame, rng: np.random.Generator) -> np.ndarray:
    """One-hot of the class at each feature cell's centre pixel, plus noise; L2-normalised."""
    cy = (np.arange(FH) * H // FH + H // (2 * FH)).clip(0, H - 1)
    cx = (np.arange(FW) * W // FW + W // (2 * FW)).clip(0, W - 1)
    cls = frame.extras["class"][np.ix_(cy, cx)]
    f = np.eye(DIM, dtype=np.float32)[cls] + rng.normal(0, 0.25, (FH, FW, DIM)).astype(np.float32)
    return f / np.linalg.norm(f, axis=-1, keepdims=True)


def write_room_store(path: Path, num_views: int = 12) -> Path:
    scene, ids = _scene()
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1.0]])
    rng = np.random.default_rng(0)
    with StoreWriter(path, EncoderInfo("synthetic", "1", DIM, tuple(CLASSES))) as writer:
        for i in range(num_views):
            a = 2 * np.pi * i / num_views
            eye = np.array([1.2 * np.cos(a), 1.2 * np.sin(a), 1.6])
            target = np.array([-0.3 * np.cos(a), -0.3 * np.sin(a), 0.3])
            frame = _render(scene, ids, _look_at(eye, target), K, 1_000_000_000 + i * 10**8)
            writer.add(frame, _features(frame, rng))
        writer.set_text(CLASSES, np.eye(len(CLASSES), DIM, dtype=np.float32))
        writer.commit({"source": "rendered room"})
    return path


def gt_labels(points: np.ndarray, max_dist: float = 0.05) -> np.ndarray:
    """Instance id of the closest mesh within max_dist (0 = structure or none)."""
    scene, ids = _scene()
    q = o3d.core.Tensor(np.asarray(points, np.float32))
    closest = scene.compute_closest_points(q)
    gid = closest["geometry_ids"].numpy()
    dist = np.linalg.norm(closest["points"].numpy() - points, axis=1)
    lut = np.zeros(max(ids) + 1, np.int64)
    for g, (inst, _) in ids.items():
        lut[g] = inst
    return np.where(dist <= max_dist, lut[gid], 0)


@pytest.fixture(scope="module")
def room(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_room_store(tmp_path_factory.mktemp("room") / "store")


CONFIG = InstanceConfig(
    voxel_size=VOXEL, stride=1, cluster_eps=0.1, plane_min_points=100, min_instance_points=30
)


QUIET = Execution(progress=False)
REBUILD = Execution(overwrite=True)

# ---------------------------------------------------------------- scene cloud


def test_voxel_accumulator_matches_open3d_and_streams() -> None:
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 2, (5000, 3))
    cols = rng.integers(0, 256, (5000, 3))
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.colors = o3d.utility.Vector3dVector(cols / 255.0)
    ref = pcd.voxel_down_sample(0.25)
    origin = pts.min(axis=0) - 0.125  # open3d's grid: min bound minus half a voxel
    acc = VoxelAccumulator(0.25, origin, flush_points=700)  # many partial merges
    for chunk in np.array_split(np.arange(5000), 9):
        acc.add(pts[chunk], cols[chunk])
    mean_p, mean_c, counts = acc.mean()
    assert counts.sum() == 5000
    ref_p, ref_c = np.asarray(ref.points), np.asarray(ref.colors) * 255
    order_ref = np.lexsort(ref_p.T)
    order = np.lexsort(mean_p.T)
    np.testing.assert_allclose(mean_p[order], ref_p[order_ref], atol=1e-9)
    np.testing.assert_allclose(mean_c[order], ref_c[order_ref], atol=1e-6)


def test_scene_points_lie_on_the_rendered_surfaces(room: Path) -> None:
    cloud = fuse_scene_points(Store(room), voxel_size=VOXEL, stride=1, max_depth=8.0, run=QUIET)
    scene, _ = _scene()
    dist = scene.compute_distance(o3d.core.Tensor(cloud.points)).numpy()
    assert len(cloud) > 2000
    assert np.percentile(dist, 99) < VOXEL  # voxel means of surface points
    assert cloud.colors.dtype == np.uint8


# ---------------------------------------------------------------- proposals


def test_label_proposals_recover_the_boxes(room: Path) -> None:
    cloud = fuse_scene_points(Store(room), voxel_size=VOXEL, stride=1, max_depth=8.0, run=QUIET)
    props = label_proposals(cloud, Store(room), CONFIG, run=QUIET)
    assert props.source_ids.tolist() == [1, 2, 3]
    ids, iou, _ = best_iou(props.masks, gt_labels(cloud.points))
    assert ids.tolist() == [1, 2, 3]
    assert iou.min() > 0.9, iou


def test_labels_without_instance_images_is_one_clear_error(tmp_path: Path) -> None:
    frame = Frame(
        0, np.zeros((4, 4, 3), np.uint8), np.ones((4, 4), np.float32), np.eye(3), np.eye(4)
    )
    with StoreWriter(tmp_path / "s", None) as writer:
        writer.add(frame)
        writer.commit({})
    cloud = fuse_scene_points(
        Store(tmp_path / "s"), voxel_size=0.1, stride=2, max_depth=8.0, run=QUIET
    )
    with pytest.raises(FuseError, match="instance_zstd"):
        label_proposals(cloud, Store(tmp_path / "s"), CONFIG, run=QUIET)


# ---------------------------------------------------------------- the whole map


def test_build_instances_labels(room: Path, tmp_path: Path) -> None:
    from care_maps.fuse.viz_instances import log_instances

    config = InstanceConfig(**{**CONFIG.__dict__, "proposals": "labels"})
    rrd = tmp_path / "inst.rrd"
    path = build_instances(room, config)
    log_instances(room, rrd)
    table = read_table(path)
    md = table.schema.metadata
    assert json.loads(md[b"care.vocabulary"]) == CLASSES
    assert float(md[b"care.logit_scale"]) == 100.0
    assert md[b"care.encoder.name"] == b"synthetic"
    assert table.column("candidate_id").to_pylist() == [0, 1, 2]
    # every box is seen by several views and is classified as its class
    assert (table.column("num_views").to_numpy() == 5).all()
    top = [t[0] for t in table.column("top_classes").to_pylist()]
    assert top == [cls for _, _, cls in BOXES]
    # masks and boxes index the scene cloud
    cloud = read_scene_points(room / "scene_points.parquet")
    for row, (lo, hi, _) in zip(table.to_pylist(), BOXES, strict=True):
        pts = cloud.points[row["point_indices"]]
        assert row["num_points"] == len(pts)
        np.testing.assert_allclose(row["bbox_min"], pts.min(0), atol=1e-6)
        np.testing.assert_allclose(row["center"], pts.mean(0), atol=1e-5)
        assert np.all(pts.min(0) > np.array(lo) - VOXEL)
        assert np.all(pts.max(0) < np.array(hi) + VOXEL)
    # per-view table: the columns recomputed independently from it
    views = read_table(room / "instance_views.parquet").to_pandas()
    text = np.eye(len(CLASSES), DIM)
    for i in range(3):
        rows = views[views.instance_id == i].sort_values("rank")
        assert rows["rank"].tolist() == list(range(5))
        assert rows.visible_points.is_monotonic_decreasing
        f = np.stack(rows.feature.to_numpy()).astype(np.float64)
        fused = f.mean(0) / np.linalg.norm(f.mean(0))
        P = class_distribution(fused[None], text)
        assert table.column("entropy")[i].as_py() == pytest.approx(
            entropy(P)[0], rel=1e-3, abs=1e-4
        )
        P_views = class_distribution(f, text)
        assert table.column("pwkl")[i].as_py() == pytest.approx(
            pwkl_pairwise([P_views])[0], rel=1e-4
        )
        se = np.std(f, axis=0).mean() / np.sqrt(len(f))  # plain form, weights 1
        assert table.column("stderr")[i].as_py() == pytest.approx(se, rel=1e-4)
    # readable by other tools
    assert pl.read_parquet(path).height == 3
    assert (
        duckdb.sql(f"select count(*) from '{room / 'instance_views.parquet'}'").fetchall()[0][0]
        == 15
    )
    counts = rrd_entity_counts(rrd)
    for i in range(3):  # one entity per instance, one step of the instance timeline each
        assert counts[(f"/world/instances/{i}", "Boxes3D:half_sizes")] == 1
        assert counts[(f"/world/segments/{i}", "Points3D:positions")] == 1
    assert counts[("/instance", "TextDocument:text")] == 3
    assert counts[("/world/chosen/0/image", "EncodedImage:blob")] == 3
    assert counts[("/world/chosen/0", "Pinhole:image_from_camera")] == 3
    assert ("/world/scene/rgb", "Points3D:positions") in counts


def test_build_is_skipped_when_current_and_recompute_changes_columns(room: Path) -> None:
    config = InstanceConfig(**{**CONFIG.__dict__, "proposals": "labels"})
    path = build_instances(room, config)
    stamp = path.stat().st_mtime_ns
    assert build_instances(room, config).stat().st_mtime_ns == stamp
    faster = Execution(batch_size=3, read_ahead=0)  # how, not what
    assert build_instances(room, config, run=faster).stat().st_mtime_ns == stamp
    before = read_table(path)
    recompute_instances(room, ["bed", "chair", "table"], logit_scale=10.0)
    after = read_table(path)
    assert json.loads(after.schema.metadata[b"care.vocabulary"]) == ["bed", "chair", "table"]
    assert [t[0] for t in after.column("top_classes").to_pylist()] == [1, 2, 0]
    assert after.column("point_indices").equals(before.column("point_indices"))
    assert after.column("entropy").to_pylist() != before.column("entropy").to_pylist()
    # the recompute equals a fresh build for that vocabulary and scale
    fresh_config = {"vocabulary": ("bed", "chair", "table"), "logit_scale": 10.0}
    fresh_map = InstanceConfig(**{**config.__dict__, **fresh_config})
    fresh = read_table(build_instances(room, fresh_map, run=REBUILD))
    for name in ("entropy", "stderr", "pwkl", "log_norm", "num_views"):
        np.testing.assert_allclose(
            after.column(name).to_numpy(), fresh.column(name).to_numpy(), rtol=1e-6, err_msg=name
        )


def test_build_instances_geometric(room: Path) -> None:
    path = build_instances(room, CONFIG)
    table = read_table(path)
    cloud = read_scene_points(room / "scene_points.parquet")
    masks = [np.asarray(m) for m in table.column("point_indices").to_pylist()]
    ids, iou, best = best_iou(masks, gt_labels(cloud.points))
    assert ids.tolist() == [1, 2, 3]
    assert iou.mean() > 0.5, iou
    top = [table.column("top_classes")[int(b)].as_py()[0] for b in best]
    assert top == [cls for _, _, cls in BOXES]


@pytest.mark.parametrize("proposals", ["geometric", "labels"])
def test_views_read_ahead_give_the_same_map(room: Path, tmp_path: Path, proposals: str) -> None:
    """Decoding views on background threads (the default) or in the projecting thread: the
    same scene cloud, instances and per-view table, byte for byte."""
    import shutil

    built = []
    for ahead in (0, 2):
        store = tmp_path / f"ahead{ahead}"
        shutil.copytree(room, store, ignore=shutil.ignore_patterns("instance*", "scene_points*"))
        config = InstanceConfig(**{**CONFIG.__dict__, "proposals": proposals})
        build_instances(store, config, run=Execution(read_ahead=ahead))
        names = ("scene_points.parquet", "instances.parquet", "instance_views.parquet")
        built.append([(store / name).read_bytes() for name in names])
    assert built[1] == built[0]


class ColourCropEncoder(Encoder):
    """Classifies a crop by its median colour against the rendered base colours."""

    name = "colour-crops"
    dim = DIM
    supports_crops = True

    def encode_views(self, frames: Sequence[Frame]) -> np.ndarray:
        raise NotImplementedError

    def encode_text(self, names: Sequence[str]) -> np.ndarray:
        return np.eye(len(names), DIM, dtype=np.float32)

    def encode_crops(self, crops: Sequence[np.ndarray]) -> np.ndarray:
        cls = np.array(sorted(BASE_COLOURS))
        ref = np.array([BASE_COLOURS[c] for c in cls], float)
        ref = ref / np.linalg.norm(ref, axis=1, keepdims=True)
        out = np.zeros((len(crops), DIM), np.float32)
        for i, crop in enumerate(crops):
            c = np.median(crop.reshape(-1, 3), axis=0)
            out[i, cls[np.argmax(ref @ (c / np.linalg.norm(c)))]] = 1.0
        return out


def test_build_instances_crops(room: Path) -> None:
    config = InstanceConfig(**{**CONFIG.__dict__, "proposals": "labels", "features": "crops"})
    path = build_instances(room, config, encoder=ColourCropEncoder())
    table = read_table(path)
    assert [t[0] for t in table.column("top_classes").to_pylist()] == [c for _, _, c in BOXES]
    with pytest.raises(FuseError, match="cannot encode crops"):
        build_instances(
            room,
            config,
            run=REBUILD,
            encoder=type("NoCrops", (ColourCropEncoder,), {"supports_crops": False})(),
        )


class _CountedCrops(ColourCropEncoder):
    """Notes the torch threads each call of the model runs on."""

    def __init__(self) -> None:
        self.threads: list[int] = []

    def encode_crops(self, crops: Sequence[np.ndarray]) -> np.ndarray:
        import torch

        self.threads.append(torch.get_num_threads())
        return super().encode_crops(crops)


def test_crops_are_encoded_on_the_encoders_threads(room: Path) -> None:
    """The fusion runs on one thread; the crops' model on every core ingest's forward pass
    has (``Work.ENCODE``), and the fusion's one thread is back after it."""
    import torch

    from care_maps.runtime.threads import Work, thread_count, threads_for

    config = InstanceConfig(**{**CONFIG.__dict__, "proposals": "labels", "features": "crops"})
    encoder = _CountedCrops()
    with threads_for(Work.FUSE):
        build_instances(room, config, run=REBUILD, encoder=encoder)
        assert torch.get_num_threads() == 1
    assert encoder.threads
    assert set(encoder.threads) == {thread_count(Work.ENCODE)}


class _FailingCrops(ColourCropEncoder):
    def encode_crops(self, crops: Sequence[np.ndarray]) -> np.ndarray:
        raise FuseError("the crop model failed")


def test_failed_build_leaves_the_previous_map_whole(room: Path) -> None:
    """A build that fails after a new scene cloud was made (another voxel size) must not
    leave that cloud next to the old masks that index the old one, nor half the tables."""
    names = ("instances.parquet", "instance_views.parquet", "scene_points.parquet")
    build_instances(room, InstanceConfig(**{**CONFIG.__dict__, "proposals": "labels"}))
    before = {n: (room / n).read_bytes() for n in names}
    config = InstanceConfig(
        **{**CONFIG.__dict__, "proposals": "labels", "features": "crops", "voxel_size": 0.05}
    )
    with pytest.raises(FuseError, match="crop model failed"):
        build_instances(room, config, encoder=_FailingCrops())
    assert {n: (room / n).read_bytes() for n in names} == before
    assert not list(room.glob(".*building*"))


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ({"min_instance_points": 10**9}, "found no instance"),
        ({"min_visible_points": 10**9}, "no view sees"),
    ],
)
def test_empty_map_is_one_clear_error(room: Path, setting: dict, message: str) -> None:
    config = InstanceConfig(**{**CONFIG.__dict__, **setting})
    with pytest.raises(FuseError, match=message):
        build_instances(room, config, run=REBUILD)


def test_bad_config_is_one_clear_error() -> None:
    with pytest.raises(FuseError, match="unknown proposals"):
        InstanceConfig(proposals="magic")
    with pytest.raises(FuseError, match="voxel_size"):
        InstanceConfig(voxel_size=0)


# ---------------------------------------------------------------- the sample world

SAMPLE = Path(__file__).resolve().parents[2] / "care_maps" / "data" / "sample" / "scene_000.mcap"


class ClassOneHotEncoder(Encoder):
    """Dense features = one-hot of the recording's class image at each cell centre.

    A perfect perception model: it isolates the proposals and view selection from
    encoder errors when measuring them on the sample.
    """

    name = "class-onehot"
    fh, fw = 24, 32

    def __init__(self) -> None:
        self.names: tuple[str, ...] = ()

    def prepare(self, context: RecordingContext) -> None:
        self.names = context.label_names
        self.dim = len(self.names)

    def encode_views(self, frames: Sequence[Frame]) -> np.ndarray:
        out = []
        for frame in frames:  # a handful of frames per call
            cls = frame.extras["class"]
            H, W = cls.shape
            rows = np.arange(self.fh) * H // self.fh + H // (2 * self.fh)
            cols = np.arange(self.fw) * W // self.fw + W // (2 * self.fw)
            out.append(np.eye(self.dim, dtype=np.float32)[cls[np.ix_(rows, cols)]])
        return np.stack(out)

    def encode_text(self, names: Sequence[str]) -> np.ndarray:
        return np.eye(self.dim, dtype=np.float32)[[self.names.index(n) for n in names]]


@pytest.fixture(scope="module")
def sample_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if not SAMPLE.is_file():
        pytest.skip(f"{SAMPLE} not present (make it with `care sample make`)")
    from care_maps.ingest.pipeline import IngestConfig, run_ingest

    out = tmp_path_factory.mktemp("sample") / "store"
    return run_ingest(SAMPLE, out, IngestConfig(), run=QUIET, encoder=ClassOneHotEncoder())


@pytest.mark.slow
@pytest.mark.parametrize(("method", "target"), [("labels", 0.9), ("geometric", 0.5)])
def test_sample_proposals_reach_their_iou(sample_store: Path, method: str, target: float) -> None:
    build_instances(sample_store, InstanceConfig(proposals=method))
    ids, iou = instance_map_iou(sample_store, SAMPLE)
    print(f"\n{method}: mean IoU {iou.mean():.3f} over {len(ids)} GT instances")
    assert len(ids) >= 10
    assert iou.mean() > target


@pytest.mark.slow
def test_cli_prints_the_proposal_iou_against_ground_truth(sample_store: Path) -> None:
    from typer.testing import CliRunner

    from care_maps.cli.main import _register, app

    _register()
    result = CliRunner().invoke(app, ["fuse", "instances", str(sample_store)])
    assert result.exit_code == 0, result.output
    line = next(ln for ln in result.output.splitlines() if ln.startswith("proposals vs ground"))
    ids, iou = instance_map_iou(sample_store, SAMPLE)
    assert f"mean best IoU {iou.mean():.3f} over {len(ids)} instances" in line
    assert iou.mean() > 0.5
