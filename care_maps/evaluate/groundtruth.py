"""Where each scene's ground truth comes from, and the checks that it can label the scene's map.

A scene's ground truth is the file named for it (``--gt`` or an index entry's ``gt``), or else
the first found beside its recording by name (:func:`care_maps.truth.load.find_beside`), in any format
of :mod:`care_maps.truth.load`. It is matched to the map frame by an explicit 4x4 (``--gt-transform``;
a scan in another frame needs it), or, for a dataset's own ground truth inside the dataset
folder that is the recording, by the store's ``map_from_world`` (it shares the recording's
world frame); its classes may be renamed (``--gt-class-map``).

Before anything is evaluated every scene's ground truth is read and checked (classes the
map's vocabulary lacks, no overlap with the map's points), so a bad scene stops the run
with one line before any result is written.
"""

from __future__ import annotations

import contextlib
import enum
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from care_maps.core.errors import CareError, EvalError, GroundTruthError
from care_maps.core.keys import VOCABULARY_KEY
from care_maps.core.maps import MapKind
from care_maps.core.store import read_map_frame, read_table
from care_maps.query.map import MAP_TABLES
from care_maps.truth.formats.matterport import CATEGORY_MAPPING
from care_maps.truth.formats.native import gt_paths
from care_maps.truth.formats.scannet import scannet_files
from care_maps.truth.load import (
    MATTERPORT_FOLDERS,
    GtFormat,
    beside_paths,
    detect_format,
    find_beside,
    inside_paths,
    parse_transform,
    read_class_map,
    read_ground_truth,
)
from care_maps.truth.model import GroundTruth

__all__ = ["GtSource", "UnknownClasses", "check_ground_truth", "gt_files", "scene_points"]


class UnknownClasses(enum.StrEnum):
    """What to do with ground-truth classes the map's vocabulary lacks."""

    REFUSE = "refuse"
    """Stop with the list of missing classes (the default: a silent drop changes the task)."""
    IGNORE = "ignore"
    """Leave their instances out of the queries (they are listed in the report header)."""


@dataclass(frozen=True)
class GtSource:
    """How to find and read one scene's ground truth."""

    path: Path | None = None
    """The file or folder; None: look beside the recording by name."""
    fmt: GtFormat | None = None
    """Its format; None: detect it."""
    transform: tuple[float, ...] | None = None
    """Row-major 4x4 taking the ground truth's frame to the map frame."""
    class_map: str | None = None
    """A class-renaming table (``FILE`` or ``FILE:FROM:TO``, see :func:`care_maps.truth.load.read_class_map`)."""

    @classmethod
    def of(
        cls,
        path: Path | str | None = None,
        fmt: str | None = None,
        transform: str | Path | list | None = None,
        class_map: str | None = None,
    ) -> GtSource:
        """From user input (CLI options or an index entry), checked."""
        try:
            kind = GtFormat(fmt) if fmt else None
        except ValueError as err:
            msg = f"--gt-format {fmt!r}: choose one of {', '.join(f.value for f in GtFormat)}"
            raise GroundTruthError(msg) from err
        matrix: np.ndarray | None
        if isinstance(transform, list | tuple):
            matrix = np.asarray(transform, np.float64)
            if matrix.size != 16:
                msg = f"gt_transform {transform!r}: give 16 numbers (a row-major 4x4)"
                raise GroundTruthError(msg)
        else:
            matrix = parse_transform(transform) if transform else None
        return cls(
            Path(path) if path else None,
            kind,
            tuple(float(v) for v in matrix.reshape(-1)) if matrix is not None else None,
            str(class_map) if class_map else None,
        )

    def resolve(self, recording: Path) -> tuple[Path, GtFormat | None]:
        """The ground truth's path and format (None: detect) for ``recording``."""
        if self.path is not None:
            return self.path, self.fmt
        found = find_beside(recording)
        if found is None:
            names = ", ".join(p.name for p, _ in beside_paths(recording))
            msg = (
                f"{recording}: no ground truth beside it (looked for {names}); pass --gt FILE "
                "(any format of `care eval --help`) or name it in index.json ('gt')"
            )
            raise GroundTruthError(msg)
        return found[0], self.fmt or found[1]

    def available(self, recording: Path) -> bool:
        """Ground truth is named, or found beside ``recording`` by name."""
        return self.path is not None or find_beside(recording) is not None

    def in_world_frame(self, recording: Path) -> bool:
        """The ground truth is the dataset's own, found inside the dataset folder that is the
        recording (:func:`care_maps.truth.load.inside_paths`), with no ``transform``: it is in the
        recording's world frame (a ScanNet scan and its poses, a Matterport3D house and its
        cameras share one), not in the map frame that fusion finds."""
        if self.path is not None or self.transform is not None:
            return False
        return find_beside(recording) in inside_paths(recording)

    def load(self, recording: Path, store: Path | None = None) -> GroundTruth:
        """The ground truth, in the map frame of ``store`` where it is in the recording's
        world frame (:meth:`in_world_frame`; given a store), else as read and transformed."""
        path, fmt = self.resolve(recording)
        transform = np.asarray(self.transform).reshape(4, 4) if self.transform else None
        if transform is None and store is not None and self.in_world_frame(recording):
            transform = read_map_frame(store).map_from_world
        mapping = read_class_map(self.class_map) if self.class_map else None
        return read_ground_truth(path, fmt, transform=transform, class_map=mapping)


