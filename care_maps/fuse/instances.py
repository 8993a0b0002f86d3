"""The OpenMask3D-style instance map: proposals, their best views, fused features, measures.

:func:`build_instances` runs the whole job on a store:

1. ``scene_points.parquet``: the voxel-averaged scene cloud (:mod:`care_maps.fuse.pointcloud`),
   reused when it was built from the same store with the same cloud settings;
2. class-agnostic proposals (:data:`care_maps.fuse.proposals.PROPOSERS`), point-index masks;
3. the top views of each mask by visible points (:func:`care_maps.fuse.views.select_views`) and
   their per-view features, pooled from the dense map inside the mask (``masked``) or
   re-encoded bounding-box crops (``crops``);
4. ``instance_views.parquet`` (every per-view feature) and ``instances.parquet`` (the
   common candidate columns of :mod:`care_maps.fuse.measures` plus the mask and its box), written
   atomically, the per-view table first. Instance features use weights 1, so ``stderr``
   is the plain form of docs/method.md.

A finished map with the same config, store and vocabulary is not rebuilt (the run's
``overwrite`` forces it; how the build runs is its :class:`care_maps.runtime.execution.Execution`);
:func:`recompute_instances` redoes only the columns for a new vocabulary or logit scale
from ``instance_views.parquet``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from care_maps.core.encoders import Encoder
from care_maps.core.errors import FuseError
from care_maps.core.maps import MapKind
from care_maps.core.outputs import damaged
from care_maps.core.store import Store, write_table_atomic
from care_maps.fuse.build import MapBuild, MapSpec, build_map
from care_maps.fuse.config import InstanceConfig, InstanceFeatures
from care_maps.fuse.frame import store_stamp
from care_maps.fuse.keys import CLOUD_CONFIG_KEY, STORE_KEY
from care_maps.fuse.measures import list_column
from care_maps.fuse.pointcloud import (
    SceneCloud,
    fuse_scene_points,
    read_scene_points,
    write_scene_points,
)
from care_maps.fuse.proposals import PROPOSERS, Proposals
from care_maps.fuse.recompute import recompute_candidates, sums_from_views
from care_maps.fuse.views import ViewSelection, crop_features, require_crops, select_views
from care_maps.runtime.execution import DEFAULT_EXECUTION, Execution

__all__ = [
    "INSTANCES_TABLE",
    "INSTANCE_FEATURES",
    "INSTANCE_MAP",
    "INSTANCE_VIEWS_SCHEMA",
    "INSTANCE_VIEWS_TABLE",
    "SCENE_POINTS_TABLE",
    "InstanceConfig",
    "build_instances",
    "recompute_instances",
]

INSTANCES_TABLE = "instances"
INSTANCE_VIEWS_TABLE = "instance_views"
SCENE_POINTS_TABLE = "scene_points"
INSTANCE_FEATURES = tuple(InstanceFeatures)
"""Ways to get a per-view instance feature (``InstanceConfig.features``)."""

INSTANCE_VIEWS_SCHEMA = pa.schema(
    [
        pa.field("instance_id", pa.int32(), nullable=False),
        pa.field("view_id", pa.int32(), nullable=False),
        pa.field("rank", pa.int32(), nullable=False),
        pa.field("visible_points", pa.int32(), nullable=False),
        pa.field("feature", pa.list_(pa.float16()), nullable=False),
    ]
)

_CLOUD_FIELDS = ("voxel_size", "stride", "max_depth")


def _scene_cloud(
    store: Store, config: InstanceConfig, run: Execution
) -> tuple[SceneCloud, dict | None]:
    """The scene cloud, reused from ``scene_points.parquet`` when it is current.

    A new cloud comes with the metadata to write it under; the build writes it together
    with the tables that index into it, so a failed build never leaves them apart.
    """
    path = store.table_path(SCENE_POINTS_TABLE)
    key = config.fingerprint(_CLOUD_FIELDS).encode()
    meta = {CLOUD_CONFIG_KEY: key, STORE_KEY: store_stamp(store)}
    if path.is_file() and not run.overwrite and not damaged(store.path, [path.name]):
        md = pq.read_schema(path).metadata or {}
        if all(md.get(k) == v for k, v in meta.items()):
            return read_scene_points(path), None
    cloud = fuse_scene_points(
        store,
        voxel_size=config.voxel_size,
        stride=config.stride,
        max_depth=config.max_depth,
        run=run,
    )
    return cloud, meta


def _store_encoder(store: Store, run: Execution) -> Encoder:
    """The model that made the store's features (its recorded weights and options)."""
    from care_maps.core.encoders.record import encoder_for_store

    return encoder_for_store(store.path, batch_size=run.batch_size)


def _per_view_features(
    store: Store,
    config: InstanceConfig,
    run: Execution,
    selection: ViewSelection,
    encoder: Encoder | None,
) -> np.ndarray:
    if config.features == "masked":
        assert selection.features is not None  # select_views pooled them
        return selection.features
    assert encoder is not None  # build_instances made and checked it
    return crop_features(
        store,
        selection,
        encoder,
        padding=config.crop_padding,
        run=run,
    )


def _views_table(selection: ViewSelection, features: np.ndarray) -> pa.Table:
    """One row per selected (instance, view), in instance then rank order."""
    inst, rank = np.nonzero(selection.view_ids >= 0)
    feats = features[inst, rank].astype(np.float16)
    return pa.table(
        {
            "instance_id": pa.array(inst.astype(np.int32)),
            "view_id": pa.array(selection.view_ids[inst, rank]),
            "rank": pa.array(rank.astype(np.int32)),
            "visible_points": pa.array(selection.visible[inst, rank]),
            "feature": list_column(feats.reshape(len(inst), -1), pa.float16()),
        },
        schema=INSTANCE_VIEWS_SCHEMA,
    )


