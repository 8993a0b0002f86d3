"""Which views see an instance: projection, occlusion test and ranking, as OpenMask3D does it.

For every mask, its points are projected into every view; a point is *visible* in a view
when it lands inside the image, in front of the camera, and within ``depth_tolerance`` of
that view's depth at the pixel (otherwise something nearer hides it, or the sensor saw
nothing there). Views are ranked by their visible point count and the best ``top_k`` are
kept (ties: lower view id first). Views are processed in batches of the same image size,
all points against all views of a batch at once; a running top-k per mask means one pass
over the store, with memory bounded by masks x top_k.

The per-view instance feature (the default, ``masked``) is pooled in the same pass: the
mean of the view's dense feature map over the feature cells its visible points fall in,
each cell weighted by its number of visible points, then L2-normalised.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import ExitStack, closing
from dataclasses import dataclass
from typing import cast

import numpy as np
import scipy.sparse as sp
from tqdm import tqdm

from care_maps.core.encoders.base import Encoder, l2_normalise
from care_maps.core.errors import FuseError
from care_maps.core.frames import Frame
from care_maps.core.store import Store
from care_maps.runtime.execution import BATCH_SIZE, DEFAULT_EXECUTION, Execution
from care_maps.runtime.readahead import READ_AHEAD
from care_maps.runtime.readahead import read_ahead as ahead
from care_maps.runtime.threads import Work, threads_for

__all__ = [
    "ViewBatch",
    "ViewSelection",
    "VisibleHits",
    "crop_features",
    "iter_view_batches",
    "select_views",
    "visible_hits",
]

_MAX_PROJECTIONS = 4_000_000
"""Points x views projected at once; bounds the temporary arrays (~100 MB)."""


@dataclass(frozen=True)
class ViewBatch:
    """Views of one image size stacked for vectorised projection.

    Attributes:
        view_ids: (B,) int view ids.
        depth: (B, H, W) float32 metres, 0 = invalid.
        K: (B, 3, 3) intrinsics.
        cam_to_world: (B, 4, 4) optical-frame poses.
        rgb: (B, H, W, 3) uint8, or None when not requested.
        extras: label images by name, each (B, H, W) uint16 (only names every view has).
        features: (B, fh * fw, d) float32 dense features, or None.
        feature_shape: (fh, fw) of ``features``.
    """

    view_ids: np.ndarray
    depth: np.ndarray
    K: np.ndarray
    cam_to_world: np.ndarray
    rgb: np.ndarray | None
    extras: dict[str, np.ndarray]
    features: np.ndarray | None
    feature_shape: tuple[int, int]


@dataclass(frozen=True)
class VisibleHits:
    """Visible (view, point) pairs of one batch, with the pixel each point lands on.

    ``view`` indexes the batch, ``point`` the projected point array.
    """

    view: np.ndarray
    point: np.ndarray
    u: np.ndarray
    v: np.ndarray


@dataclass(frozen=True)
class ViewSelection:
    """The top views of each mask; row i is mask i, column r its rank (0 = best).

    Attributes:
        view_ids: (M, k) int32 view ids, -1 where a mask has fewer than k views.
        visible: (M, k) int32 visible point counts (0 where no view).
        bboxes: (M, k, 4) int32 pixel box (u_min, v_min, u_max, v_max), max exclusive.
        features: (M, k, d) float32 pooled per-view features, or None when not pooled.
    """

    view_ids: np.ndarray
    visible: np.ndarray
    bboxes: np.ndarray
    features: np.ndarray | None

    @property
    def num_views(self) -> np.ndarray:
        """(M,) number of selected views per mask."""
        return (self.view_ids >= 0).sum(axis=1).astype(np.int32)


def iter_view_batches(
    store: Store,
    *,
    batch_size: int = BATCH_SIZE,
    rgb: bool = False,
    extras: Sequence[str] = (),
    features: bool = False,
    read_ahead: int = READ_AHEAD,
) -> Iterator[ViewBatch]:
    """Stream the store's views as :class:`ViewBatch` es (a new batch at a size change),
    decoded up to ``read_ahead`` views ahead on background threads (:mod:`care_maps.runtime.readahead`)."""
    with ExitStack() as stack:  # the reading threads end with this generator
        frames = stack.enter_context(
            closing(
                ahead(store.iter_frames(batch_size=batch_size, extras=bool(extras)), read_ahead)
            )
        )
        feats = (
            stack.enter_context(
                closing(ahead(store.iter_features(batch_size=batch_size), read_ahead))
            )
            if features
            else None
        )
        yield from _batches(store, frames, feats, batch_size=batch_size, rgb=rgb, extras=extras)


def _batches(
    store: Store,
    frames: Iterator[tuple[int, Frame]],
    feats: Iterator[tuple[int, np.ndarray]] | None,
    *,
    batch_size: int,
    rgb: bool,
    extras: Sequence[str],
) -> Iterator[ViewBatch]:
    features = feats is not None
    pending: list[tuple[int, Frame, np.ndarray | None]] = []

    def emit() -> ViewBatch:
        fr = [f for _, f, _ in pending]
        fmaps = [m for _, _, m in pending]
        names = [n for n in extras if all(n in f.extras for f in fr)]
        fshape = (0, 0)
        stacked = None
        if features:
            shapes = {m.shape for m in fmaps if m is not None}
            if len(shapes) != 1:
                msg = f"{store.path}: feature maps of different shapes {shapes} in one batch"
                raise FuseError(msg)
            fh, fw, d = shapes.pop()
            fshape = (fh, fw)
            given = cast("list[np.ndarray]", fmaps)  # with features every view has its map
            stacked = np.stack(given).astype(np.float32).reshape(len(fr), fh * fw, d)
        batch = ViewBatch(
            view_ids=np.array([i for i, _, _ in pending], np.int64),
            depth=np.stack([f.depth_m for f in fr]),
            K=np.stack([f.K for f in fr]),
            cam_to_world=np.stack([f.cam_to_world for f in fr]),
            rgb=np.stack([f.rgb for f in fr]) if rgb else None,
            extras={n: np.stack([f.extras[n] for f in fr]) for n in names},
            features=stacked,
            feature_shape=fshape,
        )
        pending.clear()
        return batch

    for view_id, frame in frames:
        fmap = None
        if feats is not None:
            try:
                fid, fmap = next(feats)
            except StopIteration as err:
                msg = f"{store.path}: features.parquet has fewer rows than views.parquet"
                raise FuseError(msg) from err
            if fid != view_id:
                msg = f"{store.path}: feature row {fid} where view {view_id} was expected"
                raise FuseError(msg)
        if pending and (
            pending[0][1].depth_m.shape != frame.depth_m.shape or len(pending) >= batch_size
        ):
            yield emit()
        pending.append((view_id, frame, fmap))
    if pending:
        yield emit()


def visible_hits(
    points: np.ndarray,
    depth: np.ndarray,
    K: np.ndarray,
    cam_to_world: np.ndarray,
    *,
    depth_tolerance: float,
) -> VisibleHits:
    """All (view, point) pairs where a world point is visible in a batch of views.

    Args:
        points: (N, 3) world points.
        depth: (B, H, W) depth images, metres, 0 = invalid.
        K: (B, 3, 3) intrinsics; cam_to_world: (B, 4, 4) poses.
        depth_tolerance: largest |point depth - measured depth| (metres) still visible.

    A point lands on the pixel nearest its projection (pixel centres at integer
    coordinates, as in :func:`care_maps.geometry.transforms.backproject`).
    """
    B, H, W = depth.shape
    world_to_cam = np.linalg.inv(cam_to_world).astype(np.float32)
    R, t = world_to_cam[:, :3, :3], world_to_cam[:, :3, 3]
    Kf = K.astype(np.float32)
    pts = np.asarray(points, np.float32)
    chunk = max(1, _MAX_PROJECTIONS // max(B, 1))
    out: list[tuple[np.ndarray, ...]] = []
    for start in range(0, len(pts), chunk):
        p = pts[start : start + chunk]
        cam = np.einsum("bij,nj->bni", R, p) + t[:, None, :]  # (B, n, 3)
        z = cam[..., 2]
        front = z > 1e-6
        zs = np.where(front, z, 1.0)
        u = np.rint(Kf[:, None, 0, 0] * cam[..., 0] / zs + Kf[:, None, 0, 2])
        v = np.rint(Kf[:, None, 1, 1] * cam[..., 1] / zs + Kf[:, None, 1, 2])
        inside = front & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        b, n = np.divmod(np.flatnonzero(inside), inside.shape[1])  # faster than 2-D nonzero
        ui = u[b, n].astype(np.int64)
        vi = v[b, n].astype(np.int64)
        d = depth[b, vi, ui]
        ok = (d > 0) & (np.abs(z[b, n] - d) <= depth_tolerance)
        out.append((b[ok], n[ok] + start, ui[ok], vi[ok]))
    if not out:
        empty = np.zeros(0, np.int64)
        return VisibleHits(empty, empty, empty, empty)
    cols = [np.concatenate(c) for c in zip(*out, strict=True)]
    return VisibleHits(*cols)


def _expand_to_masks(
    hits: VisibleHits, start: np.ndarray, count: np.ndarray, mask_sorted: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Repeat each hit once per mask containing its point: (mask, view, u, v)."""
    rep = count[hits.point]
    total = int(rep.sum())
    first = np.repeat(start[hits.point], rep)
    within = np.arange(total) - np.repeat(np.cumsum(rep) - rep, rep)
    mask = mask_sorted[first + within]
    return mask, np.repeat(hits.view, rep), np.repeat(hits.u, rep), np.repeat(hits.v, rep)


