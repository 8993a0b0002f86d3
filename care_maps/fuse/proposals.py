"""Class-agnostic instance proposals: point-index masks over the scene cloud, by plugin.

``PROPOSERS`` maps a method name to a function ``(cloud, store, settings, *, run) ->
Proposals`` (``run``: how views are read, :class:`care_maps.runtime.execution.Execution`):

- ``geometric``: no labels needed. The dominant planes are found one after the other with RANSAC
  (:func:`care_maps.geometry.planes.fit_plane`, seeded: the same planes in every process); a plane counts
  as *structure* when it is horizontal at floor or ceiling height, or vertical and at least
  ``wall_min_height`` tall (a wall; a tall flat front such as a wardrobe's can go with it, a
  known weakness). Only the inliers whose own normal agrees with the plane's are removed, so
  the sides of an object standing on the floor or against a wall stay. What is left is
  clustered with DBSCAN (open3d ``cluster_dbscan``); clusters too small or too large to be
  an object are dropped.
- ``labels``: oracle masks from the recording's instance-id images (the views table's ``instance_zstd``).
  Every scene point is projected into every view it is visible in (the occlusion test of
  :mod:`care_maps.fuse.views`) and takes the majority instance id of the pixels it lands on; id 0
  (structure) wins like any other id, and such points belong to no mask.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from tqdm import tqdm

from care_maps.core.errors import FuseError
from care_maps.core.store import Store
from care_maps.fuse.config import InstanceConfig, ProposalMethod
from care_maps.fuse.pointcloud import SceneCloud
from care_maps.fuse.views import iter_view_batches, visible_hits
from care_maps.geometry.planes import along, fit_plane
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution

__all__ = [
    "PROPOSERS",
    "Proposals",
    "geometric_proposals",
    "label_proposals",
    "remove_structure",
]

_RANSAC_SAMPLE = 20_000
"""RANSAC fits each plane on at most this many random points of the pool; the inliers are
then taken from the whole pool by their distance to the fitted plane (same result for the
dominant planes, a fraction of the time on large clouds)."""

_RANSAC_ITERATIONS = 1000
"""Random triples tried per plane."""


@dataclass(frozen=True)
class Proposals:
    """Masks over the scene cloud.

    Attributes:
        masks: M int32 arrays of sorted point indices.
        source_ids: (M,) int64 instance id each mask came from (``labels``), -1 otherwise.
    """

    masks: list[np.ndarray]
    source_ids: np.ndarray

    def __len__(self) -> int:
        return len(self.masks)


def _masks_from_labels(labels: np.ndarray, min_points: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Group point indices by label (labels <= 0 ignored), dropping groups below min_points."""
    idx = np.nonzero(labels > 0)[0]
    order = np.argsort(labels[idx], kind="stable")
    idx = idx[order]
    ids, starts, counts = np.unique(labels[idx], return_index=True, return_counts=True)
    keep = counts >= min_points
    masks = [
        idx[s : s + c].astype(np.int32) for s, c in zip(starts[keep], counts[keep], strict=True)
    ]
    return masks, ids[keep].astype(np.int64)


def _pcd(points: np.ndarray):  # -> open3d.geometry.PointCloud
    import open3d as o3d

    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(np.asarray(points, np.float64))
    return pcd


def remove_structure(points: np.ndarray, settings: InstanceConfig) -> np.ndarray:
    """(N,) bool: True for points of floor, ceiling and wall planes.

    Planes are found in turn by RANSAC on the points not yet explained by a plane; every
    found plane leaves the RANSAC pool (so the next one can be found) but only structural
    planes remove their normal-consistent inliers from the scene.
    """
    import open3d as o3d

    rng = np.random.default_rng(settings.seed)
    n = len(points)
    removed = np.zeros(n, bool)
    if n < 3:
        return removed
    pcd = _pcd(points)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(settings.normal_radius, 30))
    normals = np.asarray(pcd.normals)
    z = points[:, 2]
    floor_z, ceil_z = np.percentile(z, 1.0), np.percentile(z, 99.0)
    cos_tol = np.cos(np.deg2rad(settings.normal_angle_deg))
    pool = np.arange(n)
    structural: list[tuple[np.ndarray, float, np.ndarray]] = []
    for _ in range(settings.max_planes):
        if len(pool) < max(settings.plane_min_points, 3):
            break
        sample = pool if len(pool) <= _RANSAC_SAMPLE else rng.choice(pool, _RANSAC_SAMPLE, False)
        plane = fit_plane(points[sample], settings.plane_distance, _RANSAC_ITERATIONS, rng)
        if plane is None:
            break
        normal, offset = plane.normal, plane.offset
        inl = pool[plane.distance(points[pool]) <= settings.plane_distance]
        if len(inl) < settings.plane_min_points:
            break
        agree = np.abs(along(normals[inl], normal)) >= cos_tol
        pool = np.setdiff1d(pool, inl, assume_unique=True)
        height = float(np.median(z[inl]))
        horizontal = abs(normal[2]) >= cos_tol
        vertical = abs(normal[2]) <= np.sin(np.deg2rad(settings.normal_angle_deg))
        is_floor = horizontal and abs(height - floor_z) <= settings.floor_band
        is_ceiling = (
            horizontal and ceil_z - floor_z > 2.0 and abs(height - ceil_z) <= settings.floor_band
        )
        zs = z[inl[agree]]
        lo_z, hi_z = np.percentile(zs, [2, 98]) if zs.size else (0.0, 0.0)
        is_wall = vertical and hi_z - lo_z >= settings.wall_min_height
        if is_floor or is_ceiling or is_wall:
            removed[inl[agree]] = True
            structural.append((normal, offset, inl[~agree]))
    removed[_corner_points(points, structural, settings.normal_radius, cos_tol)] = True
    return removed