def gt_files(source: GtSource, recording: Path) -> list[Path]:
    """The files a scene's ground truth is read from (for the result cache's key): a folder's
    files (a Matterport3D house's segmentations, for any of its files), the native pair, a
    ScanNet scene's mesh, segments and aggregation, or the files beside a single file that
    share its scene name (its class table, rooms)."""
    try:
        path, fmt = source.resolve(recording)
    except CareError:
        return []
    if path.is_file() and path.parent.name in MATTERPORT_FOLDERS:
        path = path.parent.parent  # a Matterport3D file: the reader reads the whole house
    if path.name in ("mesh_semantic.ply", "info_semantic.json"):
        path = path.parent  # a Replica file: its habitat folder
    if path.is_dir() and any((path / name).is_dir() for name in MATTERPORT_FOLDERS):
        # a house: its segmentations and class table, not the images beside them (gigabytes)
        files = [p for name in MATTERPORT_FOLDERS for p in (path / name).rglob("*")]
        tables = [p / CATEGORY_MAPPING for p in (path, *path.parents)]
        return sorted(p for p in files if p.is_file()) + [p for p in tables if p.is_file()][:1]
    if path.is_dir():
        return sorted(p for p in path.rglob("*") if p.is_file())
    if fmt is GtFormat.NATIVE or path.name.endswith(".gt.json"):
        return list(gt_paths(path.with_name(path.name.removesuffix(".gt.json"))))
    if fmt is None:
        with contextlib.suppress(CareError):
            fmt = detect_format(path)
    if fmt is GtFormat.SCANNET:
        return list(scannet_files(path))  # not the scene's .sens beside them (gigabytes)
    scene = path.name.split(".")[0].removesuffix("_vh_clean_2").removesuffix("_vh_clean")
    return sorted(p for p in path.parent.iterdir() if p.is_file() and p.name.startswith(scene))


def scene_points(store: Path) -> np.ndarray:
    """(P, 3) float array of the store's ``scene_points.parquet``, the map's point cloud."""
    table = read_table(Path(store) / "scene_points.parquet", list("xyz"))
    return np.stack([table.column(c).to_numpy() for c in "xyz"], axis=1)


def _vocabulary(store: Path, kind: MapKind) -> tuple[str, ...]:
    path = store / f"{MAP_TABLES[kind]}.parquet"
    md = pq.read_schema(path).metadata or {}
    raw = md.get(VOCABULARY_KEY)
    return tuple(json.loads(raw)) if raw else ()


def check_ground_truth(
    gt: GroundTruth,
    *,
    where: str,
    store: Path,
    maps: tuple[MapKind, ...],
    label_distance: float,
    unknown: UnknownClasses,
) -> list[str]:
    """Refuse ground truth that cannot label this store's maps; return the classes left out.

    - classes no map vocabulary has: refused unless ``unknown`` is ``ignore`` (and always
      when no class at all is known);
    - no overlap: not one of the store's scene points lies on (or in) a ground-truth
      instance, which means another scene or another frame.
    """
    names = sorted(set(gt.instances.column("class_name").to_pylist()))
    left_out: set[str] = set()
    for kind in maps:
        path = store / f"{MAP_TABLES[kind]}.parquet"
        if not path.is_file():
            continue
        vocab = {n.strip().lower() for n in _vocabulary(store, kind)}
        missing = [n for n in names if n.strip().lower() not in vocab]
        if len(missing) == len(names):
            msg = (
                f"{where}: none of its {len(names)} classes ({', '.join(names[:8])}"
                f"{', ...' if len(names) > 8 else ''}) is in the {kind} map's vocabulary; "
                "rename them with --gt-class-map or rebuild the map with their names"
            )
            raise EvalError(msg)
        if missing and unknown is UnknownClasses.REFUSE:
            msg = (
                f"{where}: {len(missing)} class(es) not in the {kind} map's vocabulary: "
                f"{', '.join(repr(m) for m in missing[:10])}{', ...' if len(missing) > 10 else ''}; "
                "rename them with --gt-class-map FILE[:FROM:TO], add them to the vocabulary, "
                "or pass --gt-unknown-classes ignore to leave them out"
            )
            raise EvalError(msg)
        left_out |= set(missing)
    if (store / "scene_points.parquet").is_file():
        xyz = scene_points(store)
        if len(xyz) and not (gt.label_points(xyz, max_dist=label_distance) > 0).any():
            lo, hi = gt.bounds()
            msg = (
                f"{where}: does not overlap the map ({store}): no map point lies on a "
                f"ground-truth instance (map x,y,z {np.round(xyz.min(0), 2).tolist()}.."
                f"{np.round(xyz.max(0), 2).tolist()}, ground truth ({gt.frame} frame) "
                f"{np.round(lo, 2).tolist()}..{np.round(hi, 2).tolist()}); another scene, or "
                "another frame: pass --gt-transform"
            )
            raise EvalError(msg)
    return sorted(left_out)
