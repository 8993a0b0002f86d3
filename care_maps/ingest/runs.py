"""Several exploration runs of one place in one store (``care ingest RUN --out STORE --append``).

A building is explored in several runs, on several days, each localised in the same ``map``
frame (nav2 with AMCL, slam_toolbox in localisation mode). Appended to a store, a run keeps
its views' ids after the earlier runs' and its record in ``meta.json`` (``runs``:
:class:`care_maps.core.store.RunRecord`), so a map built from the store fuses every run, and
each view still says which run it came from.

Runs share one world frame, and the data must say so, not the frame's name alone:

- a run whose recording names another world frame than the store's is refused in one line
  naming both, unless :attr:`RunOptions.world_transform` places it (its world frame's pose
  in the store's, as ``static_transform_publisher`` takes it);
- where the new run's views overlap the earlier runs' (the robot came back to a place),
  their depths must agree when reprojected into each other
  (:func:`care_maps.geometry.consistency.pick_cross_pairs`, scored as the check of one
  recording's views): a run localised in a shifted or rotated map is refused with the
  figures, and ``--accept-geometry`` keeps it as given. A run that overlaps nothing cannot
  be checked, and the store's record says so.

The appended run must be encoded as the store was (the same encoder and options, vocabulary
and store encoding): features of two models cannot be fused.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from care_maps.core.encoders.base import HOW_OPTIONS
from care_maps.core.errors import IngestError
from care_maps.core.fingerprint import fingerprint
from care_maps.core.frames import Frame
from care_maps.core.outputs import (
    OutputKind,
    atomic_write_text,
    read_marker,
    record_table,
    write_marker,
)
from care_maps.core.store import (
    MAP_FRAME_FILE,
    MAP_FRAME_STORE_FIELD,
    STORE_OWN,
    RunRecord,
    Store,
    StoreMeta,
    StoreWriter,
    carried_meta,
    map_frame_owner,
    map_frame_record,
    run_records,
    source_record,
    store_identity,
)
from care_maps.geometry.consistency import (
    MIN_PAIRS,
    PASS_AGREE,
    Agreement,
    DepthSample,
    Hypothesis,
    agreement,
    pick_cross_pairs,
    subsample,
)
from care_maps.geometry.transforms import quaternion_to_matrix

__all__ = [
    "ALIGNMENT_VIEWS",
    "SHARED_CONFIG",
    "RunOptions",
    "WorldTransform",
    "append_frames",
    "append_lines",
    "appended_meta",
    "carry_maps",
    "check_alignment",
    "check_same_encoding",
    "check_same_names",
    "check_world_frame",
    "describe_alignment",
    "link_or_copy",
    "placed",
    "summed_counts",
]

ALIGNMENT_VIEWS = 48
"""Views of the new run (from the consistency sample) judged against the earlier runs' at
most: a bounded check whatever the runs' lengths."""

SHARED_CONFIG = ("encoder", "encoder_options", "vocabulary", "store_encoding")
"""The ingest options every run of a store shares (what its features and tables are made
with); the others (topics, selection, reading) are each run's own."""

_FLAG = "--world-transform"


@dataclass(frozen=True)
class WorldTransform:
    """The pose of a run's world frame in the store's world frame: ``x, y, z`` (metres) and
    the rotation as the quaternion ``qx, qy, qz, qw``, the order ROS's
    ``static_transform_publisher`` and ``geometry_msgs/Transform`` use."""

    xyz: tuple[float, float, float]
    xyzw: tuple[float, float, float, float]

    @classmethod
    def from_text(cls, text: str) -> WorldTransform:
        """``x,y,z,qx,qy,qz,qw``."""
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if len(values) != 7 or not np.isfinite(values).all():
            msg = f"{_FLAG} {text!r}: expected seven numbers x,y,z,qx,qy,qz,qw (the run's world frame in the store's)."
            raise IngestError(msg)
        norm = float(np.linalg.norm(values[3:]))
        if norm < 1e-6:
            msg = f"{_FLAG} {text!r}: the quaternion qx,qy,qz,qw is zero; the identity is 0,0,0,1."
            raise IngestError(msg)
        if abs(norm - 1.0) > 1e-3:  # not normalised here: a unit quaternion in another order?
            msg = (
                f"{_FLAG} {text!r}: the quaternion qx,qy,qz,qw has length {norm:.4g}, not 1; "
                "give a unit quaternion, x,y,z first and w last (the identity is 0,0,0,1)."
            )
            raise IngestError(msg)
        x, y, z, *q = values
        return cls((x, y, z), (q[0], q[1], q[2], q[3]))

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) ``store_world_from_run_world``."""
        T = np.eye(4)
        T[:3, :3] = quaternion_to_matrix(np.asarray(self.xyzw))
        T[:3, 3] = self.xyz
        return T

    def as_json(self) -> list[float]:
        return [*self.xyz, *self.xyzw]


@dataclass(frozen=True)
class RunOptions:
    """Whether the recording replaces the store or is added to it as one more run."""

    append: bool = False
    """Add the recording to the store as one more exploration run of the same place: the
    store's views are kept and the new ones follow (the maps are built again after)."""
    world_transform: WorldTransform | None = None
    """Pose of this recording's world frame in the store's, x,y,z,qx,qy,qz,qw: applied to
    every view's pose, for a run recorded in another frame."""