def _corner_points(
    points: np.ndarray,
    structural: list[tuple[np.ndarray, float, np.ndarray]],
    band: float,
    cos_tol: float,
) -> np.ndarray:
    """Indices of structural-plane inliers whose normal disagreed because they lie at a corner.

    Normals estimated within ``band`` of the line where two structural planes meet (floor
    and wall, two walls) point in between, so the normal test keeps them; left in the scene
    they form a wire frame of the room that DBSCAN merges with every object standing
    against a wall. An inlier of one structural plane that also lies within ``band`` of a
    non-parallel structural plane is such a corner point. The bottom row of an object side
    closer than ``band`` to a wall goes with them: a few points, not the object.
    """
    hits = []
    for i, (_, _, off) in enumerate(structural):
        if off.size == 0:
            continue
        near = np.zeros(off.size, bool)
        for j, (normal, d, _) in enumerate(structural):
            if j == i or abs(normal @ structural[i][0]) >= cos_tol:
                continue
            near |= np.abs(along(points[off], normal) + d) <= band
        hits.append(off[near])
    return np.concatenate(hits) if hits else np.zeros(0, np.int64)


def geometric_proposals(
    cloud: SceneCloud,
    store: Store | None,
    settings: InstanceConfig,
    *,
    run: Execution = DEFAULT_EXECUTION,
) -> Proposals:
    """Masks of the clusters left after removing floor, walls and ceiling (see module doc)."""
    points = np.asarray(cloud.points, np.float64)
    rest = np.nonzero(~remove_structure(points, settings))[0]
    if len(rest) == 0:
        return Proposals([], np.zeros(0, np.int64))
    labels_rest = np.asarray(
        _pcd(points[rest]).cluster_dbscan(settings.cluster_eps, settings.cluster_min_points),
        np.int64,
    )
    labels = np.full(len(points), -1, np.int64)
    labels[rest] = labels_rest + 1  # 0 = DBSCAN noise
    masks, _ = _masks_from_labels(labels, settings.min_instance_points)
    if masks:  # per-mask extent in one reduceat over the concatenated masks
        starts = np.cumsum([0] + [len(m) for m in masks[:-1]])
        pts = points[np.concatenate(masks)]
        extent = np.maximum.reduceat(pts, starts) - np.minimum.reduceat(pts, starts)
        keep = extent.max(axis=1) <= settings.max_instance_extent
        masks = [m for m, ok in zip(masks, keep, strict=True) if ok]
    return Proposals(masks, np.full(len(masks), -1, np.int64))


def _compress_votes(keys: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    uniq, inverse = np.unique(keys, return_inverse=True)
    return uniq, np.bincount(inverse, weights=counts, minlength=len(uniq)).astype(np.int64)


def label_proposals(
    cloud: SceneCloud,
    store: Store | None,
    settings: InstanceConfig,
    *,
    run: Execution = DEFAULT_EXECUTION,
) -> Proposals:
    """Oracle masks: each scene point takes the majority instance id over the views seeing it."""
    if store is None:
        msg = "labels proposals need the store's instance images; pass the store"
        raise FuseError(msg)
    points = np.asarray(cloud.points)
    keys = np.zeros(0, np.int64)
    counts = np.zeros(0, np.int64)
    seen = False
    bar = tqdm(total=store.num_views, desc="label votes", disable=not run.progress)
    for batch in iter_view_batches(
        store, batch_size=run.batch_size, extras=("instance",), read_ahead=run.read_ahead
    ):
        bar.update(len(batch.view_ids))
        inst = batch.extras.get("instance")
        if inst is None:
            continue
        seen = True
        hits = visible_hits(
            points,
            batch.depth,
            batch.K,
            batch.cam_to_world,
            depth_tolerance=settings.depth_tolerance,
        )
        ids = inst[hits.view, hits.v, hits.u].astype(np.int64)
        new = (hits.point.astype(np.int64) << 16) | ids
        keys, counts = _compress_votes(
            np.concatenate([keys, new]), np.concatenate([counts, np.ones(len(new), np.int64)])
        )
    bar.close()
    if not seen:
        msg = (
            f"{store.path}: no view has an instance image (views.parquet column instance_zstd); "
            "use proposals 'geometric' or ingest a recording with /camera/instance"
        )
        raise FuseError(msg)
    point, inst_id = keys >> 16, keys & 0xFFFF
    order = np.lexsort((inst_id, -counts, point))
    first = np.unique(point[order], return_index=True)[1]
    winner = order[first]
    labels = np.zeros(len(points), np.int64)
    labels[point[winner]] = inst_id[winner]
    masks, ids = _masks_from_labels(labels, settings.min_label_points)
    return Proposals(masks, ids)


class Proposer(Protocol):
    """A proposal method: masks over ``cloud`` (``store``: its views, where the method
    reads them) with ``settings``, reading views as ``run`` says."""

    def __call__(
        self,
        cloud: SceneCloud,
        store: Store | None,
        settings: InstanceConfig,
        *,
        run: Execution = ...,
    ) -> Proposals: ...


PROPOSERS: dict[ProposalMethod, Proposer] = {
    ProposalMethod.GEOMETRIC: geometric_proposals,
    ProposalMethod.LABELS: label_proposals,
}
"""Proposal method -> function; the CLI's ``--proposals`` choices are the enum's."""
