"""Ground truth from any supported format: detection, lookup beside a recording, the frame
transform and class renaming, and the sample world's export to every format.

Formats (:class:`GtFormat`): ``native`` (the sample world's ``.gt.json`` + ``.gt.parquet``),
``annotations`` (JSON / YAML / CSV boxes), ``ply`` (labelled point cloud or mesh + class
table), ``scannet``, ``matterport``, ``replica``. See each module of :mod:`care_maps.truth.formats`.
"""

from __future__ import annotations

import csv
import enum
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from care_maps.core.errors import GroundTruthError
from care_maps.truth.formats.annotations import ANNOTATION_SUFFIXES
from care_maps.truth.model import GroundTruth

__all__ = [
    "EXPORT_FORMATS",
    "MATTERPORT_FOLDERS",
    "GtFormat",
    "detect_format",
    "export_ground_truth",
    "find_beside",
    "inside_paths",
    "parse_transform",
    "read_class_map",
    "read_ground_truth",
]


class GtFormat(enum.StrEnum):
    """A ground-truth file format."""

    NATIVE = "native"
    ANNOTATIONS = "annotations"
    PLY = "ply"
    SCANNET = "scannet"
    MATTERPORT = "matterport"
    REPLICA = "replica"


EXPORT_FORMATS = ("native", "json", "yaml", "csv", "ply", "scannet", "matterport", "replica")
"""What ``care sample make --gt-formats`` writes (json, yaml and csv are annotation files)."""


def _stem(recording: Path) -> str:
    recording = Path(recording)
    return recording.stem if recording.suffix else recording.name


MATTERPORT_FOLDERS = ("region_segmentations", "house_segmentations")
"""The folders of a Matterport3D house that hold its ground truth."""


