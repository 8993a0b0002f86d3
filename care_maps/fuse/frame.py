"""The store's map frame, found once and shared by both maps (``map_frame.json``).

The first fusion of a store finds the gravity-aligned map frame from a bounded sample of the
views' depth points (:func:`care_maps.geometry.mapframe.estimate_map_frame`) and writes it beside the
tables, with the options it was found with; every later step reads the same frame
(:attr:`care_maps.core.store.Store.map_frame`), so the grid, the instances and every position in the
outputs agree. ``care fuse ... --up-axis/--floor-z`` replaces it (and so rebuilds the maps).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.mapframe import MapFrame, UpAxis
from care_maps.core.outputs import atomic_write_text
from care_maps.core.store import (
    MAP_FRAME_FILE,
    MAP_FRAME_STORE_FIELD,
    EncodedDepth,
    Store,
    map_frame_json,
    map_frame_owner,
    map_frame_record,
)
from care_maps.geometry.mapframe import estimate_map_frame
from care_maps.geometry.transforms import backproject, transform_points
from care_maps.runtime.background import thread_map

__all__ = [
    "DECODERS",
    "MIN_BAND_SHARE",
    "SAMPLE_POINTS",
    "SAMPLE_VIEWS",
    "check_height_band",
    "ensure_map_frame",
    "reframed",
    "sample_points",
    "store_stamp",
]

SAMPLE_VIEWS = 120
"""Most views whose depth is sampled (evenly spaced over the recording)."""
SAMPLE_POINTS = 30_000
"""Most points handed to the plane fit (a fixed-seed subset)."""
_PIXELS_ACROSS = 60
"""Sampled depth pixels across the shorter image side (stride 8 at 640 x 480)."""
DECODERS = 2
"""Threads decoding the sampled depth images by default (each view's points are its own: the
sample is the same whatever the count)."""


def sample_points(store: Store, decoders: int = DECODERS) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) world points from up to :data:`SAMPLE_VIEWS` views and the (V, 4, 4) world poses
    of every view; only the sampled views' depth is decoded, on ``decoders`` threads (1: in
    the caller's).

    The last store's sample is kept while its views table is unchanged (callers get
    copies): the first fusion of a store finds the map frame and then checks the height
    band on the same sample, which decoding twice cost a quarter of a second per 40 views.
    """
    path = store.table_path("views")
    stat = path.stat()
    key = (str(path.resolve()), stat.st_ino, stat.st_size, stat.st_mtime_ns)
    if not (_LAST_SAMPLE and _LAST_SAMPLE[0] == key):
        _LAST_SAMPLE[:] = [key, _sample_points(store, decoders)]
    points, poses = _LAST_SAMPLE[1]
    return points.copy(), poses.copy()


_LAST_SAMPLE: list = []
"""``[key of a views table, its sample]`` (:func:`sample_points`)."""


