"""Output safety: what a ``care`` command may replace, one writer per output, no leftovers.

Every directory a command creates (a store, an evaluation, a ``care run`` output) carries
:data:`MARKER`, a small JSON file naming its kind. A command replaces or writes into an
existing directory only when it carries the marker of the right kind; an ``--out`` that is
a regular file, a directory holding anything else, the input recording, a path inside it
or one of its ancestors is refused in one line before any work (:func:`check_output`).

One writer at a time: :func:`output_lock` takes an advisory ``fcntl.flock`` on a hidden
sibling ``.<name>.lock``; a second writer waits for the first and then finds its work done.

Temporaries are named ``.<name>.tmp-<pid>`` (also ``.old-<pid>``, ``.building-<pid>``;
:func:`temporary`, with ``<name>`` cut short and a hash added when the whole would pass the
file system's name limit), removed on every error path (:func:`staged`), and those of
processes that no longer run are swept by the next run in the same place, an up-to-date one
too (:func:`sweep_stale`, from :func:`check_output`), except the previous version
``.<name>.old-<pid>`` of an output that is itself missing: it is put back. An output whose
name or path is too long for its temporaries is refused before any work (:func:`check_length`).

An output of many files (an evaluation) changes as one unit (:func:`whole_output`): the new
version is staged whole in ``.<name>.tmp-<pid>`` and swapped in (:func:`swap_in`), so a kill
at any instant leaves the old version or the new, never a mix.

Integrity: :func:`file_digest` (size + BLAKE2b) is the one checksum of a table; a store's
``meta.json`` lists its tables' digests at commit, and tables written into a marked
directory later (maps) are listed in the marker (:func:`record_table`). :func:`damaged`
compares them with what is on disk.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import hashlib
import json
import os
import re
import shutil
import sys
from collections.abc import Callable, Iterable, Iterator
from enum import StrEnum
from pathlib import Path
from typing import Any, TypeGuard

from care_maps.core.errors import CareError, OutputError

__all__ = [
    "MARKER",
    "NAME_MAX",
    "PATH_MAX",
    "REBUILD",
    "OutputKind",
    "Staging",
    "atomic_write_text",
    "check_file_output",
    "check_length",
    "check_output",
    "damaged",
    "disk_full",
    "evaluation_output",
    "file_digest",
    "is_ours",
    "output_lock",
    "owned_output",
    "pid_alive",
    "rebuild_hint",
    "record_table",
    "refuse_link",
    "remove_path",
    "restore_stale",
    "seal",
    "staged",
    "swap_in",
    "sweep_stale",
    "temporary",
    "whole_output",
    "write_atomic",
    "write_marker",
]

MARKER = "care-output.json"
"""File whose presence marks a directory as written by ``care`` (and of which kind)."""


class OutputKind(StrEnum):
    """What a directory ``care`` wrote holds (its marker's ``kind``)."""

    STORE = "store"
    """A feature store and the maps built in it (``care ingest``, ``care fuse``)."""
    DATASET = "dataset"
    """A sample-world dataset (``care sample make``)."""
    EVAL = "eval"
    """An evaluation's tables and report (``care eval``)."""
    RUN = "run"
    """``care run``'s stores, Rerun files and evaluation."""


class Staging(StrEnum):
    """What a temporary beside an output holds (the ``<tag>`` of ``.<name>.<tag>-<pid>``)."""

    TMP = "tmp"
    """A new version being written."""
    OLD = "old"
    """The previous version, moved aside while the new one goes in (:func:`swap_in`)."""
    BUILDING = "building"
    """A map being built inside a store."""


NAME_MAX = 255
"""Bytes in one file name (Linux, macOS and the usual file systems)."""
PATH_MAX = 4096
"""Bytes in a path handed to the system, its closing NUL included (Linux)."""
_PID_DIGITS = 7
"""Digits of the largest process id (Linux's ``pid_max`` is at most 4194304)."""
_ROOM = len(".") + len(f".{Staging.BUILDING}-") + _PID_DIGITS + len(".lock")
"""Bytes a temporary's or lock's name adds to its output's name, at most."""
_HASH_HEX = 16
"""Hex digits of the hash that stands for the cut part of a long name."""

_STALE = re.compile(r"^\..+\.(?:tmp|old|building)-(\d+)(?:\.[A-Za-z0-9]+)?$")
"""Names of staged temporaries: ``.<name>.tmp-<pid>`` (optionally with a suffix)."""

_CHUNK = 1 << 20

REBUILD = {
    "views": "care ingest {recording} --out {store} --force",
    "features": "care ingest {recording} --out {store} --force",
    "text": "care ingest {recording} --out {store} --force",
    "meta": "care ingest {recording} --out {store} --force",
    "cells": "care fuse grid {store} --overwrite",
    "cell_views": "care fuse grid {store} --overwrite",
    "instances": "care fuse instances {store} --overwrite",
    "instance_views": "care fuse instances {store} --overwrite",
    "scene_points": "care fuse instances {store} --overwrite",
}
"""Table name -> the command that rebuilds it (``{store}``, ``{recording}`` filled in)."""


def _stem(name: str) -> str:
    """The part of a temporary's name that stands for output ``name``: the name itself, or,
    where ``.<name>.building-<pid>`` would pass :data:`NAME_MAX`, its start and a hash of
    the whole (a 250-byte name still gets temporaries, each still naming its output)."""
    raw = os.fsencode(name)
    if len(raw) + _ROOM <= NAME_MAX:
        return name
    digest = hashlib.blake2b(raw, digest_size=_HASH_HEX // 2).hexdigest()
    return f"{os.fsdecode(raw[: NAME_MAX - _ROOM - _HASH_HEX - 1])}~{digest}"


def temporary(path: Path, tag: Staging = Staging.TMP) -> Path:
    """This process's temporary sibling ``.<name>.<tag>-<pid>`` of output ``path``, within
    the name limit however long ``path``'s name (:func:`_stem`)."""
    path = Path(path)
    return path.with_name(f".{_stem(path.name)}.{Staging(tag)}-{os.getpid()}")


def _lock_path(out: Path) -> Path:
    """The lock file of output ``out`` (:func:`output_lock`)."""
    return out.parent / f".{_stem(out.name)}.lock"


def check_length(path: Path, flag: str, *, full_name: bool = False) -> None:
    """Refuse, in one line and before any work, an output whose path or name the system
    would refuse (``ENAMETOOLONG`` half-way through the work otherwise): a name over
    :data:`NAME_MAX` bytes, a path over :data:`PATH_MAX` with its temporaries' room.
    ``full_name``: its writer stages it as ``.<name>.tmp-<pid>`` in full, not cut short
    (:func:`temporary`), so its name must leave room for that too."""
    path = Path(path)
    raw = os.fsencode(Path.cwd() / path)  # as given: resolving it may fail
    if len(raw) + _ROOM >= PATH_MAX:
        msg = (
            f"{flag} {_shown(path)}: path of {len(raw)} bytes, too long for this system "
            f"(its temporaries need {len(raw) + _ROOM} of at most {PATH_MAX - 1}); choose "
            "a shorter path"
        )
        raise OutputError(msg)
    for part in path.parts:
        size = len(os.fsencode(part))
        limit = NAME_MAX - _ROOM if full_name and part == path.name else NAME_MAX
        if size > limit:
            what = "name" if part == path.name else "folder name"
            msg = (
                f"{flag} {_shown(path)}: {what} of {size} bytes, longer than the {limit} "
                f"this output may have (file names hold at most {NAME_MAX}); choose a shorter name"
            )
            raise OutputError(msg)


def _shown(path: Path) -> str:
    """``path`` as a line may show it: a long one cut in the middle."""
    text = str(path)
    return text if len(text) <= 120 else f"{text[:60]}...{text[-50:]}"


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` runs (on this machine's PID namespace)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it runs, as another user
        return True
    return True


def remove_path(path: Path) -> None:
    """Remove a file or directory tree if it exists (a temporary of ours)."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def sweep_stale(directory: Path, name: str | None = None) -> list[Path]:
    """Remove staged temporaries in ``directory`` whose process no longer runs; with
    ``name``, only those of that output (``.<name>.tmp-<pid>``, ...): a directory that is not
    ours may hold the user's own files of a similar pattern.

    A dead process's ``.<name>.old-<pid>`` whose output ``<name>`` is missing is the previous
    version of an output killed between the two renames of :func:`swap_in`'s fallback: it
    is put back (:func:`restore_stale`), not removed.
    """
    directory = Path(directory)
    removed: list[Path] = []
    if not directory.is_dir():
        return removed
    try:
        entries = list(directory.iterdir())
    except OSError:
        return removed
    for entry in sorted(entries, key=lambda e: _OLD.match(e.name) is None):  # .old-<pid> first
        m = _STALE.match(entry.name)
        if m is None or (name is not None and not entry.name.startswith(f".{_stem(name)}.")):
            continue
        pid = int(m.group(1))
        if pid == os.getpid() or pid_alive(pid):
            continue
        if _restore(entry, name) or _unnamed_old(entry, name):
            continue
        remove_path(entry)
        removed.append(entry)
    return removed


_OLD = re.compile(r"^\.(?P<name>.+)\.old-(?P<pid>\d+)$")
"""The previous version of output ``<name>``, moved aside by process ``<pid>``."""


def _unnamed_old(entry: Path, name: str | None) -> bool:
    """Whether ``entry`` is a previous version whose output cannot be told from its cut-short
    name (:func:`_stem`) here: it is left for a run that knows the name."""
    m = _OLD.match(entry.name)
    return m is not None and name is None and m.group("name") != _stem(m.group("name"))


def _restore(entry: Path, name: str | None = None) -> bool:
    """Put a dead process's ``.<name>.old-<pid>`` back as ``<name>`` if that is missing
    (``name``: the output's full name, for a cut-short temporary's)."""
    m = _OLD.match(entry.name)
    if m is None or pid_alive(int(m.group("pid"))) or int(m.group("pid")) == os.getpid():
        return False
    if name is None:
        name = m.group("name")
    if m.group("name") != _stem(name):
        return False
    target = entry.with_name(name)
    if os.path.lexists(target):
        return False
    try:
        _renameat2(entry, target, _RENAME_NOREPLACE)
    except OSError as err:
        if err.errno not in _UNSUPPORTED:
            return False  # appeared meanwhile (EEXIST) or cannot be moved: leave it be
        if os.path.lexists(target):
            return False
        try:
            entry.rename(target)
        except OSError:
            return False
    return True


def restore_stale(path: Path) -> bool:
    """Put back the previous version of output ``path`` that a killed process had moved
    aside (``.<name>.old-<pid>``) when ``path`` itself is missing; whether one was."""
    path = Path(path)
    if os.path.lexists(path) or not path.parent.is_dir():
        return False
    try:
        entries = sorted(path.parent.iterdir())
    except OSError:
        return False
    for entry in entries:
        m = _OLD.match(entry.name)
        if m is not None and m.group("name") == _stem(path.name) and _restore(entry, path.name):
            return True
    return False


def _tree_size(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    total = 0
    for p in path.rglob("*"):
        with contextlib.suppress(OSError):
            if p.is_file():
                total += p.stat().st_size
    return total


def _human(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def is_disk_full(err: BaseException) -> TypeGuard[OSError]:
    """ENOSPC, EDQUOT or EFBIG (a file-size limit): no more bytes can be written."""
    return isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def disk_full(target: Path, written: int, err: OSError) -> OutputError:
    """The one-line error of a full disk (or file-size limit) while writing ``target``."""
    where = Path(target).parent
    while not where.exists() and where != where.parent:
        where = where.parent
    try:
        free = shutil.disk_usage(where).free
    except OSError:
        free = 0
    reason = "file-size limit reached" if err.errno == errno.EFBIG else "no space left on device"
    need = (
        f"after writing {_human(written)}; it needs more than {_human(written)} " if written else ""
    )
    msg = (
        f"{target}: {reason} {need}({_human(free)} free on {where}); free space (or raise "
        "the limit) and re-run; nothing half-written was left behind"
    )
    return OutputError(msg)


@contextlib.contextmanager
def staged(path: Path, *, directory: bool = False) -> Iterator[Path]:
    """A temporary sibling ``.<name>.tmp-<pid>`` of ``path``, removed on any error.

    The caller moves it into place (``os.replace``) before leaving the block. A full disk
    becomes :func:`disk_full`'s one-line error, after the temporary has been removed.
    """
    path = Path(path)
    tmp = temporary(path)
    remove_path(tmp)
    if directory:
        tmp.mkdir(parents=True)
    try:
        yield tmp
    except BaseException as err:
        written = _tree_size(tmp) if tmp.exists() else 0
        remove_path(tmp)
        if is_disk_full(err):
            raise disk_full(path, written, err) from err
        raise
    remove_path(tmp)


def write_atomic(path: Path, write: Callable[[Path], object]) -> None:
    """Run ``write(tmp)`` on a staged temporary of ``path`` and rename it into place (the
    parent is created; nothing is left behind on failure)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with staged(path) as tmp:
        write(tmp)
        tmp.replace(path)


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a staged temporary renamed over it."""
    with staged(path) as tmp:
        with tmp.open("w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        tmp.replace(path)


# -- replacing a directory in one step ---------------------------------------------------

_RENAME_NOREPLACE = 1
_RENAME_EXCHANGE = 2
_AT_FDCWD = -100
_UNSUPPORTED = {errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP}
"""What ``renameat2`` fails with where the kernel, libc or filesystem lacks a flag."""


def _renameat2(src: Path, dst: Path, flags: int) -> None:
    """Linux's ``renameat2(2)`` through libc; ENOSYS where there is none (another OS, an
    older libc)."""
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        raise OSError(errno.ENOSYS, "renameat2 is not available", str(src)) from None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    if fn(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), flags) != 0:
        code = ctypes.get_errno()
        raise OSError(code, os.strerror(code), str(src), None, str(dst))


def exchange(a: Path, b: Path) -> None:
    """Swap two existing paths in one atomic step (``RENAME_EXCHANGE``); OSError EINVAL or
    ENOSYS where the filesystem or system cannot."""
    _renameat2(a, b, _RENAME_EXCHANGE)


def swap_in(new: Path, out: Path) -> None:
    """Put the complete directory ``new`` (a staged sibling of ``out``) at ``out``, whose
    previous version, if any, is removed; a kill at any instant leaves one or the other.

    With a previous version the two are exchanged atomically (:func:`exchange`); the staged
    name then holds the old version until it is removed, and a kill before that leaves
    only a stale temporary that the next run sweeps. Where the exchange is unavailable, the
    old version is renamed aside to ``.<name>.old-<pid>`` and the new one renamed into
    place: a kill between the two leaves ``out`` missing and the old version aside, which
    the next run (:func:`sweep_stale`) or ``care check`` (:func:`restore_stale`) puts back.
    """
    new, out = Path(new), Path(out)
    if not os.path.lexists(out):
        new.rename(out)
        return
    try:
        exchange(new, out)
    except OSError as err:
        if err.errno not in _UNSUPPORTED:
            raise
    else:
        remove_path(new)  # the previous version
        return
    old = temporary(out, Staging.OLD)
    remove_path(old)
    out.rename(old)
    try:
        new.rename(out)
    finally:
        if not os.path.lexists(out):  # the new version did not go in: the old one goes back
            old.rename(out)
    remove_path(old)


def _link_tree(src: Path, dst: Path) -> None:
    """``dst``: a copy of the directory ``src`` made of hard links (a copy where links are
    refused), leaving out temporaries and locks. Safe for staging a new version because our
    writers never write a file in place: each is staged and renamed over the old one, which
    gives it a new inode and leaves ``src``'s file as it was."""

    def link(s: str, d: str) -> None:
        try:
            os.link(s, d)
        except OSError:
            shutil.copy2(s, d)

    def skip(_dir: str, names: list[str]) -> set[str]:
        return {n for n in names if _STALE.match(n) or n.endswith(".lock")}

    shutil.copytree(src, dst, symlinks=True, copy_function=link, ignore=skip)


def file_digest(path: Path) -> dict[str, Any]:
    """``{"size": bytes, "blake2b": hex}`` of a file: the one checksum of a table."""
    h = hashlib.blake2b(digest_size=16)
    size = 0
    with Path(path).open("rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)
            size += len(chunk)
    return {"size": size, "blake2b": h.hexdigest()}


# -- markers ----------------------------------------------------------------------------


def read_marker(directory: Path) -> dict[str, Any] | None:
    """The marker of ``directory`` (None if it has none or it is unreadable)."""
    path = Path(directory) / MARKER
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def is_ours(directory: Path, kind: OutputKind | None = None) -> bool:
    """Whether ``directory`` carries our marker (of ``kind`` when given)."""
    marker = read_marker(directory)
    return marker is not None and (kind is None or marker.get("kind") == kind)


def write_marker(
    directory: Path,
    kind: OutputKind,
    tables: dict[str, Any] | None = None,
    source: str | None = None,
) -> None:
    """Mark ``directory`` as a ``kind`` output of ours (keeping recorded tables); ``source``:
    the input it was made from (so the rebuild command is known even without meta.json)."""
    directory = Path(directory)
    old = read_marker(directory) or {}
    marker: dict[str, Any] = {"kind": kind, "tables": {**old.get("tables", {}), **(tables or {})}}
    if source or old.get("source"):
        marker["source"] = source or old.get("source")
    atomic_write_text(directory / MARKER, json.dumps(marker, indent=1, sort_keys=True))


def record_table(path: Path) -> None:
    """List ``path``'s digest in its directory's marker, if the directory is ours."""
    path = Path(path)
    marker = read_marker(path.parent)
    if marker is None or path.name.startswith("."):  # not ours, or a staged temporary
        return
    write_marker(path.parent, marker.get("kind", OutputKind.STORE), {path.name: file_digest(path)})


def seal(directory: Path, kind: OutputKind) -> None:
    """Record every file of ``directory`` (subdirectories too, by relative path; not the
    marker, temporaries or locks) in its marker, replacing what it listed: the whole
    version, so :func:`damaged` (``care check``) finds any file missing or changed."""
    directory = Path(directory)
    files = {}
    for path in sorted(directory.rglob("*")):
        rel = path.relative_to(directory)
        if any(part.startswith(".") for part in rel.parts) or rel.as_posix() == MARKER:
            continue
        if path.is_file() and not path.is_symlink():
            files[rel.as_posix()] = file_digest(path)
    marker = read_marker(directory) or {}
    marker.update(kind=kind, tables=files)
    atomic_write_text(directory / MARKER, json.dumps(marker, indent=1, sort_keys=True))


def _recorded(directory: Path) -> dict[str, dict[str, Any]]:
    tables: dict[str, dict[str, Any]] = {}
    marker = read_marker(directory)
    if marker:
        tables.update(marker.get("tables") or {})
    meta = Path(directory) / "meta.json"
    if meta.is_file():
        with contextlib.suppress(OSError, ValueError):
            tables.update(json.loads(meta.read_text()).get("tables") or {})
    return tables


def damaged(
    directory: Path, names: Iterable[str] | None = None, *, checksum: bool = True
) -> list[str]:
    """File names of recorded tables of ``directory`` that are missing or changed.

    ``names``: only these files (default every recorded one); ``checksum=False`` compares
    sizes only (a stat: cheap enough for every open).
    """
    directory = Path(directory)
    recorded = _recorded(directory)
    wanted = recorded if names is None else {n: recorded[n] for n in names if n in recorded}
    bad = []
    for name, expected in sorted(wanted.items()):
        path = directory / name
        try:
            size = path.stat().st_size
        except OSError:
            bad.append(name)
            continue
        if size != expected.get("size") or (
            checksum and file_digest(path).get("blake2b") != expected.get("blake2b")
        ):
            bad.append(name)
    return bad


def rebuild_hint(store: Path, table: str) -> str:
    """The command that rebuilds ``table`` (a file or table name) of the store ``store``."""
    name = Path(table).name.removesuffix(".parquet").removesuffix(".json")
    recording = (read_marker(store) or {}).get("source") or "RECORDING"
    meta = Path(store) / "meta.json"
    files: list[str] = []
    with contextlib.suppress(OSError, ValueError, AttributeError, KeyError, TypeError):
        # a store written without a recording (the Python API) records none
        source = json.loads(meta.read_text())["source"]
        recording = source["path"] or "RECORDING"
        # a recording in several files: every one of them
        files = [str(f["path"]) for f in source.get("files") or ()]
    if recording != "RECORDING":  # recorded relative to the store
        recording = " ".join(os.path.normpath(Path(store) / f) for f in files or [recording])
    template = REBUILD.get(name, "care ingest {recording} --out {store} --force")
    return "`" + template.format(store=store, recording=recording) + "`"


# -- where outputs may go ------------------------------------------------------------------


def _same_or_under(a: Path, b: Path) -> bool:
    """Whether ``a`` is ``b`` or lies inside it."""
    return a == b or b in a.parents


def refuse_link(path: Path, flag: str) -> None:
    """Refuse an output path that is itself a symbolic link (dangling or not).

    An output is replaced whole (staged beside it, then renamed over it), which would
    replace the user's link by a directory or file of ours; writing through the link
    instead would put our output wherever it points. Neither is asked for, so the user is
    told the real path to give. Links among the path's parents are harmless: the staged
    sibling and the rename both stay inside the directory they lead to.
    """
    path = Path(path)
    if not path.is_symlink():
        return
    target = path.readlink()
    real = (path.parent / target).resolve()
    if real.exists():
        how = f"give the path it points to ({real}) or another {flag}"
    else:
        how = f"it points to {real}, which does not exist; give a real path as {flag}"
    msg = f"{flag} {path}: is a symbolic link; not replaced or followed ({how})"
    raise OutputError(msg)


def check_output(
    out: Path, *, kind: OutputKind, inputs: Iterable[Path] = (), flag: str = "--out"
) -> None:
    """Refuse, in one line, an output directory this command must not replace or fill.

    Refused: a symbolic link (:func:`refuse_link`), a regular file (or a path under one),
    an input or a path inside an input or an ancestor of one, an unwritable parent, and an
    existing non-empty directory without our marker of ``kind``.
    """
    out = Path(out)
    check_length(out, flag)
    refuse_link(out, flag)
    resolved = out.resolve()
    for inp in inputs:
        r = Path(inp).resolve()
        if _same_or_under(resolved, r):
            msg = f"{flag} {out}: is the input {inp} or inside it; refusing to write there (choose another {flag})"
            raise OutputError(msg)
        if _same_or_under(r, resolved):
            msg = f"{flag} {out}: contains the input {inp}; refusing to replace it (choose another {flag})"
            raise OutputError(msg)
    for parent in [resolved, *resolved.parents]:
        if parent.exists() and not parent.is_dir():
            what = "is a regular file" if parent == resolved else f"lies under the file {parent}"
            msg = f"{flag} {out}: {what}; not replaced (choose a directory path)"
            raise OutputError(msg)
    if resolved.is_dir():
        marker = read_marker(resolved)
        if marker is None:
            if any(resolved.iterdir()):
                msg = (
                    f"{flag} {out}: directory holds files care did not write (no {MARKER}); "
                    f"not replaced (choose a new or empty directory)"
                )
                raise OutputError(msg)
        elif marker.get("kind") != kind:
            msg = f"{flag} {out}: is a care {marker.get('kind')} directory, not a {kind}; choose another {flag}"
            raise OutputError(msg)
    existing = next(p for p in [resolved, *resolved.parents] if p.exists())
    if not os.access(existing, os.W_OK | os.X_OK):
        msg = f"{flag} {out}: permission denied: cannot write in {existing} (fix its permissions or choose another {flag})"
        raise OutputError(msg)
    sweep_dead(out)


def sweep_dead(out: Path) -> None:
    """Sweep what runs that no longer exist left where ``out`` is written: its temporaries
    beside it, and those inside it if it is a directory of ours (a map's, a cached scene's).
    Done by every run, an up-to-date one too, without the lock: only a dead process's
    temporaries go, and no live writer touches those."""
    out = Path(out)
    sweep_stale(out.parent, out.name)
    if out.is_dir() and not out.is_symlink() and is_ours(out):
        sweep_stale(out)


_RRD_MAGIC = (b"RRF0", b"RRF1", b"RRF2")


def check_file_output(
    path: Path,
    *,
    inputs: Iterable[Path] = (),
    flag: str = "--rrd",
    magic: tuple[bytes, ...] = _RRD_MAGIC,
) -> None:
    """Refuse an output file that is a symbolic link (:func:`refuse_link`), a directory, an
    input, or an existing file of other content (one whose first bytes are not ``magic``)."""
    path = Path(path)
    check_length(path, flag, full_name=True)  # the .rrd writers stage it under its full name
    refuse_link(path, flag)
    resolved = path.resolve()
    for inp in inputs:
        r = Path(inp).resolve()
        if _same_or_under(resolved, r) or r in resolved.parents:
            msg = f"{flag} {path}: is or lies inside the input {inp}; choose another {flag}"
            raise OutputError(msg)
    for parent in resolved.parents:
        if parent.exists() and not parent.is_dir():
            msg = f"{flag} {path}: lies under the regular file {parent}; choose another {flag}"
            raise OutputError(msg)
    if resolved.is_dir():
        msg = f"{flag} {path}: is a directory; give a file path"
        raise OutputError(msg)
    if resolved.is_file() and resolved.stat().st_size:
        with resolved.open("rb") as f:
            head = f.read(4)
        if not head.startswith(magic):
            msg = f"{flag} {path}: exists and is not a file care wrote; not overwritten (choose another {flag})"
            raise OutputError(msg)


@contextlib.contextmanager
def output_lock(out: Path, *, wait: bool = True) -> Iterator[None]:
    """Hold an advisory lock on output ``out`` (a sibling ``.<name>.lock``) for the block.

    A second writer waits for the first (saying so on stderr), or with ``wait=False``
    fails in one line. The stale temporaries of dead writers are swept once it is held.
    The lock file is removed on release; a waiter that then holds a removed file's lock
    notices (its inode is gone) and locks the new one, so two writers never both hold it.
    """
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    lock_path = _lock_path(out)
    while True:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                if not wait:
                    msg = f"{out}: being written by another care process (pid {holder}); wait for it to finish"
                    raise OutputError(msg) from None
                print(f"{out}: waiting for care process {holder} writing it", file=sys.stderr)
                fcntl.flock(fd, fcntl.LOCK_EX)
            try:
                same = lock_path.stat().st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
        except BaseException:
            os.close(fd)
            raise
        if same:
            break
        os.close(fd)  # the holder removed that file: lock the current one
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        sweep_dead(out)
        try:
            yield
        except OSError as err:  # a full disk the staged writers did not already report
            if is_disk_full(err):
                raise disk_full(out, 0, err) from err
            raise
    finally:
        with contextlib.suppress(OSError):
            lock_path.unlink()
        os.close(fd)  # releases the lock


@contextlib.contextmanager
def owned_output(out: Path, kind: OutputKind, inputs: Iterable[Path] = ()) -> Iterator[Path]:
    """Check ``out`` (:func:`check_output`), lock it, create and mark it; yield it. A
    directory this call created is removed again if the work inside fails."""
    out = Path(out)
    check_output(out, kind=kind, inputs=inputs)
    with output_lock(out):
        check_output(out, kind=kind, inputs=inputs)
        created = not out.exists()
        out.mkdir(parents=True, exist_ok=True)
        if not is_ours(out, kind):
            write_marker(out, kind)
        try:
            yield out
        except BaseException:
            if created:  # made by this run, which failed: leave nothing behind
                remove_path(out)
            raise


@contextlib.contextmanager
def whole_output(out: Path, kind: OutputKind, inputs: Iterable[Path] = ()) -> Iterator[Path]:
    """Check ``out`` (:func:`check_output`) and lock it; yield a staged directory to write
    the new version into, which replaces ``out`` as one unit when the block succeeds.

    The staged directory ``.<name>.tmp-<pid>`` starts as a copy of the previous version
    (hard links, :func:`_link_tree`: what the new one reuses, such as cached results, and
    what it does not rewrite stays as before), is sealed (:func:`seal`: every file's size
    and checksum in the marker) and swapped in (:func:`swap_in`). A kill at any instant
    leaves the previous version or the new one, never a mix, and at most a temporary the
    next run sweeps; on an error the temporary is removed and ``out`` is as it was. An
    error naming a staged file names the file of ``out`` instead.
    """
    out = Path(out)
    check_output(out, kind=kind, inputs=inputs)
    with output_lock(out):
        check_output(out, kind=kind, inputs=inputs)
        tmp = temporary(out)
        remove_path(tmp)
        try:
            if out.is_dir():
                _link_tree(out, tmp)
            else:
                tmp.mkdir()
            if not is_ours(tmp, kind):
                write_marker(tmp, kind)
            yield tmp
            seal(tmp, kind)
            swap_in(tmp, out)
        except BaseException as err:
            remove_path(tmp)
            if is_disk_full(err):
                raise disk_full(out, 0, err) from err
            if isinstance(err, CareError) and str(tmp) in str(err):
                renamed = _renamed(err, str(err).replace(str(tmp), str(out)))
                if renamed is not None:
                    raise renamed from err
            raise
        remove_path(tmp)


def _renamed(err: CareError, message: str) -> CareError | None:
    """``err``'s kind of error with another message (None if it cannot be made)."""
    try:
        return type(err)(message)
    except Exception:
        return None


def evaluation_output(
    out: Path, stores: Iterable[Path] = ()
) -> contextlib.AbstractContextManager[Path]:
    """An evaluation directory of ours at ``out`` (never one of the ``stores`` or inside one),
    replaced as one unit: write into the yielded staged directory (:func:`whole_output`)."""
    return whole_output(out, OutputKind.EVAL, stores)