def placed(frames: Iterator[Frame], transform: WorldTransform | None) -> Iterator[Frame]:
    """``frames`` with their poses moved into the store's world frame."""
    if transform is None:
        yield from frames
        return
    T = transform.matrix
    for frame in frames:
        yield replace(frame, cam_to_world=T @ np.asarray(frame.cam_to_world, np.float64))


def check_same_encoding(store: Store, recorded: dict[str, Any], where: str) -> None:
    """Refuse a run encoded otherwise than ``store`` (``recorded``: the new run's recorded
    config): one line naming the first option that differs."""
    for name in SHARED_CONFIG:
        ours, theirs = store.meta.config.get(name), recorded.get(name)
        if ours != theirs:
            if isinstance(ours, dict) and isinstance(theirs, dict):  # the encoder's options
                differ = [
                    k
                    for k in sorted({*ours, *theirs} - set(HOW_OPTIONS))
                    if ours.get(k) != theirs.get(k)
                ]
                if not differ:  # how the model runs (device, batch size) may differ
                    continue
                name = differ[0]
                ours, theirs = ours.get(name), theirs.get(name)
            option = f"--{name.replace('_', '-')}"
            msg = (
                f"{where}: cannot be appended to {store.path}: its {name} would be {theirs!r}, "
                f"the store's is {ours!r}; pass the store's {option} (every run of a store is "
                "encoded alike), or ingest it into a store of its own."
            )
            raise IngestError(msg)


def check_same_names(
    store: Store, vocabulary: Sequence[str], label_names: Sequence[str], where: str
) -> None:
    """Refuse a run whose class names differ from ``store``'s: a vocabulary taken from the
    recording's labels (no ``--vocabulary``), or the label ids' names, would index another
    list of names than the store's text table and labels do."""
    for what, ours, theirs in (
        ("class names", tuple(store.meta.vocabulary), tuple(vocabulary or ())),
        ("label names", tuple(store.meta.label_names), tuple(label_names or ())),
    ):
        if ours != theirs:
            msg = (
                f"{where}: cannot be appended to {store.path}: its {what} are "
                f"{_names(theirs)}, the store's are {_names(ours)}; every run of a store is "
                "labelled alike: give both the store's --vocabulary, or ingest it into a "
                "store of its own."
            )
            raise IngestError(msg)


def _names(names: tuple[str, ...]) -> str:
    shown = ",".join(names[:6]) + (f",... ({len(names)})" if len(names) > 6 else "")
    return repr(shown) if names else "none"


def check_world_frame(
    store: Store, world_frame: str | None, transform: WorldTransform | None, where: str
) -> None:
    """Refuse a run recorded in another world frame than the store's, unless placed."""
    ours = store.meta.world_frame
    if transform is None and world_frame != ours:
        msg = (
            f"{where}: its views are in world frame {world_frame!r} but {store.path}'s are in "
            f"{ours!r}; record the run localised in {ours!r} (AMCL, slam_toolbox localisation), "
            f"or place it with {_FLAG} x,y,z,qx,qy,qz,qw ({world_frame!r} in {ours!r})."
        )
        raise IngestError(msg)