def inside_paths(folder: Path) -> list[tuple[Path, GtFormat]]:
    """Ground truth inside a dataset folder read as one recording, as the dataset ships it
    there: a ScanNet scene's annotation (``<scene>.aggregation.json`` and its mesh and
    segments) beside the frames exported into the scene folder, or a Matterport3D house's
    segmentations beside its undistorted images (unzipped in the house, in
    ``<house>/<house>/``, or into a folder named after the zip)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = [(p, GtFormat.SCANNET) for p in sorted(folder.glob("*.aggregation.json"))[:1]]
    houses = (folder, folder / folder.name, folder / MATTERPORT_FOLDERS[0] / folder.name)
    found += [
        (house, GtFormat.MATTERPORT)
        for house in houses
        if any(next((house / name).glob("*.ply"), None) for name in MATTERPORT_FOLDERS)
    ][:1]
    return found


def beside_paths(recording: Path) -> list[tuple[Path, GtFormat]]:
    """Where ground truth is looked for beside a recording, in order of preference; for a
    dataset folder, then inside it (:func:`inside_paths`)."""
    recording = Path(recording)
    stem, folder = _stem(recording), recording.parent
    return [
        (folder / f"{stem}.gt.json", GtFormat.NATIVE),
        *(
            (folder / f"{stem}.annotations{ext}", GtFormat.ANNOTATIONS)
            for ext in ANNOTATION_SUFFIXES
        ),
        (folder / f"{stem}.labels.ply", GtFormat.PLY),
        (folder / f"{stem}.scannet", GtFormat.SCANNET),
        (folder / f"{stem}.matterport", GtFormat.MATTERPORT),
        (folder / f"{stem}.replica", GtFormat.REPLICA),
        *inside_paths(recording),
    ]


def find_beside(recording: Path) -> tuple[Path, GtFormat] | None:
    """The first ground truth found beside ``recording`` by name, or None."""
    for path, fmt in beside_paths(recording):
        if path.exists():
            return path, fmt
    return None


def detect_format(path: Path) -> GtFormat:
    """The format of a ground-truth file or folder, from its name and, for a PLY, its header."""
    path = Path(path)
    name = path.name
    if path.is_dir():
        if (path / "region_segmentations").is_dir() or (path / "house_segmentations").is_dir():
            return GtFormat.MATTERPORT
        if (path / "mesh_semantic.ply").is_file() or (
            path / "habitat" / "mesh_semantic.ply"
        ).is_file():
            return GtFormat.REPLICA
        if any(path.glob("*_vh_clean_2.ply")):
            return GtFormat.SCANNET
        msg = f"{path}: a folder but not a ScanNet scene, Matterport3D house or Replica scene"
        raise GroundTruthError(msg)
    if name.endswith((".gt.json", ".gt.parquet")):
        return GtFormat.NATIVE
    if name.endswith(("_vh_clean_2.ply", ".aggregation.json", ".segs.json")):
        return GtFormat.SCANNET
    if name in ("mesh_semantic.ply", "info_semantic.json"):
        return GtFormat.REPLICA
    if name.endswith((".semseg.json", ".fsegs.json", ".house")) or path.parent.name in (
        "region_segmentations", "house_segmentations",
    ):  # fmt: skip
        return GtFormat.MATTERPORT
    suffix = path.suffix.lower()
    if suffix in ANNOTATION_SUFFIXES:
        return GtFormat.ANNOTATIONS
    if suffix == ".ply":
        return GtFormat.PLY
    msg = (
        f"{path}: unknown ground-truth format; give a .gt.json, an annotation file (.json, .yaml, "
        ".csv), a labelled .ply, a ScanNet scene, a Matterport3D house or a Replica scene"
    )
    raise GroundTruthError(msg)


def read_ground_truth(
    path: Path,
    fmt: GtFormat | str | None = None,
    *,
    transform: np.ndarray | None = None,
    class_map: dict[str, str] | None = None,
) -> GroundTruth:
    """Read ground truth in any format (detected unless ``fmt``), rename its classes by
    ``class_map`` and move it into the map frame by ``transform`` (4x4)."""
    path = Path(path)
    if not path.exists() and not path.name.endswith(".gt.json"):
        msg = f"{path}: no such ground-truth file or folder"
        raise GroundTruthError(msg)
    kind = GtFormat(fmt) if fmt else detect_format(path)
    if kind is GtFormat.NATIVE:
        from care_maps.truth.formats.native import read_native

        gt = read_native(path.with_name(path.name.replace(".gt.parquet", ".gt.json")))
    elif kind is GtFormat.ANNOTATIONS:
        from care_maps.truth.formats.annotations import read_annotations

        gt = read_annotations(path)
    elif kind is GtFormat.PLY:
        from care_maps.truth.formats.labelled_ply import read_labelled_ply

        gt = read_labelled_ply(path)
    elif kind is GtFormat.SCANNET:
        from care_maps.truth.formats.scannet import read_scannet

        gt = read_scannet(path)
    elif kind is GtFormat.MATTERPORT:
        from care_maps.truth.formats.matterport import read_matterport

        gt = read_matterport(path)
    else:
        from care_maps.truth.formats.replica import read_replica

        gt = read_replica(path)
    if gt.instances.num_rows == 0:
        msg = f"{path}: the ground truth lists no instances"
        raise GroundTruthError(msg)
    if class_map:
        gt = gt.renamed(class_map)
        if gt.instances.num_rows == 0:
            msg = f"{path}: the class map drops every instance"
            raise GroundTruthError(msg)
    if transform is not None:
        gt = gt.transformed(transform)
    return gt


def parse_transform(text: str | Path) -> np.ndarray:
    """A 4x4 from 16 comma/space-separated numbers (row-major) or a file holding them
    (``.npy``, ``.json`` (nested or flat list), or text such as ScanNet's ``axisAlignment = ...``)."""
    text = str(text)
    path = Path(text)
    values: list[float]
    try:
        if path.suffix == ".npy" and path.is_file():
            values = np.load(path).reshape(-1).tolist()
        elif path.is_file():
            raw = path.read_text()
            if path.suffix == ".json":
                values = np.asarray(json.loads(raw), np.float64).reshape(-1).tolist()
            else:
                lines = [ln for ln in raw.splitlines() if ln.strip().startswith("axisAlignment")]
                raw = lines[0].split("=", 1)[1] if lines else raw
                values = [float(v) for v in raw.replace(",", " ").split()]
        else:
            values = [float(v) for v in text.replace(",", " ").split()]
    except (OSError, ValueError, json.JSONDecodeError) as err:
        msg = f"--gt-transform {text!r}: not 16 numbers nor a file of them ({err})"
        raise GroundTruthError(msg) from err
    if len(values) != 16:
        msg = f"--gt-transform {text!r}: {len(values)} numbers; give a 4x4 (16 numbers, row-major)"
        raise GroundTruthError(msg)
    return np.asarray(values, np.float64).reshape(4, 4)


def read_class_map(spec: str | Path) -> dict[str, str]:
    """Class renaming from ``FILE`` (two columns: from, to) or ``FILE:FROM:TO`` (named columns
    of a TSV/CSV with a header, e.g. ``scannetv2-labels.combined.tsv:raw_category:nyu40class``).
    A row mapping to an empty name drops that class."""
    parts = str(spec).split(":")
    path, columns = (
        (Path(":".join(parts[:-2])), parts[-2:]) if len(parts) >= 3 else (Path(str(spec)), None)
    )
    try:
        text = path.read_text()
    except OSError as err:
        msg = f"--gt-class-map {spec}: cannot read {path} ({err.strerror or err})"
        raise GroundTruthError(msg) from err
    first = text.splitlines()[0] if text.strip() else ""
    delimiter = "\t" if "\t" in first else ","
    rows = list(csv.reader(text.splitlines(), delimiter=delimiter))
    if columns is None:
        return {
            r[0].strip(): (r[1].strip() if len(r) > 1 else "")
            for r in rows
            if r and not r[0].startswith("#")
        }
    header = rows[0] if rows else []
    missing = [c for c in columns if c not in header]
    if missing:
        msg = f"--gt-class-map {spec}: {path.name} has no column {missing[0]!r} (has {', '.join(header)})"
        raise GroundTruthError(msg)
    a, b = header.index(columns[0]), header.index(columns[1])
    return {r[a].strip(): r[b].strip() for r in rows[1:] if len(r) > max(a, b)}


def export_ground_truth(gt: GroundTruth, recording: Path, formats: Sequence[str]) -> list[Path]:
    """Write ``gt`` beside ``recording`` in each of ``formats`` (:data:`EXPORT_FORMATS`), under
    the names :func:`find_beside` looks for. Instances the recording never saw
    (``info['unseen_instances']``) are left out of every format but the native one."""
    bad = [f for f in formats if f not in (*EXPORT_FORMATS, "all")]
    if bad:
        msg = f"--gt-formats {','.join(bad)}: choose from {', '.join(EXPORT_FORMATS)} or all"
        raise GroundTruthError(msg)
    todo = EXPORT_FORMATS if "all" in formats else tuple(formats)
    recording = Path(recording)
    stem, folder = _stem(recording), recording.parent
    seen = gt.without_instances(gt.info.get("unseen_instances") or [])
    out: list[Path] = []
    for fmt in todo:
        if fmt == "native":
            from care_maps.truth.formats.native import write_native

            write_native(gt, recording)
            out += [folder / f"{stem}.gt.json", folder / f"{stem}.gt.parquet"]
        elif fmt in ("json", "yaml", "csv"):
            from care_maps.truth.formats.annotations import write_annotations

            out += write_annotations(seen, folder / f"{stem}.annotations.{fmt}")
        elif fmt == "ply":
            from care_maps.truth.formats.labelled_ply import write_labelled_ply

            out += write_labelled_ply(seen, folder / f"{stem}.labels.ply")
        elif fmt == "scannet":
            from care_maps.truth.formats.scannet import write_scannet

            out += write_scannet(seen, folder / f"{stem}.scannet", stem)
        elif fmt == "matterport":
            from care_maps.truth.formats.matterport import write_matterport

            out += write_matterport(seen, folder / f"{stem}.matterport", stem)
        elif fmt == "replica":
            from care_maps.truth.formats.replica import write_replica

            out += write_replica(seen, folder / f"{stem}.replica")
    return out
