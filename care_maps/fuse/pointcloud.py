"""The scene point cloud: every view's depth back-projected into the world and voxel-averaged.

The cloud is what instance proposals are masks over (``point_indices`` in
``instances.parquet`` index into ``scene_points.parquet``), so it is built once per store
and kept. Views are streamed one at a time into a :class:`VoxelAccumulator`, which keeps
per-voxel sums and counts; pending points are merged into it every ``flush_points``
points, so memory is bounded by the occupied voxels, not by the number of views.

Why not re-run open3d's ``voxel_down_sample`` on the growing cloud: it aligns its grid to
the current cloud's minimum corner, which moves as views arrive, and averaging already
averaged points weights them wrongly. The accumulator keeps exact sums on a fixed grid and
gives the same result as one ``voxel_down_sample`` call over all points at once on the same
grid (the tests check this against open3d).
"""

from __future__ import annotations

from contextlib import closing
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
from tqdm import tqdm

from care_maps.core.errors import FuseError, StoreError
from care_maps.core.store import Store, read_table, write_table_atomic
from care_maps.geometry.transforms import backproject, transform_points
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution
from care_maps.runtime.readahead import read_ahead as ahead

__all__ = [
    "SCENE_POINTS_SCHEMA",
    "SceneCloud",
    "VoxelAccumulator",
    "fuse_scene_points",
    "read_scene_points",
    "write_scene_points",
]

SCENE_POINTS_SCHEMA = pa.schema(
    [
        pa.field("x", pa.float32(), nullable=False),
        pa.field("y", pa.float32(), nullable=False),
        pa.field("z", pa.float32(), nullable=False),
        pa.field("r", pa.uint8(), nullable=False),
        pa.field("g", pa.uint8(), nullable=False),
        pa.field("b", pa.uint8(), nullable=False),
    ]
)

FLUSH_POINTS = 2_000_000
"""Pending points merged into the voxel sums at a time (bounds the memory of a cloud)."""

_KEY_BITS = 21
_KEY_OFFSET = 1 << (_KEY_BITS - 1)
_KEY_MASK = (1 << _KEY_BITS) - 1


@dataclass(frozen=True)
class SceneCloud:
    """A coloured point cloud in the world frame (z up).

    Attributes:
        points: (N, 3) float32 world coordinates, metres.
        colors: (N, 3) uint8 RGB.
    """

    points: np.ndarray
    colors: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])


