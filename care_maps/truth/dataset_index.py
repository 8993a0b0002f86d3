"""Reading a dataset's ``index.json``: the one reader for every stage that walks a dataset.

``care sample make`` writes it (:func:`care_maps.world.record.make_dataset`): ``{"recordings": [...]}``
with one entry per scene, each naming its ``recording`` relative to the dataset directory.
Hand-written indexes may also be a bare list of entries or of paths, use ``scenes`` for
``recordings`` or ``path`` for ``recording``, and name a ``store`` directory. An entry's
``skipped`` flag only says that ``care sample make`` found the recording up to date: it is a
recording like any other. An entry may name its ground truth: ``gt`` (a file or folder,
relative to the dataset directory, in any format ``care eval --help`` lists), ``gt_format``,
``gt_transform`` (16 numbers, row-major, or a file of them) and ``gt_class_map``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from care_maps.core.errors import WorldError

__all__ = ["INDEX_NAME", "IndexEntry", "read_index"]

INDEX_NAME = "index.json"


@dataclass(frozen=True)
class IndexEntry:
    """One recording of a dataset: its name, path, and the store the index names (if any)."""

    name: str
    recording: Path
    store: Path | None = None
    gt: Path | None = None
    """Ground truth named by the entry (else it is looked for beside the recording)."""
    gt_format: str | None = None
    gt_transform: str | list | None = None
    gt_class_map: str | None = None


def read_index(dataset: Path) -> list[IndexEntry]:
    """The entries of ``dataset/index.json``; a bad or empty index is one clear error."""
    index = Path(dataset) / INDEX_NAME
    try:
        doc = json.loads(index.read_text())
    except (OSError, json.JSONDecodeError) as err:
        msg = f"{index}: not a readable dataset index ({err}); re-run `care sample make`"
        raise WorldError(msg) from err
    entries = doc if isinstance(doc, list) else doc.get("recordings") or doc.get("scenes") or []
    out = []
    for entry in entries:
        item = {"recording": entry} if isinstance(entry, str) else dict(entry)
        rel = item.get("recording") or item.get("path")
        if rel is None:
            msg = f"{index}: entry {entry!r} names no recording ('recording' or 'path')"
            raise WorldError(msg)
        recording = Path(dataset) / rel
        store = Path(dataset) / item["store"] if item.get("store") else None
        transform = item.get("gt_transform")
        if isinstance(transform, str) and (Path(dataset) / transform).is_file():
            transform = str(Path(dataset) / transform)
        class_map = item.get("gt_class_map")
        if isinstance(class_map, str) and (Path(dataset) / class_map.split(":")[0]).is_file():
            class_map = str(Path(dataset) / class_map)
        out.append(
            IndexEntry(
                str(item.get("name") or Path(rel).stem),
                recording,
                store,
                gt=Path(dataset) / item["gt"] if item.get("gt") else None,
                gt_format=item.get("gt_format"),
                gt_transform=transform,
                gt_class_map=class_map,
            )
        )
    if not out:
        msg = f"{index}: lists no recordings"
        raise WorldError(msg)
    return out
