"""One fingerprint for every cache key: a hash of canonical JSON of what an output depends on.

Every "is this output current?" check in the project (a store against its recording and
ingest options, a map against its store and config, a query sidecar against its map, an
evaluation cache against its maps and ground truth) compares one of these strings. They
are built from *content* (file sizes and checksums, config values), never from paths or
modification times, so a dataset or an output folder copied to another directory or
machine is still current there, and the same inputs give the same key on every worker.

Only the standard library is imported: an up-to-date re-run must stay fast (no torch).
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import json
from collections.abc import Iterable
from pathlib import Path, PurePath
from typing import Any

__all__ = ["canonical_json", "config_fields", "config_json", "content_digest", "fingerprint"]

_CHUNK = 1 << 20


def _plain(obj: Any) -> Any:
    """``obj`` as JSON-able values: dataclasses as dicts, enums by value, paths as strings."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, enum.Enum):
        return _plain(obj.value)
    if isinstance(obj, dict):
        return {str(_plain(k)): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, PurePath):
        return str(obj)
    if isinstance(obj, bytes):
        return obj.decode(errors="replace")
    if obj is None or isinstance(obj, bool | int | float | str):
        return obj
    if hasattr(obj, "item"):  # numpy scalars
        return obj.item()
    return str(obj)


def canonical_json(obj: Any) -> str:
    """Compact JSON with sorted keys: equal values give equal strings on every machine."""
    return json.dumps(_plain(obj), sort_keys=True, separators=(",", ":"))


def fingerprint(*parts: Any, length: int = 64) -> str:
    """Hex sha256 (first ``length`` digits) of the canonical JSON of ``parts``."""
    return hashlib.sha256(canonical_json(list(parts)).encode()).hexdigest()[:length]


def config_fields(config: Any, exclude: Iterable[str] = ()) -> dict[str, Any]:
    """A config dataclass's fields as plain values, without ``exclude`` (the settings that
    change how an output is made, not what it is: ``overwrite``, memory budgets, batch
    sizes)."""
    fields = _plain(config)
    for name in exclude:
        fields.pop(name, None)
    return fields


def config_json(config: Any, exclude: Iterable[str] = ()) -> str:
    """:func:`config_fields` as canonical JSON (what a map records of the config it was
    built with, so a later command can reuse it)."""
    return canonical_json(config_fields(config, exclude))


def _reached_files(root: Path) -> list[Path]:
    """Every file under the directory ``root`` as a reader reaches it: links to files and to
    folders followed (a dataset shares its big ``image/`` folder by a link), each real folder
    entered once (a link back up the tree is not a loop), sorted by their relative names'
    parts (the order ``sorted(root.rglob("*"))`` gave, so a tree without links keeps its
    digest)."""
    found: list[tuple[tuple[str, ...], Path]] = []
    seen: set[tuple[int, int]] = set()

    def walk(folder: Path, rel: tuple[str, ...]) -> None:
        try:
            st = folder.stat()
        except OSError:
            return  # a dangling link: nothing a reader could read either
        if (st.st_dev, st.st_ino) in seen:
            return
        seen.add((st.st_dev, st.st_ino))
        for entry in folder.iterdir():
            parts = (*rel, entry.name)
            if entry.is_dir():  # follows a link to a folder
                walk(entry, parts)
            elif entry.is_file():  # follows a link to a file
                found.append((parts, entry))
        seen.discard((st.st_dev, st.st_ino))  # a folder linked twice (not a cycle) is read twice

    walk(root, ())
    return [path for _, path in sorted(found, key=lambda item: item[0])]


def content_digest(path: Path) -> dict[str, Any]:
    """``{"size", "blake2b"}`` of a file, or of every file of a directory (with their
    relative names, sorted): what a recording *is*, wherever it lies. Links are followed,
    to folders too: the digest covers what a reader of the folder reads, so a dataset whose
    ``image/`` is a link to shared storage is stale once an image there changes."""
    path = Path(path)
    is_dir = path.is_dir()
    files = _reached_files(path) if is_dir else [path]
    h = hashlib.blake2b(digest_size=16)
    size = 0
    for p in files:
        if is_dir:
            h.update(p.relative_to(path).as_posix().encode() + b"\0")
        with p.open("rb") as f:
            while chunk := f.read(_CHUNK):
                h.update(chunk)
                size += len(chunk)
    return {"size": size, "blake2b": h.hexdigest()}