class VoxelAccumulator:
    """Streaming voxel-grid average of points and colours on a fixed grid.

    A point p falls in voxel ``floor((p - origin) / voxel_size)``; each occupied voxel
    keeps the sum of its points, of their colours and their count. Memory grows with
    the occupied voxels plus at most ``flush_points`` pending points.
    """

    def __init__(
        self,
        voxel_size: float,
        origin: np.ndarray | None = None,
        *,
        flush_points: int = FLUSH_POINTS,
    ) -> None:
        if voxel_size <= 0:
            msg = f"voxel size must be positive, got {voxel_size}"
            raise FuseError(msg)
        self.voxel_size = float(voxel_size)
        self.origin = np.zeros(3) if origin is None else np.asarray(origin, np.float64)
        self.flush_points = flush_points
        self._keys = np.zeros(0, np.int64)
        self._sums = np.zeros((0, 6), np.float64)
        self._counts = np.zeros(0, np.int64)
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []
        self._num_pending = 0

    def add(self, points: np.ndarray, colors: np.ndarray) -> None:
        """Add (N, 3) points with their (N, 3) colours (any numeric type, 0..255)."""
        self._pending.append((np.asarray(points, np.float64), np.asarray(colors, np.float64)))
        self._num_pending += len(points)
        if self._num_pending >= self.flush_points:
            self._flush()

    def _voxel_keys(self, points: np.ndarray) -> np.ndarray:
        idx = np.floor((points - self.origin) / self.voxel_size).astype(np.int64) + _KEY_OFFSET
        if idx.size and (idx.min() < 0 or idx.max() > _KEY_MASK):
            msg = (
                f"points span more than {1 << _KEY_BITS} voxels of {self.voxel_size} m on an "
                "axis; raise the voxel size or cap the depth (max_depth)"
            )
            raise FuseError(msg)
        return (idx[:, 0] << (2 * _KEY_BITS)) | (idx[:, 1] << _KEY_BITS) | idx[:, 2]

    def _flush(self) -> None:
        if not self._pending:
            return
        pts = np.concatenate([p for p, _ in self._pending])
        cols = np.concatenate([c for _, c in self._pending])
        self._pending.clear()
        self._num_pending = 0
        keys = np.concatenate([self._keys, self._voxel_keys(pts)])
        sums = np.concatenate([self._sums, np.concatenate([pts, cols], axis=1)])
        counts = np.concatenate([self._counts, np.ones(len(pts), np.int64)])
        self._keys, inverse = np.unique(keys, return_inverse=True)
        n = len(self._keys)
        self._counts = np.bincount(inverse, weights=counts, minlength=n).astype(np.int64)
        self._sums = np.stack(
            [np.bincount(inverse, weights=sums[:, k], minlength=n) for k in range(6)], axis=1
        )

    def __len__(self) -> int:
        self._flush()
        return len(self._keys)

    def mean(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-voxel mean points (M, 3) and colours (M, 3) as float64, and counts (M,).

        Voxels come in the order of their grid keys (x, then y, then z index).
        """
        self._flush()
        c = np.maximum(self._counts, 1)[:, None]
        return self._sums[:, :3] / c, self._sums[:, 3:] / c, self._counts.copy()

    def cloud(self) -> SceneCloud:
        """The voxel means as a :class:`SceneCloud` (float32 points, rounded uint8 colours)."""
        pts, cols, _ = self.mean()
        return SceneCloud(pts.astype(np.float32), np.clip(np.rint(cols), 0, 255).astype(np.uint8))


def fuse_scene_points(
    store: Store,
    *,
    voxel_size: float,
    stride: int,
    max_depth: float,
    flush_points: int = FLUSH_POINTS,
    run: Execution = DEFAULT_EXECUTION,
) -> SceneCloud:
    """Back-project every view of ``store`` and voxel-average the points into one cloud.

    Args:
        store: the feature store (only views.parquet is read).
        voxel_size: edge of the averaging voxel, metres (``InstanceConfig.voxel_size``).
        stride: use every ``stride``-th pixel in both directions.
        max_depth: ignore depth beyond this (metres); far depth is noisy on real sensors.
        flush_points: pending points merged into the voxel sums at a time (memory bound).
        run: its ``read_ahead`` views decoded ahead on a background thread
            (:mod:`care_maps.runtime.readahead`); a tqdm bar over views with its ``progress``.
    """
    if stride < 1:
        msg = f"stride must be >= 1, got {stride}"
        raise FuseError(msg)
    acc = VoxelAccumulator(voxel_size, flush_points=flush_points)
    # the views are decoded on a background thread while this one back-projects them
    with closing(ahead(store.iter_frames(extras=False), run.read_ahead)) as frames:
        for _, frame in tqdm(
            frames, total=store.num_views, desc="scene points", disable=not run.progress
        ):
            depth = np.where(frame.depth_m <= max_depth, frame.depth_m, 0)
            pts_cam, pix = backproject(depth, frame.K, stride)
            if len(pts_cam) == 0:
                continue
            acc.add(transform_points(frame.cam_to_world, pts_cam), frame.rgb[pix[:, 1], pix[:, 0]])
    if len(acc) == 0:
        msg = f"{store.path}: no valid depth pixel in any view; the scene cloud is empty"
        raise FuseError(msg)
    return acc.cloud()


def write_scene_points(
    cloud: SceneCloud, path: Path, metadata: dict[bytes, bytes] | None = None
) -> None:
    """Write ``scene_points.parquet`` (x, y, z float32, r, g, b uint8) atomically."""
    p, c = cloud.points, cloud.colors
    table = pa.table(
        {
            "x": p[:, 0],
            "y": p[:, 1],
            "z": p[:, 2],
            "r": c[:, 0],
            "g": c[:, 1],
            "b": c[:, 2],
        },
        schema=SCENE_POINTS_SCHEMA,
    )
    write_table_atomic(table, path, metadata)


def read_scene_points(path: Path) -> SceneCloud:
    """Read ``scene_points.parquet`` back into a :class:`SceneCloud`."""
    table = read_table(path)
    missing = {f.name for f in SCENE_POINTS_SCHEMA} - set(table.column_names)
    if missing:
        msg = f"{path}: columns {sorted(missing)} missing; rebuild with `care fuse instances`"
        raise StoreError(msg)
    pts = np.stack([table.column(k).to_numpy() for k in "xyz"], axis=1).astype(np.float32)
    cols = np.stack([table.column(k).to_numpy() for k in "rgb"], axis=1).astype(np.uint8)
    return SceneCloud(pts, cols)