def _sample_points(store: Store, decoders: int) -> tuple[np.ndarray, np.ndarray]:
    poses = store.poses(in_map=False)
    keep = set(np.linspace(0, len(poses) - 1, min(len(poses), SAMPLE_VIEWS)).round().astype(int))

    def points_of(view: EncodedDepth) -> np.ndarray:
        depth = view.decode()
        stride = max(1, min(depth.shape) // _PIXELS_ACROSS)
        pts, _ = backproject(depth, view.K, stride=stride)
        return transform_points(poses[view.view_id], pts)

    sampled = store.iter_depths({int(v) for v in keep})
    # the depth decoding (free of the GIL) on threads, in view order
    chunks = thread_map(points_of, sampled, decoders, "care-sample")
    points = np.concatenate(chunks) if chunks else np.zeros((0, 3))
    if len(points) > SAMPLE_POINTS:
        pick = np.random.default_rng(0).choice(len(points), SAMPLE_POINTS, replace=False)
        points = points[np.sort(pick)]
    return points, poses


def ensure_map_frame(
    store_path: Path, up_axis: UpAxis | None = None, floor_z: float | None = None
) -> MapFrame:
    """The store's map frame: the one in ``map_frame.json`` when ``up_axis`` is None (the
    default: keep what an earlier step found), else found anew with these options; found
    with ``auto`` when there is none yet. Written atomically, with the store's identity.

    A frame found for another store (copied in) is found again, with ``auto``; one that
    names no store (an earlier care's) again with the options it records, which give the
    same frame, so its maps stay current."""
    store = Store(store_path)
    path = store.path / MAP_FRAME_FILE
    record = map_frame_record(store.path)
    ours = record is not None and map_frame_owner(record, store.meta)
    if up_axis is None:
        if path.is_file() and (ours or record is None):  # unreadable: the reader says so
            return store.map_frame
        up_axis, floor_z = UpAxis.AUTO, None
        if record is not None and not ours:
            up_axis, floor_z = _unstamped_options(record)
    options = {"up_axis": up_axis.value, "floor_z": floor_z}
    if ours and record is not None and record.get("options") == options:
        return store.map_frame
    points, poses = sample_points(store)
    frame = estimate_map_frame(points, poses, up_axis=up_axis, floor=floor_z)
    atomic_write_text(path, map_frame_json(frame, options, store))
    return frame


def _unstamped_options(record: dict) -> tuple[UpAxis, float | None]:
    """The options a map frame of an earlier care (naming no store) was found with, to find
    it again the same way; ``auto`` for another store's frame, or options not understood."""
    options = record.get("options")
    if MAP_FRAME_STORE_FIELD in record or not isinstance(options, dict):
        return UpAxis.AUTO, None
    try:
        floor = options.get("floor_z")
        up: Any = options.get("up_axis")  # any JSON value: not a member is a ValueError
        return UpAxis(up), None if floor is None else float(floor)
    except (TypeError, ValueError):
        return UpAxis.AUTO, None


@contextlib.contextmanager
def reframed(
    store_path: Path, up_axis: UpAxis | None = None, floor_z: float | None = None
) -> Iterator[MapFrame]:
    """:func:`ensure_map_frame` for the block's work; if the block fails, the frame file is
    put back as it was (or removed, if this call made it).

    A frame asked for anew is a change to the store, and a command that fails must leave
    the store as it found it: a frame that made the build fail (a floor far from the depth)
    would otherwise stay and fail every later command. A kill between the two leaves the
    new frame with the old maps, which record the frame they were built in
    (:func:`store_stamp`) and so are rebuilt rather than read in the wrong frame.
    """
    path = Path(store_path) / MAP_FRAME_FILE
    before = path.read_text() if path.is_file() else None
    try:
        yield ensure_map_frame(store_path, up_axis, floor_z)
    except BaseException:
        now = path.read_text() if path.is_file() else None
        if now != before:
            if before is None:
                path.unlink(missing_ok=True)
            else:
                atomic_write_text(path, before)
        raise


MIN_BAND_SHARE = 0.3
"""Least share of the sampled depth points between the floor and the top of a map's height
band; below it the map frame (or the band) is wrong and the map would be a slice of the scene
(a y-down trajectory read as z-up keeps a fifth of the room, the first release's bug)."""


def check_height_band(store: Store, z_min: float, z_max: float, decoders: int = DECODERS) -> float:
    """The share of sampled depth points between the floor (or ``z_min`` below it) and
    ``z_max`` in the map frame, or one clear error when it is below :data:`MIN_BAND_SHARE`."""
    from care_maps.core.errors import FuseError

    points, _ = sample_points(store, decoders)
    frame = store.map_frame
    z = points @ frame.map_from_world[2, :3] + frame.map_from_world[2, 3]
    lo, hi = min(z_min, 0.0) - 0.1, max(z_max, 0.0)  # the floor, with its noise
    share = float(np.mean((z >= lo) & (z <= hi))) if len(z) else 0.0
    if share < MIN_BAND_SHARE:
        msg = (
            f"{store.path}: only {share:.0%} of the depth points lie between z = {lo} and "
            f"{hi} m of the map frame ({frame.describe()}); the up axis or floor is wrong: "
            "pass --up-axis (the world axis that points up) and --floor-z, or widen the band"
        )
        raise FuseError(msg)
    return share


def store_stamp(store: Store) -> bytes:
    """What a map records of the store it was built from (:attr:`care_maps.core.store.Store.stamp`)."""
    return store.stamp