def _batch_stats(
    batch: ViewBatch,
    mask: np.ndarray,
    view: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    num_masks: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Counts (M, B), boxes (M, B, 4) and pooled features (M, B, d) of one batch's hits."""
    B, H, W = batch.depth.shape
    key = mask * B + view
    counts = np.bincount(key, minlength=num_masks * B)
    big = np.iinfo(np.int32).max
    lo = np.full((num_masks * B, 2), big, np.int64)
    hi = np.full((num_masks * B, 2), -1, np.int64)
    uv = np.stack([u, v], axis=1)
    np.minimum.at(lo, key, uv)
    np.maximum.at(hi, key, uv)
    boxes = np.concatenate([lo, hi + 1], axis=1)
    boxes[counts == 0] = 0
    pooled = None
    if batch.features is not None:
        fh, fw = batch.feature_shape
        cells = fh * fw
        cell = (v * fh // H) * fw + (u * fw // W)
        weights = sp.csr_matrix(
            (np.ones(len(key), np.float32), (key, view * cells + cell)),
            shape=(num_masks * B, B * cells),
        )
        d = batch.features.shape[2]
        pooled = np.asarray(weights @ batch.features.reshape(B * cells, d), np.float32)
        pooled = l2_normalise(pooled).reshape(num_masks, B, d)
    return counts.reshape(num_masks, B), boxes.reshape(num_masks, B, 4), pooled


def select_views(
    store: Store,
    points: np.ndarray,
    masks: Sequence[np.ndarray],
    *,
    top_k: int,
    depth_tolerance: float,
    min_visible_points: int,
    pool_features: bool = True,
    run: Execution = DEFAULT_EXECUTION,
) -> ViewSelection:
    """Rank the store's views for each mask by visible point count; keep the best ``top_k``.

    Args:
        store: the feature store.
        points: (N, 3) scene points the masks index.
        masks: M arrays of point indices (masks may overlap).
        top_k: views kept per mask (the map's: :class:`care_maps.fuse.config.InstanceConfig`).
        depth_tolerance: see :func:`visible_hits`.
        min_visible_points: a view with fewer visible points of a mask is not its view.
        pool_features: also pool each kept view's dense features inside the mask.
        run: its ``batch_size`` views projected at once, decoded ``read_ahead`` views
            ahead on background threads (:func:`iter_view_batches`), a progress bar over
            views with ``progress``.
    """
    M = len(masks)
    lengths = np.array([len(m) for m in masks], np.int64)
    flat = np.concatenate([np.asarray(m, np.int64) for m in masks]) if M else np.zeros(0, int)
    owner = np.repeat(np.arange(M), lengths)
    order = np.argsort(flat, kind="stable")
    uniq, start, count = np.unique(flat[order], return_index=True, return_counts=True)
    mask_sorted = owner[order]
    sub = np.asarray(points)[uniq]

    best_count = np.zeros((M, 0), np.int64)
    best_view = np.zeros((M, 0), np.int64)
    best_box = np.zeros((M, 0, 4), np.int64)
    best_feat: np.ndarray | None = None
    bar = tqdm(total=store.num_views, desc="view selection", disable=not run.progress)
    for batch in iter_view_batches(
        store, batch_size=run.batch_size, features=pool_features, read_ahead=run.read_ahead
    ):
        hits = visible_hits(
            sub, batch.depth, batch.K, batch.cam_to_world, depth_tolerance=depth_tolerance
        )
        mask, view, u, v = _expand_to_masks(hits, start, count, mask_sorted)
        counts, boxes, pooled = _batch_stats(batch, mask, view, u, v, M)
        counts = np.where(counts >= min_visible_points, counts, 0)
        B = len(batch.view_ids)
        all_count = np.concatenate([best_count, counts], axis=1)
        all_view = np.concatenate([best_view, np.broadcast_to(batch.view_ids, (M, B))], axis=1)
        keep = np.argsort(-all_count, axis=1, kind="stable")[:, :top_k]
        best_count = np.take_along_axis(all_count, keep, axis=1)
        best_view = np.take_along_axis(all_view, keep, axis=1)
        best_box = np.take_along_axis(
            np.concatenate([best_box, boxes], axis=1), keep[..., None], axis=1
        )
        if pooled is not None:
            prev = best_feat if best_feat is not None else np.zeros((M, 0, pooled.shape[2]))
            best_feat = np.take_along_axis(
                np.concatenate([prev, pooled], axis=1).astype(np.float32), keep[..., None], axis=1
            )
        bar.update(B)
    bar.close()
    width = best_count.shape[1]
    if width < top_k:  # fewer views in the store than top_k
        pad = top_k - width
        best_count = np.pad(best_count, ((0, 0), (0, pad)))
        best_view = np.pad(best_view, ((0, 0), (0, pad)))
        best_box = np.pad(best_box, ((0, 0), (0, pad), (0, 0)))
        if best_feat is not None:
            best_feat = np.pad(best_feat, ((0, 0), (0, pad), (0, 0)))
    none = best_count <= 0
    best_view = np.where(none, -1, best_view)
    best_box[none] = 0
    if best_feat is not None:
        best_feat[none] = 0
    elif pool_features:
        best_feat = np.zeros((M, top_k, store.encoder.dim), np.float32)
    return ViewSelection(
        best_view.astype(np.int32),
        best_count.astype(np.int32),
        best_box.astype(np.int32),
        best_feat,
    )


def require_crops(encoder: Encoder) -> None:
    """One clear error for an encoder that cannot re-encode crops (checked before any work)."""
    if not encoder.supports_crops:
        msg = f"encoder {encoder.name!r} cannot encode crops; use features='masked'"
        raise FuseError(msg)


def crop_features(
    store: Store,
    selection: ViewSelection,
    encoder: Encoder,
    *,
    padding: float = 0.1,
    min_size: int = 8,
    run: Execution = DEFAULT_EXECUTION,
) -> np.ndarray:
    """Per-view features (M, k, d) from re-encoding the bounding-box crop of each mask.

    Each selected (mask, view) box is grown by ``padding`` of its size on every side (at
    least ``min_size`` pixels wide), clipped to the image, cut from the view's RGB and
    encoded with ``encoder.encode_crops``; unselected slots stay zero. Views are read
    ``run.batch_size`` at a time, ``run.read_ahead`` ahead. The model runs on
    :attr:`~care_maps.runtime.threads.Work.ENCODE`'s threads, as ingest's forward pass does,
    not the fusion's one: its last bits may depend on the core count, as a model's do
    (:data:`care_maps.runtime.threads.PINNED`); what is fused from them does not.
    """
    require_crops(encoder)
    M, k = selection.view_ids.shape
    out = np.zeros((M, k, encoder.dim), np.float32)
    sel_m, sel_r = np.nonzero(selection.view_ids >= 0)
    sel_view = selection.view_ids[sel_m, sel_r]
    bar = tqdm(total=store.num_views, desc="crops", disable=not run.progress)
    batches = iter_view_batches(
        store, batch_size=run.batch_size, rgb=True, read_ahead=run.read_ahead
    )
    for batch in batches:
        assert batch.rgb is not None  # requested above
        _, H, W, _ = batch.rgb.shape
        pos = np.searchsorted(batch.view_ids, sel_view)
        pos = np.minimum(pos, len(batch.view_ids) - 1)
        here = np.nonzero(batch.view_ids[pos] == sel_view)[0]
        crops = []
        for j in here:  # one crop per selected (mask, view) pair: sizes differ
            u0, v0, u1, v1 = selection.bboxes[sel_m[j], sel_r[j]]
            pu = max(int((u1 - u0) * padding), (min_size - (u1 - u0) + 1) // 2, 0)
            pv = max(int((v1 - v0) * padding), (min_size - (v1 - v0) + 1) // 2, 0)
            crops.append(
                batch.rgb[
                    pos[j], max(v0 - pv, 0) : min(v1 + pv, H), max(u0 - pu, 0) : min(u1 + pu, W)
                ]
            )
        if crops:
            with threads_for(Work.ENCODE):  # a model's products scale with cores, as at ingest
                encoded = encoder.encode_crops(crops)
            out[sel_m[here], sel_r[here]] = l2_normalise(np.asarray(encoded))
        bar.update(len(batch.view_ids))
    bar.close()
    return out