def _earlier_samples(store: Store, new: Sequence[DepthSample]) -> list[DepthSample]:
    """The earlier runs' views nearest each of ``new`` in position (one each, distinct),
    subsampled as the check takes them: only those views are decoded."""
    poses = store.poses(in_map=False)
    if not len(poses) or not new:
        return []
    wanted: set[int] = set()
    for sample in new:
        distance = np.linalg.norm(poses[:, :3, 3] - sample.pose[:3, 3], axis=1)
        wanted.add(int(np.argmin(distance)))
    return [
        subsample(frame.depth_m, frame.K, frame.cam_to_world, frame.stamp_ns)
        for _, frame in store.iter_frames(extras=False, view_ids=wanted, in_map=False)
    ]


def check_alignment(
    store: Store, new: Sequence[DepthSample], where: str, *, accept: bool
) -> dict[str, Any]:
    """The new run's views (``new``: its consistency sample, poses in the store's frame)
    against the earlier runs' where they overlap: the record of what was found, or one line
    refusing a run whose depths disagree with the store's (unless ``accept``)."""
    if len(new) > ALIGNMENT_VIEWS:
        keep = np.unique(np.linspace(0, len(new) - 1, ALIGNMENT_VIEWS).round().astype(int))
        new = [new[k] for k in keep]
    earlier = _earlier_samples(store, new)
    pairs = pick_cross_pairs(new, earlier, ALIGNMENT_VIEWS)
    found: Agreement = agreement([*new, *earlier], pairs, Hypothesis("as given"))
    record: dict[str, Any] = {"status": "unchecked", **found.as_json()}
    if found.pairs < MIN_PAIRS:
        record["reason"] = (
            f"{found.pairs} overlapping view pairs with the earlier runs (needs {MIN_PAIRS})"
        )
        return record
    if found.agree >= PASS_AGREE:
        return {**record, "status": "agree"}
    if not accept:
        msg = (
            f"{where}: its views disagree with {store.path}'s where they overlap (median "
            f"{found.agree:.0%} of reprojected depth agrees over {found.pairs} pairs, "
            f"{PASS_AGREE:.0%} needed): the runs are not localised in one world frame; place "
            f"the run with {_FLAG} x,y,z,qx,qy,qz,qw, or pass --accept-geometry to keep it as given."
        )
        raise IngestError(msg)
    return {**record, "status": "disagree", "accepted": True}