def _geometry_columns(points: np.ndarray, proposals: Proposals) -> dict[str, pa.Array]:
    """``num_points``, ``point_indices``, ``bbox_min``, ``bbox_max``, ``center`` of each mask."""
    masks = proposals.masks
    lengths = np.array([len(m) for m in masks], np.int64)
    flat = np.concatenate(masks).astype(np.int32) if masks else np.zeros(0, np.int32)
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int32)
    if masks:
        pts = points[flat]
        lo = np.minimum.reduceat(pts, offsets[:-1], axis=0)
        hi = np.maximum.reduceat(pts, offsets[:-1], axis=0)
        centre = np.add.reduceat(pts.astype(np.float64), offsets[:-1], axis=0) / lengths[:, None]
    else:
        lo = hi = centre = np.zeros((0, 3))

    def vec3(a: np.ndarray) -> pa.Array:
        return pa.FixedSizeListArray.from_arrays(pa.array(a.astype(np.float32).ravel()), 3)

    return {
        "num_points": pa.array(lengths.astype(np.int32)),
        "point_indices": pa.ListArray.from_arrays(pa.array(offsets), pa.array(flat, pa.int32())),
        "bbox_min": vec3(lo),
        "bbox_max": vec3(hi),
        "center": vec3(centre),
        "source_id": pa.array(proposals.source_ids.astype(np.int64)),
    }


INSTANCE_MAP = MapSpec(
    MapKind.INSTANCES,
    (SCENE_POINTS_TABLE, INSTANCE_VIEWS_TABLE, INSTANCES_TABLE),
)
"""The instance map's tables: the cloud, the per-view rows and the masks that index into
them belong together, committed in this order."""


def build_instances(
    store_path: Path,
    config: InstanceConfig | None = None,
    *,
    run: Execution = DEFAULT_EXECUTION,
    encoder: Encoder | None = None,
) -> Path:
    """Build ``instances.parquet`` (and ``instance_views``, ``scene_points``) in the store.

    Args:
        store_path: the feature store directory.
        config: what the map is made from (default :class:`InstanceConfig`).
        run: how the build runs: views read ``batch_size`` at a time, ``read_ahead``
            ahead; ``overwrite`` rebuilds a current map (and scene cloud); progress bars.
        encoder: the encoder for ``features="crops"``; default: the store's own model,
            rebuilt from its record (:func:`care_maps.core.encoders.record.encoder_for_store`).

    Returns the path of ``instances.parquet``. The up-to-date check and the staged commit
    are the skeleton's (:mod:`care_maps.fuse.build`). Logging the map to Rerun is the caller's
    (:func:`care_maps.fuse.viz_instances.log_instances`).
    """
    config = config or InstanceConfig()
    return build_map(
        store_path, INSTANCE_MAP, config, lambda build: _build(build, config, run, encoder), run=run
    )


def _build(
    build: MapBuild, config: InstanceConfig, run: Execution, encoder: Encoder | None
) -> None:
    """Stage the tables of a new instance map (the cloud only when it is not current)."""
    store = build.store
    if config.features == "crops":  # before any work, not after the views are chosen
        encoder = encoder or _store_encoder(store, run)
        require_crops(encoder)
    cloud, cloud_meta = _scene_cloud(store, config, run)
    proposals = PROPOSERS[config.proposals](cloud, store, config, run=run)
    if len(proposals) == 0:
        msg = (
            f"{store.path}: the {config.proposals} proposals found no instance in "
            f"{len(cloud.points)} scene points; check the recording or the proposal "
            "settings (--set)"
        )
        raise FuseError(msg)
    selection = select_views(
        store,
        cloud.points,
        proposals.masks,
        top_k=config.top_k,
        depth_tolerance=config.depth_tolerance,
        min_visible_points=config.min_visible_points,
        pool_features=config.features == "masked",
        run=run,
    )
    if not (selection.view_ids >= 0).any():
        msg = (
            f"{store.path}: no view sees any of the {len(proposals)} proposals with "
            f"{config.min_visible_points}+ visible points; lower it with "
            "--set min_visible_points=N"
        )
        raise FuseError(msg)
    views = _views_table(selection, _per_view_features(store, config, run, selection, encoder))
    staged_views = build.staged.path(INSTANCE_VIEWS_TABLE)
    write_table_atomic(views, staged_views, build.metadata)
    sums = sums_from_views(
        staged_views, "instance_id", build.text, config.logit_scale, num_candidates=len(proposals)
    )
    table = sums.columns()
    for name, col in _geometry_columns(cloud.points, proposals).items():
        table = table.append_column(name, col)
    if cloud_meta is not None:
        write_scene_points(cloud, build.staged.path(SCENE_POINTS_TABLE), cloud_meta)
    write_table_atomic(table, build.staged.path(INSTANCES_TABLE), build.metadata)


def recompute_instances(
    store_path: Path, vocabulary: Sequence[str] | None = None, logit_scale: float | None = None
) -> Path:
    """Rewrite the candidate columns of ``instances.parquet`` for a new vocabulary or scale.

    Reads only ``instance_views.parquet`` and the instance table itself; the masks and
    boxes are kept. ``None`` keeps the current scale / the store's cached names.
    """
    return recompute_candidates(
        store_path, INSTANCES_TABLE, INSTANCE_VIEWS_TABLE, "instance_id", "instances",
        vocabulary=vocabulary, logit_scale=logit_scale,
    )  # fmt: skip