def summed_counts(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """Two runs' counts added, key by key (nested counts by reason too)."""
    out: dict[str, Any] = dict(a)
    for key, value in b.items():
        if isinstance(value, dict):
            out[key] = summed_counts(out.get(key) or {}, value)
        elif isinstance(value, int | float) and isinstance(out.get(key, 0), int | float):
            out[key] = out.get(key, 0) + value
        else:
            out.setdefault(key, value)
    return out


def appended_meta(
    base: Store,
    run: dict[str, Any],
    num_views: int,
    alignment: dict[str, Any],
    options: RunOptions,
) -> dict[str, Any]:
    """``meta.json`` of ``base`` with the run whose own metadata is ``run`` appended
    (``num_views``: the new store's): the first run's fields as they were, the counts of all
    runs, a fingerprint of every run's, and the runs' records."""
    earlier = run_records(base.meta)
    added = RunRecord(
        first_view=base.num_views,
        num_views=num_views - base.num_views,
        source=source_record(run["source"]),
        fingerprint=run["fingerprint"],
        request_fingerprint=run.get("request_fingerprint"),
        world_frame=run.get("world_frame"),
        camera_frame=run.get("camera_frame"),
        world_transform=None
        if options.world_transform is None
        else options.world_transform.as_json(),
        counts=run.get("counts") or {},
        geometry=run.get("geometry"),
        alignment=alignment,
    )
    runs = [*earlier, added]
    meta = carried_meta(base.meta)
    counts: dict[str, Any] = {}
    for each in runs:
        counts = summed_counts(counts, each.counts)
    return {
        **meta,
        "counts": counts,
        "fingerprint": fingerprint(*(r.fingerprint for r in runs)),
        "request_fingerprint": None,
        "runs": [asdict(r) for r in runs],
    }


def link_or_copy(src: str, dst: str) -> None:
    """``dst`` a hard link to ``src`` (the maps are replaced by renames, never changed in
    place), or a copy where the file system has no links."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def carry_maps(old: Path, new: Path) -> list[str]:
    """Carry the maps of the store ``old`` into ``new``, the store with one more run not yet
    in its place (all but the store's own files, :data:`STORE_OWN`): linked, listed in ``new``'s
    marker as in ``old``'s, and the map frame stamped with ``new``'s identity, the frame
    unchanged, so ``care fuse grid`` adds the new views to the grid in the frame it was built
    in (:mod:`care_maps.fuse.grid_state`); the maps it cannot grow are built again, as stale.
    Returns the names carried."""
    names = sorted(p.name for p in old.iterdir() if p.name not in STORE_OWN and p.name[0] != ".")
    for name in names:
        if (old / name).is_dir():
            shutil.copytree(old / name, new / name, copy_function=link_or_copy)
        else:
            link_or_copy(str(old / name), str(new / name))
    recorded = (read_marker(old) or {}).get("tables", {})
    write_marker(
        new,
        OutputKind.STORE,
        {k: v for k, v in recorded.items() if k.split("/")[0] in names},
    )
    record = map_frame_record(new)
    if record is not None and map_frame_owner(record, StoreMeta.read(old)):
        record[MAP_FRAME_STORE_FIELD] = store_identity(StoreMeta.read(new))
        atomic_write_text(new / MAP_FRAME_FILE, json.dumps(record, indent=2))
        if MAP_FRAME_FILE in recorded:
            record_table(new / MAP_FRAME_FILE)
    return names


def append_frames(
    store: Path,
    frames: Sequence[Frame],
    features: Sequence[np.ndarray] | np.ndarray | None,
    *,
    name: str,
    fingerprint: str,
) -> None:
    """Add ``frames`` (posed in the store's world frame, with their feature maps from the
    store's encoder) to ``store`` as one more run named ``name``, as ``care ingest --append``
    adds a recording once it is read and checked: the earlier views copied as stored, the
    maps carried over (the grid grows from them, :mod:`care_maps.fuse.grid_state`),
    committed in one step. For views made for a store (rendered where ``care explore``
    says, a benchmark's): ``fingerprint`` names what they are, so a store is grown by them
    once."""
    base = Store(store)
    with StoreWriter(base.path, base.meta.encoder, encoding=base.views_encoding) as writer:
        writer.copy_views(base)
        for i, frame in enumerate(frames):
            writer.add(frame, None if features is None else np.asarray(features[i], np.float32))
        if base.table_path("text").is_file():
            writer.set_text(*base.text_embeddings())
        run = {
            "source": {"name": name},
            "fingerprint": fingerprint,
            "counts": {"frames": len(frames)},
        }
        unchecked = {"status": "unchecked", "reason": "views made for the store, not recorded"}
        meta = appended_meta(base, run, writer.num_views, unchecked, RunOptions())
        writer.commit(meta, replacing=lambda: carry_maps(base.path, writer.tmp))


def describe_alignment(found: dict[str, Any]) -> str:
    """How a run's views agreed with the earlier runs' (:func:`check_alignment`'s record)."""
    share = f"{found.get('agree', 0):.0%} of reprojected depth over {found.get('pairs_judged', 0)} view pairs"
    status = found.get("status")
    if status == "agree":
        return f"agrees with the earlier runs where they overlap: {share}"
    if status == "disagree":
        return f"disagrees with the earlier runs ({share}), kept as given (--accept-geometry)"
    return f"not checked against the earlier runs: {found.get('reason', 'no overlap')}"


def append_lines(
    store: Path,
    sample: Sequence[DepthSample],
    world_frame: str | None,
    options: RunOptions,
    where: str,
    *,
    accept: bool,
) -> list[str]:
    """``care topics REC --store STORE``: what ``care ingest REC --out STORE --append``
    would say of the recording's first views (``sample``, placed by ``options``)."""
    opened = Store(store)
    runs = len(run_records(opened.meta))
    try:
        check_world_frame(opened, world_frame, options.world_transform, where)
        found = check_alignment(opened, sample, where, accept=accept)
    except IngestError as err:
        return [f"ingest --append would refuse: {err}"]
    return [f"  {'runs':<12} run {runs + 1} of {store}: {describe_alignment(found)}"]
